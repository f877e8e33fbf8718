"""A drive's road centreline on imagery our own renderer did not make.

``testkit.ipm_world`` renders with conventions of its own (transverse Mercator ground,
a rotation matrix from Rodrigues' formula, a noisy orthophoto, the vehicle anywhere across
the road). Here: a 7 m grey road on darker, noisy grey ground, driven 1.5 m right of its
centre line by a 1.9 m camera with a 768x384 panorama, through the real ``ugvmap ingest ipm``
and ``ugvmap ingest roads`` with defaults only. Before the road's colour line was ended by the
drive's not-road sample, the darker ground counted as road: the whole 30 m wide coverage was
"road" and its middle, the vehicle's path, the centreline (1.5 m off).
"""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner

from cli.main import main
from testkit.ipm_world import Look, Mount, World, write
from tests.test_ipm_roads import segments

WORLD = World(radius_m=60.0, width_m=7.0, arc_deg=40.0, offsets_m=(1.5, 1.5),
              look=Look(road_rgb=(125, 125, 125), road_noise=6, ground_rgb=(95, 95, 95),
                        ground_noise=25))
MOUNT = Mount(size=(768, 384))


@pytest.fixture(scope="module")
def grey_drive(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return write(tmp_path_factory.mktemp("grey-drive"), WORLD, MOUNT, frames=40)


def test_centreline_on_grey_ground_with_the_vehicle_off_centre(
        database_url: str, grey_drive: dict[str, Path]) -> None:
    slug, network = f"grey-{uuid.uuid4().hex[:8]}", f"grey-{uuid.uuid4().hex[:8]}"
    runner = CliRunner()
    result = runner.invoke(main, ["ingest", "ipm", str(grey_drive["frames"]), "--poses",
                                  str(grey_drive["poses"]), "--calib", str(grey_drive["calib"]),
                                  "--layer", slug, "--workers", "2"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["ingest", "roads", "--layer", slug, "--network", network])
    assert result.exit_code == 0, result.output
    rows = segments(network)
    lonlat = np.vstack([shapely.get_coordinates(shapely.from_wkb(bytes(r.wkb))) for r in rows])
    x, y = WORLD.local(lonlat[:, 0], lonlat[:, 1])
    error = np.abs(WORLD.signed_offset_m(np.asarray(x), np.asarray(y)))
    # Measured: median 0.034 m, max 0.117 m; before the fix 0.61 / 1.29 m (the coverage's
    # middle, drawn towards the vehicle's path).
    assert np.median(error) <= 0.10 and error.max() <= 0.5
