"""QGIS 3.34 LTR's OAPIF provider as an editing client, replayed over real HTTP.

What QGIS sends and how it reads the answers, from its source (qgis/QGIS,
``src/providers/wfs/``, the revisions of the 3.32-3.34 era in the stored index):

- layer load (``qgsoapifprovider.cpp``, ``init()``): ``GET {items}?limit=10`` with
  ``Accept: application/geo+json, application/json``; the page is written to ``/vsimem`` and
  opened with OGR's GeoJSON driver (``qgsoapifitemsrequest.cpp``, ``processReply()``), whose
  field types become the layer's (QGIS 3.34 reads no schema: ``qgsoapifschemarequest.cpp`` is
  from 2025). The GeoJSON ``id`` becomes OGR's feature id, not a field.
- ``computeCapabilities()``: ``OPTIONS {items}``; only if ``Allow`` has ``POST`` (AddFeatures),
  ``OPTIONS {items}/{id}`` with the first id of that page (or ``unknown_id``): ``PUT`` ->
  change attributes and geometries, ``DELETE`` -> delete, ``PATCH`` -> use PATCH.
- ``QgsBaseNetworkRequest::sendOPTIONS()`` (``qgsbasenetworkrequest.cpp``): the first response
  header whose name ``== QByteArray("Allow")`` (case-sensitive), split on ``,``, each trimmed.
- ``QgsOapifCreateFeatureRequest::createFeature()``: ``POST {items}`` with
  ``Content-Type: application/geo+json``, the feature as ``QgsJsonExporter`` writes it (every
  field, ``null`` where empty) without ``id`` and ``bbox``, ``Content-Crs: <bare URI>`` when
  the layer CRS is not CRS84, coordinates swapped when that CRS's axis order is inverted; the
  new id is the ``Location`` header's value after its last ``/items/``, the header found with
  ``== QByteArray("Location")`` (case-sensitive until PR 61814, 2025; QGIS issue 61729 reports
  it on 3.34.14). QGIS releases after PR 57547 (May 2024) then ``GET {items}/{id}`` to
  refresh the feature; replayed too, since it must work either way.
- ``QgsOapifPatchFeatureRequest``: ``PATCH {items}/{id}``, ``application/merge-patch+json``,
  ``{"properties": {changed fields}}`` (NULL as ``null``) or ``{"geometry": ...}`` (+
  ``Content-Crs``).
- ``sendDELETE()``: ``DELETE {items}/{id}``; any 2xx succeeds.
- No request carries ``If-Match`` and no ``ETag`` is read. Credentials: the connection's
  user name and password as HTTP Basic (``QgsAuthorizationSettings``).
- Any other status fails the commit ("... Feature request failed: <Qt error>"); JSON error
  bodies are not read.
"""

from __future__ import annotations

import base64
import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pyogrio.raw

CRS84 = "http://www.opengis.net/def/crs/OGC/1.3/CRS84"
ITEMS_ACCEPT = "application/geo+json, application/json"


def qgis_header(response: httpx.Response, name: str) -> str | None:
    """The first header named exactly ``name`` on the wire, as QGIS 3.34 looks it up."""
    for key, value in response.headers.raw:
        if key == name.encode():
            return value.decode()
    return None


def ogr_fields(page: bytes) -> tuple[list[str], list[str], list[list[Any]]]:
    """(names, numpy dtypes, rows of values) of an items page as OGR's GeoJSON driver reads
    it: what QGIS 3.34's layer fields and attribute values are."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp, "page.json")
        path.write_bytes(page)
        meta, _, _, columns = pyogrio.raw.read(path)
    names = [str(n) for n in meta["fields"]]
    dtypes = [str(c.dtype) for c in columns]
    rows = [[None if v is None else v.item() if hasattr(v, "item") else v
             for v in values] for values in zip(*columns, strict=True)]
    return names, dtypes, rows


@dataclass
class QgisLayer:
    """One OAPIF layer being edited in QGIS 3.34: its items URL, the connection's user name
    and password, the layer CRS (None: CRS84), and what loading it found."""

    client: httpx.Client
    items: str
    user: str
    password: str
    crs: str | None = None
    lat_first: bool = False
    fields: list[str] = field(default_factory=list)
    dtypes: list[str] = field(default_factory=list)
    first_page: dict[str, Any] = field(default_factory=dict)
    log: list[tuple[str, str, int]] = field(default_factory=list)

    def _auth(self) -> dict[str, str]:
        basic = base64.b64encode(f"{self.user}:{self.password}".encode()).decode()
        return {"Authorization": f"Basic {basic}"}

    def send(self, method: str, url: str, headers: dict[str, str] | None = None,
             **kw: Any) -> httpx.Response:
        """One request with the connection's credentials, logged (method, URL, status)."""
        response = self.client.request(method, url, headers={**self._auth(), **(headers or {})},
                                       **kw)
        self.log.append((method, url, response.status_code))
        return response

    def load(self) -> None:
        """``GET {items}?limit=10``; the fields are typed by OGR from that page."""
        r = self.send("GET", f"{self.items}?limit=10", headers={"Accept": ITEMS_ACCEPT})
        r.raise_for_status()
        self.first_page = r.json()
        self.fields, self.dtypes, _ = ogr_fields(r.content)

    def capabilities(self) -> set[str]:
        """``computeCapabilities()``: what QGIS lets the user do with the layer."""
        allow = qgis_header(self.send("OPTIONS", self.items), "Allow") or ""
        found: set[str] = set()
        if "POST" not in [t.strip() for t in allow.split(",")]:
            return found
        found.add("AddFeatures")
        features = self.first_page.get("features") or []
        test_id = str(features[0]["id"]) if features else "unknown_id"
        one = qgis_header(self.send("OPTIONS", f"{self.items}/{test_id}"), "Allow") or ""
        tokens = [t.strip() for t in one.split(",")]
        if "PUT" in tokens:
            found |= {"ChangeAttributeValues", "ChangeGeometries"}
        if "DELETE" in tokens:
            found.add("DeleteFeatures")
        if "PATCH" in tokens:
            found.add("SupportsPatch")
        return found

    def _crs_headers(self) -> dict[str, str]:
        return {"Content-Crs": self.crs} if self.crs and self.crs != CRS84 else {}

    def _geometry(self, geometry: dict[str, Any]) -> dict[str, Any]:
        """Coordinates as QGIS sends them (swapped for a lat-first CRS)."""
        if not self.lat_first:
            return geometry
        swap: Any = (lambda c: [c[1], c[0]]) if geometry["type"] == "Point" else \
            (lambda cs: [[p[1], p[0]] for p in cs])
        return {**geometry, "coordinates": swap(geometry["coordinates"])}

    def add_feature(self, geometry: dict[str, Any], attributes: dict[str, Any]) -> str | None:
        """``addFeatures()``: POST the feature with every layer field (unset ones null);
        the new id read from ``Location``, then the feature re-read. None when QGIS would
        report "Feature creation failed"."""
        properties = {name: attributes.get(name) for name in self.fields}
        body = {"type": "Feature", "geometry": self._geometry(geometry),
                "properties": properties}
        r = self.send("POST", self.items, content=json.dumps(body, default=str),
                      headers={"Content-Type": "application/geo+json", **self._crs_headers()})
        location = qgis_header(r, "Location") if r.is_success else None
        if location is None or "/items/" not in location:
            return None
        created = location[location.rindex("/items/") + len("/items/"):]
        self.send("GET", f"{self.items}/{created}", headers={"Accept": ITEMS_ACCEPT})
        return created

    def change_attributes(self, fid: str, changes: dict[str, Any]) -> bool:
        """``changeAttributeValues()`` with PATCH: the changed fields only."""
        r = self.send("PATCH", f"{self.items}/{fid}",
                      content=json.dumps({"properties": changes}),
                      headers={"Content-Type": "application/merge-patch+json"})
        return r.is_success

    def change_geometry(self, fid: str, geometry: dict[str, Any]) -> bool:
        """``changeGeometryValues()`` with PATCH."""
        r = self.send("PATCH", f"{self.items}/{fid}",
                      content=json.dumps({"geometry": self._geometry(geometry)}),
                      headers={"Content-Type": "application/merge-patch+json",
                               **self._crs_headers()})
        return r.is_success

    def delete(self, fid: str) -> bool:
        """``deleteFeatures()``."""
        return self.send("DELETE", f"{self.items}/{fid}").is_success
