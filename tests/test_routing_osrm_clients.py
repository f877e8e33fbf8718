"""Real OSRM clients against our routes: osrm-text-instructions phrases our steps, and Leaflet
Routing Machine's OSRM v1 router requests and parses our answers (both run in node from
``tests/osrm_clients``, installed by scripts/setup.sh with ``npm ci``)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import httpx
import psycopg
import pytest

from tests.routing_support import dsn, town, unique, xy

CLIENTS = Path(__file__).parent / "osrm_clients"
NODE = shutil.which("node")

# node is installed by scripts/setup.sh (the web map needs it too); without it the test cannot
# say anything, which is a broken setup, not a reason to pass.
pytestmark = pytest.mark.skipif(NODE is None, reason="node not on PATH: run scripts/setup.sh")


def node(script: str, *args: str, stdin: str = "") -> Any:
    """Run a client script in node; its stdout is JSON."""
    assert (CLIENTS / "node_modules").is_dir(), "run scripts/setup.sh (npm ci there)"
    done = subprocess.run([NODE or "node", str(CLIENTS / script), *args], input=stdin,
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.fixture(scope="module")
def town_net(database_url: str) -> dict:
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        return town(conn, unique("town"))


def test_text_instructions_read_our_steps(client, town_net) -> None:
    """Turns, a name change and a roundabout, phrased by osrm-text-instructions itself."""
    (ax, ay), (bx, by) = xy(20, -4), xy(405, 450)  # the end 5 m east of North Road
    r = client.get(f"/networks/{town_net['name']}/route/v1/driving/{ax},{ay};{bx},{by}",
                   params={"steps": "true"})
    assert r.status_code == 200, r.text
    sentences = node("instructions.js", stdin=r.text)
    assert sentences == [[
        "Head east on Main Street",
        "Continue onto High Street",
        "Turn left onto Church Lane",
        "Enter the roundabout and take the 2nd exit onto North Road",
        "Exit the roundabout onto North Road",
        "You have arrived at your destination, on the right",
    ]]


def test_text_instructions_between_legs(client, town_net) -> None:
    """Two legs: the first ends at a waypoint, the second starts there."""
    pts = [xy(20, 4), xy(300, 4), xy(396, 100)]
    r = client.get(f"/networks/{town_net['name']}/route/v1/driving/"
                   + ";".join(f"{x},{y}" for x, y in pts), params={"steps": "true"})
    assert r.status_code == 200, r.text
    first, second = node("instructions.js", stdin=r.text)
    assert first == ["Head east on Main Street", "Continue onto High Street",
                     "You have arrived at your 1st destination, on the left"]
    assert second == ["Head east on High Street", "Turn left onto Church Lane",
                      "You have arrived at your destination, on the left"]


def test_leaflet_routing_machine_requests_and_parses_our_answer(live_server, town_net) -> None:
    """LRM's OSRMv1 router, unmodified, with its default options (overview=false,
    alternatives=true, steps=true, hints=;): its URL is accepted and its parser builds a route
    with coordinates, instructions and waypoints; the second request sends back our hints."""
    (ax, ay), (bx, by) = xy(20, -4), xy(405, 450)
    service = f"{live_server}/networks/{town_net['name']}/route/v1"
    first, second = node("lrm.js", service, json.dumps([[ay, ax], [by, bx]]))
    assert "overview=false&alternatives=true&steps=true&hints=;" in first["url"]
    assert first["err"] is None, first["err"]
    route = first["routes"][0]
    # Main 180 m, High 200, Church 200, half the roundabout 153, North Road 150.
    assert route["summary"]["totalDistance"] == pytest.approx(883, rel=0.01)
    assert route["coordinates"] > 10 and route["waypointIndices"][0] == 0
    assert route["first"] == pytest.approx([xy(20, 0)[1], xy(20, 0)[0]], abs=1e-5)
    assert [i["type"] for i in route["instructions"]] == [
        "Head", "Continue", "Left", "Roundabout", "Right", "DestinationReached"]
    assert route["instructions"][2]["text"] == "Turn left onto Church Lane"
    assert route["instructions"][0]["direction"] == "E"
    # Hints come back on the next request, and it answers the same.
    hints = second["url"].split("hints=")[1].split("&")[0].split(";")
    assert len(hints) == 2 and all(hints)
    assert second["err"] is None and second["routes"][0]["summary"] == route["summary"]
    # The same URL over plain HTTP: code Ok, and a polyline per step (LRM decodes them).
    body = httpx.get(first["url"]).json()
    assert body["code"] == "Ok" and "geometry" not in body["routes"][0]
    assert route["name"] == body["routes"][0]["legs"][0]["summary"] == "High Street, Church Lane"
    assert all(isinstance(s["geometry"], str) for s in body["routes"][0]["legs"][0]["steps"])
