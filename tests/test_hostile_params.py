"""Hostile path, query and body values (issue 12): one validation layer (``app/params.py``)
answers each with a clear 4xx ``{"code", "message"}``, never a 500 and never a silent guess,
and nothing stored changes."""

from __future__ import annotations

import json
import uuid
from typing import Annotated, Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.db.session import session_scope
from app.errors import InvalidParameterValueError, InvalidQueryError, InvalidValueError
from app.main import EXCEPTION_HANDLERS
from app.params import (
    Finite,
    Int,
    LonLat,
    NetworkName,
    parse_float,
    parse_int,
    parse_lonlat,
    parse_position,
    parse_slug,
)
from ingest.network import RoadAttributes, RoadLine, write_network
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer, grid_network
from testkit.raster_synth import synthetic_utm

RADIUS_LIMIT = {"radius": 100.0}  # stands for a bound read from settings per request


@pytest.fixture(scope="module")
def safe_client(app):
    """A client that shows a server error as the 500 a user gets, not as a test crash."""
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


@pytest.fixture(scope="module")
def layer(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> str:
    path, _ = synthetic_utm(tmp_path_factory.mktemp("hp") / "h.tif", width=64, height=64)
    slug = f"hp-{uuid.uuid4().hex[:8]}"
    ingest_raster([path], slug)
    return slug


def _problem(resp, status: int, code: str) -> dict:
    assert resp.status_code == status, (str(resp.request.url)[:120], resp.text[:300])
    body = resp.json()
    assert body["code"] == code and body["message"], body
    return body


# -- pure parsers ------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["٣", "²", "1_000", " 1", "1.0", "0x1", "", "9" * 20])
def test_int_is_ascii_digits_only(text: str) -> None:
    with pytest.raises(InvalidParameterValueError):
        parse_int(text, "z")


def test_int_bounds_and_error_class() -> None:
    assert parse_int("42", "n", low=1, high=lambda: 50) == 42
    with pytest.raises(InvalidQueryError, match=r"radius must be within 0\.\.50"):
        parse_int("51", "radius", low=0, high=lambda: 50, error=InvalidQueryError)


@pytest.mark.parametrize("text", ["nan", "NaN", "inf", "-Infinity", "1e999", "١٫٥", "٣",
                                  "1,5", "", "0x10", "1e"])
def test_float_is_finite_ascii(text: str) -> None:
    with pytest.raises(InvalidParameterValueError):
        parse_float(text, "radius")


def test_float_accepts_plain_decimals() -> None:
    assert [parse_float(t, "x") for t in ("1", "-2.5", ".5", "3.", "1e-3", "+7E2")] == \
        [1.0, -2.5, 0.5, 3.0, 0.001, 700.0]
    with pytest.raises(InvalidValueError) as caught:
        parse_float(10**400, "fraction", error=InvalidValueError)  # JSON int beyond float
    assert caught.value.errors == {"fraction": caught.value.message.removeprefix("fraction ")}


def test_slug_and_coordinates() -> None:
    assert parse_slug("andorra-2024_v1") == "andorra-2024_v1"
    for bad in ("a\x00b", "A", "-a", "a/b", "a" * 65, "ä", "a\nb"):
        with pytest.raises(InvalidParameterValueError):
            parse_slug(bad, "layer slug")
    assert parse_lonlat("1.5, 42.5") == (1.5, 42.5)
    for bad in ("200,0", "0,95", "nan,0", "1", "1,2,3", "٣,1"):
        with pytest.raises(InvalidParameterValueError):
            parse_lonlat(bad)
    for bad in ([float("inf"), 0], [0], [True, 0], ["1", 2], [0, -90.5]):
        with pytest.raises(InvalidValueError):
            parse_position(bad)


# -- HTTP: raster layers and tiles -----------------------------------------------------------
def test_nul_byte_in_a_layer_slug_is_400(safe_client, layer) -> None:
    # Before: PostgreSQL refused the NUL in the bound parameter -> 500.
    for url in ("/layers/a%00b", "/layers/a%00b/tilejson.json", "/tiles/a%00b/0/0/0.png",
                "/tiles/a%00b/0/0/0@2x.webp", "/layers/%01x", "/layers/" + "a" * 65):
        body = _problem(safe_client.get(url), 400, "InvalidParameterValue")
        assert "layer slug" in body["message"]
    assert safe_client.get(f"/layers/{layer}").status_code == 200


@pytest.mark.parametrize("part", ["%C2%B2", "%D9%A3", "%EF%BC%91", "%E2%91%A0"])
def test_unicode_digit_tile_coordinates_are_400(safe_client, layer, part) -> None:
    """``²`` (int() refuses it: was a 500) and ``٣``/``１`` (int() reads 3/1: was a silent
    tile) are not tile coordinates, in any position, raster or vector."""
    net = grid_network().network
    for address in (f"{part}/0/0", f"1/{part}/0", f"1/0/{part}"):
        for url in (f"/tiles/{layer}/{address}.png", f"/networks/{net}/tiles/{address}.mvt"):
            _problem(safe_client.get(url), 400, "InvalidParameterValue")


def test_nul_byte_in_a_network_name_is_400(safe_client) -> None:
    _problem(safe_client.get("/networks/a%00b/tiles/0/0/0.mvt"), 400, "InvalidParameterValue")


# -- HTTP: topology edits -------------------------------------------------------------------
@pytest.fixture()
def bent(database_url: str) -> tuple[str, int]:
    """One segment with a vertex in the middle: a point that is not a number used to land
    on it (ST_LineLocatePoint of POINT(Infinity 0) is 0.5 there)."""
    name = f"bent-{uuid.uuid4().hex[:8]}"
    with session_scope() as s:
        write_network(s, name, [RoadLine([(10.0, 50.0), (10.001, 50.001), (10.002, 50.0)],
                                         RoadAttributes())], node_crossings=False)
    return name, _features(name)[0]["id"]


def _features(name: str) -> list[dict]:
    from app.network import collections as colls
    from app.network.collections import ItemQuery

    with session_scope() as s:
        c = colls.resolve(s, f"{name}-segments")
        return colls.query_items(s, c, ItemQuery(), limit=100, offset=0)[1]


def _split(client, name: str, fid: int, body: str):
    return client.post(f"/collections/{name}-segments/items/{fid}/split", content=body,
                       headers={**bearer("admin"), "If-Match": '"1"',
                                "Content-Type": "application/json"})


@pytest.mark.parametrize("body", ['{"fraction": 1e-300}', '{"fraction": 0.9999999999999}',
                                  '{"fraction": 1e-12}', '{"fraction": -0.0}',
                                  '{"fraction": "0.5"}', '{"fraction": 1e400}',
                                  '{"point": [1e400, 0]}', '{"point": [200, 50]}',
                                  '{"point": [10.001]}'])
def test_split_refuses_slivers_and_impossible_points(safe_client, bent, body) -> None:
    # 1e-300 and 0.9999999999999 made a zero-length half: 500 before (a Point, not a line).
    name, fid = bent
    _problem(_split(safe_client, name, fid, body), 422, "InvalidValue")
    assert [f["properties"]["version"] for f in _features(name)] == [1]


@pytest.mark.parametrize("body", ['{"point": [Infinity, 0]}', '{"fraction": NaN}',
                                  '{"point": [-Infinity, 50]}'])
def test_split_refuses_non_json_numbers(safe_client, bent, body) -> None:
    # Before: Python's parser took Infinity, and the split went through at the middle (200).
    name, fid = bent
    body_ = _problem(_split(safe_client, name, fid, body), 400, "InvalidParameterValue")
    assert "not a JSON number" in body_["message"]
    assert len(_features(name)) == 1


def test_split_in_the_middle_still_works(client, bent) -> None:
    name, fid = bent
    r = _split(client, name, fid, json.dumps({"point": [10.001, 50.0011]}))
    assert r.status_code == 200, r.text
    assert len(_features(name)) == 2


def test_revert_version_is_ascii_digits(safe_client) -> None:
    net = grid_network().network
    items = f"/collections/{net}-segments/items"
    fid = safe_client.get(items).json()["features"][0]["id"]
    for to in ("%D9%A3", "%C2%B2", "0", "-1", "1.0", "99999999999"):
        _problem(safe_client.post(f"{items}/{fid}/revert?to={to}",
                                  headers={**bearer("editor"), "If-Match": '"1"'}),
                 400, "InvalidParameterValue")


def test_annotated_rules_on_an_endpoint() -> None:
    """The parameter types as another capability (routing) uses them: the rule's own error
    class and code, bounds read from settings at request time, and an honest OpenAPI."""
    limit = RADIUS_LIMIT
    probe = FastAPI(exception_handlers=EXCEPTION_HANDLERS)

    @probe.get("/n/{name}")
    def endpoint(name: NetworkName,
                 point: Annotated[Any, LonLat("point", error=InvalidQueryError)],
                 radius: Annotated[float, Finite("radius", low=0,
                                                 high=lambda: RADIUS_LIMIT["radius"])] = 50.0,
                 n: Annotated[int, Int("n", low=1, high=10)] = 1) -> dict:
        return {"name": name, "point": list(point), "radius": radius, "n": n}

    c = TestClient(probe)
    assert c.get("/n/x?point=1.5,42.5&radius=75&n=3").json() == \
        {"name": "x", "point": [1.5, 42.5], "radius": 75.0, "n": 3}
    assert c.get("/n/x?point=1.5,42.5").json()["radius"] == 50.0
    for query, code in (("point=1.5,95", "InvalidQuery"), ("point=nan,1", "InvalidQuery"),
                        ("point=1,1&radius=inf", "InvalidParameterValue"),
                        ("point=1,1&radius=101", "InvalidParameterValue"),
                        ("point=1,1&n=%D9%A3", "InvalidParameterValue")):
        _problem(c.get(f"/n/x?{query}"), 400, code)
    limit["radius"] = 200.0  # a bound from settings follows them
    assert c.get("/n/x?point=1,1&radius=150").status_code == 200
    _problem(c.get("/n/a%00b?point=1,1"), 400, "InvalidParameterValue")
    params = {p["name"]: p["schema"] for p in
              probe.openapi()["paths"]["/n/{name}"]["get"]["parameters"]}
    assert params["name"]["pattern"].startswith("^[a-z0-9]")
    assert (params["n"]["minimum"], params["n"]["maximum"]) == (1, 10)
    assert params["radius"]["minimum"] == 0 and "maximum" not in params["radius"]
