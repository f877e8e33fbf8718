"""One error model: the same fault gives the same status, code and body shape on every
producer — raster tiles and vector tiles, features, jobs, routes, and the framework's own
404/405/422 — and no answer is ever FastAPI's ``{"detail"}``."""

from __future__ import annotations

import uuid

import httpx
import pytest

from app.grid import MAX_ZOOM
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer, grid_network
from testkit.raster_synth import synthetic_utm


@pytest.fixture(scope="module")
def names(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """An existing raster layer and road network, so every fault is on a real resource."""
    path, _ = synthetic_utm(tmp_path_factory.mktemp("err") / "e.tif", width=64, height=64)
    layer = f"err-{uuid.uuid4().hex[:8]}"
    ingest_raster([path], layer)
    return {"layer": layer, "network": grid_network().network}


def _tile_urls(names: dict[str, str], address: str) -> list[str]:
    """The same tile address on every tile producer: raster formats and vector tiles."""
    return [f"/tiles/{names['layer']}/{address}.png",
            f"/tiles/{names['layer']}/{address}@2x.webp",
            f"/networks/{names['network']}/tiles/{address}.mvt"]


def _problem(resp: httpx.Response, status: int, code: str) -> dict:
    assert resp.status_code == status, (resp.request.url, resp.text)
    body = resp.json()
    assert body["code"] == code, (resp.request.url, body)
    assert isinstance(body["message"], str) and body["message"]
    assert set(body) <= {"code", "message", "errors"}, body  # never {"detail"}
    return body


@pytest.mark.parametrize("address", [
    f"{MAX_ZOOM + 1}/0/0", "1/2/0", "1/0/2", "3/8/1", "3/0/99999999999999999999", "31/0/0"])
def test_tile_outside_the_matrix_set_is_404_everywhere(client, names, address) -> None:
    for url in _tile_urls(names, address):
        _problem(client.get(url), 404, "TileOutOfRange")


@pytest.mark.parametrize("address", ["a/0/0", "1/0/-1", "1/-1/0", "1.5/0/0", "1/0/0x1"])
def test_malformed_tile_address_is_400_everywhere(client, names, address) -> None:
    for url in _tile_urls(names, address):
        _problem(client.get(url), 400, "InvalidParameterValue")


def test_max_zoom_is_one_value_for_both_tile_kinds(client, names) -> None:
    for url in _tile_urls(names, f"{MAX_ZOOM}/0/0"):
        assert client.get(url).status_code == 200, url


def test_unknown_resources_are_404_not_found(client, names) -> None:
    for url in ("/networks/nope/tiles/1/0/0.mvt", "/networks/nope/route?points=0,0;0.1,0.1",
                "/collections/nope-segments", f"/collections/{names['network']}-segments/items/0",
                "/jobs/999999999", "/jobs/0", "/no/such/path", "/web/no-such-file.js"):
        _problem(client.get(url), 404, "NotFound")
    # A raster layer keeps its own, more precise code; it is still a 404.
    for url in ("/tiles/nope/1/0/0.png", "/layers/nope", "/layers/nope/tilejson.json"):
        _problem(client.get(url), 404, "LayerNotFound")


def test_wrong_method_is_405_with_allow(client, names) -> None:
    for resp in (client.post("/layers"), client.delete("/jobs"),
                 client.put(f"/tiles/{names['layer']}/1/0/0.png")):
        _problem(resp, 405, "MethodNotAllowed")
        assert "GET" in resp.headers["allow"]
    # Allow names every method of the path, whichever router serves it (GET and PATCH of an
    # item live in different routers).
    item = client.post(f"/collections/{names['network']}-segments/items/1")
    _problem(item, 405, "MethodNotAllowed")
    assert item.headers["allow"] == "DELETE, GET, HEAD, OPTIONS, PATCH, PUT"
    # Ours (nodes are not split) answers the same code.
    _problem(client.post(f"/collections/{names['network']}-nodes/items/1/split",
                         json={"fraction": 0.5},
                         headers={**bearer("admin"), "If-Match": '"1"'}), 405,
             "MethodNotAllowed")


def test_request_validation_is_422_with_per_field_errors(client, names) -> None:
    body = _problem(client.get("/jobs", params={"limit": 0}), 422, "InvalidValue")
    assert set(body["errors"]) == {"limit"}
    body = _problem(client.get("/jobs/abc"), 422, "InvalidValue")
    assert set(body["errors"]) == {"job_id"}
    body = _problem(client.post(f"/networks/{names['network']}/route", json={"cost": "time"}),
                    422, "InvalidValue")
    assert set(body["errors"]) == {"points"}
    # The editing API's own value checks give the same code and the same errors shape.
    items = client.get(f"/collections/{names['network']}-segments/items").json()["features"]
    body = _problem(client.patch(f"/collections/{names['network']}-segments/items/"
                                 f"{items[0]['id']}", json={"lanes_forward": 99},
                                 headers={**bearer("editor"), "If-Match": '"1"'}),
                    422, "InvalidValue")
    assert set(body["errors"]) == {"lanes_forward"}


def test_bad_parameter_values_are_400_invalid_parameter_value(client, names) -> None:
    for url in ("/jobs?status=nonsense", f"/layers/{names['layer']}/tilejson.json?format=tiff",
                f"/tiles/{names['layer']}/1/0/0.gif", f"/tiles/{names['layer']}/1/0/0",
                f"/collections/{names['network']}-segments/items?bbox=1,2,3",
                f"/collections/{names['network']}-segments/items?limit=x"):
        _problem(client.get(url), 400, "InvalidParameterValue")


def test_routing_keeps_osrm_codes(client, names) -> None:
    route = f"/networks/{names['network']}/route"
    _problem(client.get(route, params={"points": "x"}), 400, "InvalidQuery")
    _problem(client.get(route, params={"points": "0,0;0.001,0.001"}), 422, "NoSegment")


def test_unauthorized_carries_the_challenge(client, names) -> None:
    resp = client.patch(f"/collections/{names['network']}-segments/items/1", json={})
    _problem(resp, 401, "Unauthorized")
    assert resp.headers["www-authenticate"].startswith("Bearer")


def test_every_fault_has_its_own_row_in_the_status_table() -> None:
    """The core's faults carry no status; the edge's table gives each one its answer. A fault
    class added without a row would answer 500 ``InternalError`` through its base: refused
    here, so the table stays the one place a fault's status and code are decided."""
    from app import errors
    from app.api import errors as http

    def subclasses(cls: type[errors.UgvmapError]) -> set[type[errors.UgvmapError]]:
        return {cls} | {s for sub in cls.__subclasses__() for s in subclasses(sub)}

    assert sorted(c.__name__ for c in subclasses(errors.UgvmapError)
                  if c not in http.STATUS_CODES) == []
