"""Conditional answers for versioned tiles: ``Cache-Control``, strong ``ETag`` and 304.

The version tokens themselves are the core's (:mod:`app.tiles.versioned`: the catalogue and
the batch jobs hand them out); how a request naming one is answered is the HTTP layer's.
Used by the raster and the vector tile endpoints alike.
"""

from __future__ import annotations

from fastapi import Request, Response

from app.tiles.versioned import VERSION_PARAM

IMMUTABLE = "max-age=31536000, immutable"


def cache_headers(request: Request, token: str, unversioned: str, *,
                  public: bool = True) -> dict[str, str]:
    """``Cache-Control`` and strong ``ETag`` for a tile of the version named by ``token``.

    ``immutable`` only when the request names the current version; otherwise the
    ``unversioned`` policy (a short max-age, or no-cache). ``public=False`` (tiles that need a
    token to read) makes it ``private``, so no shared cache keeps what one reader may see.
    """
    current = request.query_params.get(VERSION_PARAM) == token
    policy = IMMUTABLE if current else unversioned
    if not public:
        policy = "private, " + policy.removeprefix("public, ")
    elif current:
        policy = "public, " + policy
    return {"Cache-Control": policy, "ETag": f'"{token}"'}


def not_modified(request: Request, headers: dict[str, str]) -> Response | None:
    """A 304 when the client's ``If-None-Match`` holds the tile's ETag (weak or strong)."""
    given = request.headers.get("if-none-match")
    if not given:
        return None
    tags = {t.strip().removeprefix("W/") for t in given.split(",")}
    if headers["ETag"] in tags or "*" in tags:
        return Response(status_code=304, headers=headers)
    return None
