"""``ugvmap demo`` loads a meaningful map (real samples, or a generated town) and is re-runnable."""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

from click.testing import CliRunner
from pyproj import Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from ingest.demo import SYNTHETIC_ORIGIN
from tests.conftest import REPO


def _names(table: str, column: str) -> set[str]:
    with session_scope() as session:
        return set(session.execute(text(f"SELECT {column} FROM {table}")).scalars())


def test_demo_without_samples_generates_a_routable_town(client, tmp_path: Path) -> None:
    runner = CliRunner()
    first = runner.invoke(main, ["demo", "--shared-data", str(tmp_path / "absent")])
    assert first.exit_code == 0, first.output
    assert "synthetic-town" in _names("layers", "slug")
    assert "synthetic-town" in _names("networks", "name")
    token = first.output.strip().splitlines()[-1].rsplit(" ", 1)[-1]
    assert token.startswith("ugv_")

    again = runner.invoke(main, ["demo", "--shared-data", str(tmp_path / "absent")])
    assert again.exit_code == 0 and "already there" in again.output
    assert again.output.strip().endswith(token)  # the same demo token, not a new one

    # Two junctions of the generated grid, 500 m apart along one road.
    utm = Transformer.from_crs("EPSG:4326", "EPSG:32611", always_xy=True)
    east, north = utm.transform(*SYNTHETIC_ORIGIN)
    grid = from_origin(round(east), round(north), 0.5, 0.5)
    to_lonlat = Transformer.from_crs("EPSG:32611", "EPSG:4326", always_xy=True).transform
    a, b = (to_lonlat(*(grid @ (x, 375.5))) for x in (375.5, 1375.5))
    route = client.get("/networks/synthetic-town/route",
                       params={"points": f"{a[0]},{a[1]};{b[0]},{b[1]}", "cost": "distance"})
    assert route.status_code == 200, route.text
    assert abs(route.json()["routes"][0]["distance"] - 500) < 15


def test_demo_with_shared_samples(client, shared_data: Path) -> None:
    result = CliRunner().invoke(main, ["demo", "--shared-data", str(shared_data)])
    assert result.exit_code == 0, result.output
    assert {"vegas", "drone-orthophotos"} <= _names("layers", "slug")
    assert {"vegas", "vegas-extracted", "helsinki"} <= _names("networks", "name")
    tile = client.get("/layers/vegas/tilejson.json")
    assert tile.status_code == 200
    with session_scope() as session:  # both ends of the arterial along the top of the image
        vertices = session.execute(text(
            "SELECT ST_X(p.geom), ST_Y(p.geom) FROM road_segments s"
            " JOIN networks n ON n.id = s.network_id, ST_DumpPoints(s.geom) AS p"
            " WHERE n.name = 'vegas' AND s.road_class = 'primary' ORDER BY ST_X(p.geom)")).all()
    points = ";".join(f"{x},{y}" for x, y in (vertices[0], vertices[-1]))
    route = client.get("/networks/vegas/route", params={"points": points})
    assert route.status_code == 200, route.text
    assert route.json()["routes"][0]["distance"] > 200


def test_a_busy_port_is_said_plainly_and_make_demo_takes_another(database_url: str) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        said = (f"Error: port {port} on 127.0.0.1 is in use (another `ugvmap serve`, or "
                "another program): choose another with --port N, UGVMAP_PORT=N, or "
                "`make demo PORT=N`")
        for args, env in ((["serve", "--port", str(port)], {}),
                          (["serve"], {"UGVMAP_PORT": str(port)})):
            result = CliRunner().invoke(main, args, env=env)
            assert result.exit_code == 1 and result.output.strip() == said, result.output

    def served_on(*args: str, **env: str) -> str:
        """The port `make demo` serves on (its plan, `make -n`), with only ``env``'s
        UGVMAP_PORT."""
        # Under `make test` (CI) the environment carries the outer make's MAKELEVEL and
        # MAKEFLAGS, and a nested make then ends its plan with "Leaving directory ...".
        clean = {k: v for k, v in os.environ.items()
                 if k not in ("UGVMAP_PORT", "MAKELEVEL", "MAKEFLAGS", "MFLAGS")}
        plan = subprocess.run(["make", "--no-print-directory", "-n", "demo", *args], cwd=REPO,
                              check=True, text=True, capture_output=True,
                              env={**clean, **env}).stdout
        return plan.strip().splitlines()[-1].rsplit(" ", 1)[-1]

    assert served_on("PORT=8101") == "8101"
    assert served_on(UGVMAP_PORT="8102") == "8102"
    assert served_on() == "8000"
