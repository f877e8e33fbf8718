"""Versioned tile URLs: tiles that any HTTP cache may keep forever, for rasters and MVT alike.

A layer's or network's TileJSON hands out tile URLs ending in ``?v=<token>``, where the token
names exactly one version of the data (:func:`version_token`). A tile asked for with the
current token can never change, so it is answered ``Cache-Control: public, max-age=31536000,
immutable`` with a strong ETag (:mod:`app.api.conditional`): browsers, nginx and CDNs keep it
without revalidating. Every re-ingest or edit bumps the version, so the TileJSON hands out
*new* URLs and nothing ever has to be purged; the old entries just age out of the caches.

Why a query parameter and not a path segment: the tile path stays the public contract
(``/tiles/{slug}/{z}/{x}/{y}.png`` keeps working unversioned, as today), every XYZ client
(MapLibre, Leaflet, QGIS, GDAL_WMS) keeps a template's query string, and nginx keys its cache
on the full request URI, query included.

A *stale* (or unknown) token, e.g. from a page that read the TileJSON before a re-ingest, is
answered with the current content under the short, revalidating policy of unversioned
requests: never a redirect, which would cost every tile of that page a second round trip, and
never ``immutable``, since what that URL should show is no longer what we have. The client's
next TileJSON read moves it to the new URLs.
"""

from __future__ import annotations

import hashlib
from datetime import datetime

VERSION_PARAM = "v"


def version_token(kind: str, row_id: int, version: int, created_at: datetime) -> str:
    """An opaque token naming one version of one layer/network.

    ``created_at`` is part of it so that a layer deleted and created again (or a database
    rebuilt), whose id and version numbers start over, never reuses a token that caches may
    still hold for the old data.
    """
    raw = f"{kind}:{row_id}:{version}:{created_at.timestamp():.6f}"
    return hashlib.blake2b(raw.encode(), digest_size=8).hexdigest()


def versioned(template: str, token: str) -> str:
    """``template`` (a tile URL template) with the version token appended as ``?v=``."""
    sep = "&" if "?" in template else "?"
    return f"{template}{sep}{VERSION_PARAM}={token}"
