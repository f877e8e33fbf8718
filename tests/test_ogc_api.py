"""OGC API Features core as standard clients use it: the negotiated landing page, the OpenAPI
3.0 document, conformance, queryables and schemas, datetime / bbox / property filters, HEAD,
and QGIS's own request sequence (from its OAPIF provider's source) replayed step by step."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from urllib.parse import parse_qs, urlsplit

import pytest
from openapi_spec_validator import validate

from app.db.session import session_scope
from ingest.network import RoadAttributes, RoadLine, write_network
from testkit.network_helpers import grid_network

OPENAPI_30 = "application/vnd.oai.openapi+json;version=3.0"
BROWSER_ACCEPT = "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8"


@pytest.fixture(scope="module")
def grid(database_url: str):
    return grid_network()


@pytest.fixture(scope="module")
def diagonal(database_url: str) -> str:
    """One straight diagonal road, so a box can meet its envelope but not the line."""
    name = f"diag-{uuid.uuid4().hex[:8]}"
    with session_scope() as session:
        write_network(session, name, [RoadLine([(20.0, 60.0), (20.01, 60.01)],
                                               RoadAttributes(1, 1, 30.0, name="Diagonal"))])
    return name


def links(doc: dict, rel: str) -> list[dict]:
    return [link for link in doc["links"] if link["rel"] == rel]


def test_root_is_the_map_for_browsers_and_the_landing_page_for_json_clients(client) -> None:
    page = client.get("/", headers={"Accept": BROWSER_ACCEPT})
    assert page.headers["content-type"].startswith("text/html") and "Accept" in page.headers["vary"]
    for request in ({"headers": {"Accept": "application/json"}}, {"params": {"f": "json"}},
                    {"headers": {"Accept": "text/html;q=0.5, application/json"}}):
        landing = client.get("/", **request)
        assert landing.headers["content-type"] == "application/json", request
        body = landing.json()
        assert {link["rel"] for link in body["links"]} >= {
            "self", "service-desc", "service-doc", "conformance", "data"}
    assert client.get("/", headers={"Accept": "*/*"}).headers["content-type"].startswith(
        "text/html")
    assert client.get("/", params={"f": "html"},
                      headers={"Accept": "application/json"}).headers["content-type"].startswith(
        "text/html")
    bad = client.get("/", params={"f": "xml"})
    assert bad.status_code == 400 and bad.json()["code"] == "InvalidParameterValue"
    # /ogc: the landing page whatever the client accepts; below it, the API's own paths.
    ogc = client.get("/ogc", headers={"Accept": BROWSER_ACCEPT}).json()
    assert links(ogc, "service-desc")[0]["type"] == OPENAPI_30
    moved = client.get("/ogc/collections?f=json", follow_redirects=False)
    assert moved.status_code == 308 and moved.headers["location"].endswith("/collections?f=json")


def test_api_document_is_valid_openapi_30_and_describes_the_items(client, grid) -> None:
    response = client.get("/openapi.json")
    assert response.headers["content-type"] == OPENAPI_30
    doc = response.json()
    assert doc["openapi"] == "3.0.3"
    validate(doc)  # raises on anything 3.0 does not allow (3.1's type lists, numeric exclusives)
    text = json.dumps(doc)
    assert '"type": "null"' not in text and "HTTPValidationError" not in text
    limit = doc["components"]["parameters"]["limit"]["schema"]
    assert limit == {"type": "integer", "minimum": 1, "maximum": 10_000, "default": 10}
    items = doc["paths"]["/collections/{collection_id}/items"]["get"]
    refs = {p.get("$ref", "").rsplit("/", 1)[-1] for p in items["parameters"]}
    assert refs >= {"limit", "offset", "bbox", "bbox-crs", "datetime"}
    assert set(items["responses"]) >= {"200", "400", "404", "503"}
    assert "application/geo+json" in items["responses"]["200"]["content"]
    own = doc["paths"][f"/collections/{grid.network}-segments/items"]["get"]
    filters = {p["name"]: p["schema"]["type"] for p in own["parameters"] if "name" in p}
    assert filters["lanes_forward"] == "integer" and filters["road_class"] == "string"
    assert "collection_id" not in filters
    segment = doc["components"]["schemas"]["SegmentFeature"]["properties"]["properties"]
    assert segment["properties"]["width_m"] == {
        "type": "number", "description": "Carriageway width, metres", "nullable": True}
    patch = doc["paths"]["/collections/{collection_id}/items/{fid}"]["patch"]
    assert set(patch["requestBody"]["content"]) == {"application/merge-patch+json",
                                                    "application/json"}
    assert set(patch["responses"]) >= {"200", "401", "403", "404", "412", "422", "428"}
    split = doc["paths"]["/collections/{collection_id}/items/{fid}/split"]["post"]
    fraction = split["requestBody"]["content"]["application/json"]["schema"]["oneOf"][0]
    assert fraction["properties"]["fraction"]["exclusiveMinimum"] is True
    route = doc["paths"]["/networks/{name}/route"]["post"]
    assert route["responses"]["422"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/ErrorBody"}


def test_conformance_queryables_and_schemas(client, grid) -> None:
    conf = client.get("/conformance").json()["conformsTo"]
    assert "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/oas30" in conf
    meta = client.get(f"/collections/{grid.network}-segments").json()
    by_rel = {link["rel"]: link for link in meta["links"]}
    assert by_rel["describedby"]["type"] == "application/schema+json"
    temporal = meta["extent"]["temporal"]["interval"][0]
    assert temporal[0] <= temporal[1]

    queryables = client.get(by_rel["http://www.opengis.net/def/rel/ogc/1.0/queryables"]["href"])
    assert queryables.headers["content-type"] == "application/schema+json"
    q = queryables.json()
    assert q["$schema"].startswith("https://json-schema.org/draft/2020-12")
    assert q["properties"]["lanes_forward"]["type"] == "integer"
    assert q["properties"]["oneway"]["enum"] == ["none", "forward", "backward"]

    schema = client.get(by_rel["http://www.opengis.net/def/rel/ogc/1.0/schema"]["href"]).json()
    types = {k: v.get("type") for k, v in schema["properties"].items()}
    assert types["width_m"] == "number" and types["lanes_forward"] == "integer"
    assert types["is_junction"] == "boolean" and types["name"] == "string"
    assert schema["properties"]["geometry"]["format"] == "geometry-linestring"
    assert schema["properties"]["updated_at"]["format"] == "date-time"
    assert schema["properties"]["version"]["readOnly"] is True

    feature = client.get(by_rel["describedby"]["href"]).json()
    assert feature["properties"]["properties"]["properties"]["width_m"]["type"] == "number"
    nodes = client.get(f"/collections/{grid.network}-nodes/schema").json()
    assert nodes["properties"]["degree"]["type"] == "integer"
    assert client.get("/collections/nope-segments/queryables").status_code == 404


def count(client, collection: str, **params) -> int:
    response = client.get(f"/collections/{collection}/items", params={"limit": 100, **params})
    assert response.status_code == 200, response.text
    return response.json()["numberMatched"]


def test_bbox_is_a_true_intersection_and_accepts_3d_and_the_antimeridian(client,
                                                                        diagonal) -> None:
    segments = f"{diagonal}-segments"
    # The box sits inside the line's envelope, off the line itself.
    assert count(client, segments, bbox="20.0,60.008,20.002,60.01") == 0
    assert count(client, segments, bbox="20.004,60.004,20.006,60.006") == 1
    assert count(client, segments, bbox="20.004,60.004,-100,20.006,60.006,100") == 1
    assert count(client, segments, bbox="179,60.004,20.006,60.006") == 1  # wraps east
    assert count(client, segments, bbox="179,60.004,-179,60.006") == 0


def test_datetime_filters_segments_and_is_ignored_for_nodes(client, grid) -> None:
    segments, nodes = f"{grid.network}-segments", f"{grid.network}-nodes"
    assert count(client, segments, datetime="2000-01-01T00:00:00Z/..") == 12
    assert count(client, segments, datetime="2000-01-01/") == 12
    assert count(client, segments, datetime="../2000-01-01T00:00:00Z") == 0
    assert count(client, segments, datetime="2000-01-01") == 0
    assert count(client, segments, datetime="2000-01-01T00:00:00+02:00/2999-01-01") == 12
    assert count(client, nodes, datetime="../2000-01-01T00:00:00Z") == 9


def test_property_filters(client, grid) -> None:
    segments, nodes = f"{grid.network}-segments", f"{grid.network}-nodes"
    assert count(client, segments, name="Row 1") == 2
    assert count(client, segments, lanes_forward=2, road_class="residential") == 12
    assert count(client, segments, lanes_forward=3) == 0
    assert count(client, segments, is_junction="false", oneway="none") == 12
    assert count(client, nodes, kind="junction") == 5
    page = client.get(f"/collections/{segments}/items", params={"name": "Row 1", "limit": 1})
    nxt = links(page.json(), "next")[0]["href"]
    assert parse_qs(urlsplit(nxt).query)["name"] == ["Row 1"]  # paging keeps the filter


def test_head_answers_every_get(client, grid) -> None:
    for path in ("/", "/ogc", "/conformance", "/collections", "/openapi.json", "/healthz",
                 f"/collections/{grid.network}-segments/items?limit=3",
                 f"/networks/{grid.network}/tilejson.json", "/layers",
                 "/web/app.js", "/docs"):
        got, head = client.get(path), client.head(path)
        assert head.status_code == got.status_code == 200, path
        assert head.content == b"", path
        assert head.headers["content-type"] == got.headers["content-type"], path
        assert head.headers["content-length"] == got.headers["content-length"], path
    assert client.head("/collections/nope-segments").status_code == 404


def test_qgis_request_sequence(client, grid) -> None:
    """What QGIS's OAPIF provider (src/providers/wfs/oapif) asks, in its order, read the way
    it reads the answers."""
    # 1. Landing page: GET the URL the user typed, Accept: application/json.
    landing = client.get("/ogc", headers={"Accept": "application/json"}).json()
    api_url = next(link["href"] for link in landing["links"] if link["rel"] == "service-desc"
                   and link["type"] == OPENAPI_30)
    collections_url = next(link["href"] for link in landing["links"]
                           if link["rel"] == "data" and link["type"] == "application/json")
    conformance_url = next(link["href"] for link in landing["links"]
                           if link["rel"] == "conformance")
    # 2. The API document: the page size comes from components/parameters/limit.
    api = client.get(api_url, headers={"Accept": f"{OPENAPI_30}, application/json"}).json()
    max_limit = api["components"]["parameters"]["limit"]["schema"]["maximum"]
    default_limit = api["components"]["parameters"]["limit"]["schema"]["default"]
    page_size = min(max(1000, default_limit), max_limit)
    assert page_size == 1000
    # ... and simple queryables from the collection's own items path (form, not exploded).
    typename = f"{grid.network}-segments"
    params = api["paths"][f"/collections/{typename}/items"]["get"]["parameters"]
    simple = {p["name"]: p["schema"]["type"] for p in params
              if p.get("in") == "query" and p.get("style") == "form"
              and p.get("explode") is False and isinstance(p.get("schema", {}).get("type"), str)
              and p["name"] not in ("bbox", "bbox-crs", "datetime", "limit")}
    assert simple["name"] == "string" and simple["lanes_forward"] == "integer"
    # 3. The collection, by appending its id to the collections URL.
    collection = client.get(f"{collections_url}/{typename}",
                            headers={"Accept": "application/json"}).json()
    bbox = collection["extent"]["spatial"]["bbox"][0]
    # 4. Conformance: Part 5 schemas declared, so QGIS fetches the schema below.
    classes = client.get(conformance_url).json()["conformsTo"]
    assert "http://www.opengis.net/spec/ogcapi-features-5/1.0/conf/schemas" in classes
    # 5. A first page of 10 for numberMatched and a sample.
    first = client.get(f"{collections_url}/{typename}/items?limit=10").json()
    assert first["numberMatched"] == 12
    # 6. The schema (rel .../schema, application/schema+json) types the fields.
    schema_url = next(link["href"] for link in collection["links"]
                      if link["rel"] == "http://www.opengis.net/def/rel/ogc/1.0/schema"
                      and link["type"] == "application/schema+json")
    fields = client.get(schema_url).json()["properties"]
    assert fields["width_m"]["type"] == "number" and fields["lanes_backward"]["type"] == "integer"
    # 7. The features of the view: bbox + limit, following `next` links.
    url = (f"{collections_url}/{typename}/items?limit=5&bbox="
           + ",".join(str(v) for v in bbox))
    seen = []
    while url:
        page = client.get(url, headers={"Accept": "application/geo+json"})
        assert page.headers["content-type"] == "application/geo+json"
        body = page.json()
        seen += [f["id"] for f in body["features"]]
        url = next((link["href"] for link in body["links"] if link["rel"] == "next"), None)
    assert len(seen) == len(set(seen)) == 12
    # 8. A single feature by id, and a server-side filter from a simple queryable.
    one = client.get(f"{collections_url}/{typename}/items/{seen[0]}").json()
    assert one["id"] == seen[0]
    filtered = client.get(f"{collections_url}/{typename}/items",
                          params={"limit": page_size, "name": "Column 2"}).json()
    assert {f["properties"]["name"] for f in filtered["features"]} == {"Column 2"}


def gdal_fetches(stderr: str) -> list[str]:
    """The URLs GDAL fetched, from its CPL_DEBUG output."""
    return [line.split("Fetch(", 1)[1].rstrip(")") for line in stderr.splitlines()
            if "HTTP: Fetch(" in line]


@pytest.mark.slow
def test_gdal_36_where_filters_on_the_server_without_errors(live_server: str, grid,
                                                            tmp_path) -> None:
    """Debian's ogr2ogr (GDAL 3.6): the API document names the collection's filters, so
    ``-where`` becomes ``?name=...`` instead of a full download, and nothing goes wrong on the
    way (before: two 404s for /api and a Content-Type error on stderr). The describedby
    schema types width_m as Real although every sampled value is null."""
    out = tmp_path / "row1.geojson"
    run = subprocess.run(
        ["ogr2ogr", "--config", "CPL_DEBUG", "ON", "-f", "GeoJSON", str(out),
         f"OAPIF:{live_server}", f"{grid.network}-segments", "-where", "name = 'Row 1'"],
        capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert not [line for line in run.stderr.splitlines() if line.startswith("ERROR")]
    features = json.loads(out.read_text())["features"]
    assert sorted(f["properties"]["name"] for f in features) == ["Row 1", "Row 1"]
    items = [u for u in gdal_fetches(run.stderr) if "/items" in u]
    assert any("name=Row" in u for u in items), items
    assert all(f"{live_server}/api" not in u for u in gdal_fetches(run.stderr))
    info = subprocess.run(["ogrinfo", "-ro", "-so", f"OAPIF:{live_server}",
                           f"{grid.network}-segments"], capture_output=True, text=True,
                          timeout=60)
    assert "width_m: Real" in info.stdout and "lanes_forward: Integer" in info.stdout
    assert not info.stderr.strip()


GDAL_312 = """
import json, sys
import pyogrio.raw as raw
meta, fids, geom, fields = raw.read(sys.argv[1], layer=sys.argv[2], where=sys.argv[3] or None)
print(json.dumps({"count": len(geom), "gdal": __import__("pyogrio").__gdal_version_string__,
                  "types": dict(zip(meta["fields"], meta["dtypes"]))}))
"""


@pytest.mark.slow
def test_newer_gdal_pages_by_the_documented_limit(live_server: str, grid) -> None:
    """pyogrio's bundled GDAL (3.8+ reads the items path of the API document): pages of
    min(max(1000, default), maximum) features, and ``-where`` runs on the server."""
    def read(where: str) -> tuple[dict, list[str]]:
        run = subprocess.run([sys.executable, "-c", GDAL_312, f"OAPIF:{live_server}",
                              f"{grid.network}-segments", where],
                             capture_output=True, text=True, timeout=120,
                             env={**os.environ, "CPL_DEBUG": "ON"})
        assert run.returncode == 0, run.stderr
        return json.loads(run.stdout), gdal_fetches(run.stderr)

    result, fetched = read("")
    assert result["count"] == 12 and result["types"]["width_m"] == "float64"
    pages = [u for u in fetched if "/items?" in u and "limit=20" not in u]
    assert pages and all("limit=1000" in u for u in pages), fetched
    assert f"{live_server}/openapi.json" in fetched
    result, fetched = read("lanes_forward = 2 AND name = 'Column 0'")
    assert result["count"] == 2
    assert any("lanes_forward=2" in u and "name=Column" in u for u in fetched), fetched
