"""``ugvmap extract-roads`` / ``evaluate-roads`` end to end, and their one-line errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli.main import main
from ingest.roads.synthetic import Scene, render
from tests.test_roads_pipeline import CROSS_T, ROAD_BOX, scene


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("roads")
    rgb, road = render(scene())
    paths = {"image": d / "scene.png", "truth": d / "truth.png", "junk": d / "junk.png",
             "tiny": d / "tiny.png", "grass": d / "grass.png", "out": d / "roads.geojson",
             "labels": d / "labels.png"}
    cv2.imwrite(str(paths["image"]), rgb[..., ::-1])
    cv2.imwrite(str(paths["truth"]), road.astype(np.uint8) * 255)
    labels = np.where(road, 255, 128).astype(np.uint8)
    labels[:, 200:] = 0
    cv2.imwrite(str(paths["labels"]), labels)
    paths["junk"].write_text("this is not an image")
    cv2.imwrite(str(paths["tiny"]), rgb[:1, :1])
    grass, _ = render(Scene((200, 200), seed=9))
    cv2.imwrite(str(paths["grass"]), grass[..., ::-1])
    return paths


def invoke(*args: object):
    return CliRunner().invoke(main, [str(a) for a in args])


def box(b: tuple[int, int, int, int]) -> str:
    return ",".join(map(str, b))


def test_extract_then_evaluate(files: dict[str, Path], tmp_path: Path) -> None:
    debug = tmp_path / "debug"
    result = invoke("extract-roads", files["image"], "--train-box", box(ROAD_BOX),
                    "--classifier", "spectral", "--resolution", 0.5, "--out", files["out"],
                    "--debug-dir", debug)
    assert result.exit_code == 0, result.output
    assert "7 segments, 8 nodes (2 junctions), spectral" in result.output
    doc = json.loads(files["out"].read_text())
    assert doc["crs"] is None and doc["coordinate_space"] == "pixel"
    assert {f["geometry"]["type"] for f in doc["features"]} == {"LineString"}
    assert {"source", "target", "length_m", "width_m", "lanes"} <= set(
        doc["features"][0]["properties"])
    assert sorted(p.name for p in debug.iterdir()) == [
        "1_binary.png", "2_cleaned.png", "3_houses_removed.png", "4_skeleton.png"]

    result = invoke("evaluate-roads", files["out"], files["truth"], "--resolution", 0.5,
                    "--json", "--max-radius", 3)
    assert result.exit_code == 0, result.output
    scores = json.loads(result.output)
    assert [s["radius_m"] for s in scores] == [0.5, 1.0, 1.5]
    assert scores[1]["precision"] > 0.95 and scores[1]["recall"] > 0.95

    table = invoke("evaluate-roads", files["out"], files["truth"])
    assert table.exit_code == 0 and "precision" in table.output


def test_learned_from_a_label_image(files: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "learned.geojson"
    result = invoke("extract-roads", files["image"], "--train-mask", files["labels"],
                    "--classifier", "learned", "--resolution", 0.5, "--out", out)
    assert result.exit_code == 0, result.output
    assert "learned classifier" in result.output


def test_a_sample_adapts_the_road_model_by_default(files: dict[str, Path], tmp_path: Path
                                                   ) -> None:
    out = tmp_path / "adapted.geojson"
    result = invoke("extract-roads", files["image"], "--train-mask", files["labels"],
                    "--resolution", 0.5, "--out", out)
    assert result.exit_code == 0, result.output
    assert "adapted classifier" in result.output
    # whether the sample was used, with the held-out figures that decided it
    assert re.search(r"^sample (not )?used: on the held-out half of the labels the adapted "
                     r"model agreed [0-9.]+ and the network [0-9.]+", result.output, re.M), \
        result.output
    assert len(json.loads(out.read_text())["features"]) >= 4


def test_evaluate_two_geojson_files_in_map_coordinates(tmp_path: Path) -> None:
    def fc(dx: float) -> dict:
        lines = [[[500_000 + x * 0.5 + dx, 4_600_000 - y * 0.5] for x, y in line]
                 for line in CROSS_T]
        return {"type": "FeatureCollection",
                "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32633"}},
                "features": [{"type": "Feature", "properties": {},
                              "geometry": {"type": "LineString", "coordinates": c}}
                             for c in lines]}
    pred, gt = tmp_path / "pred.geojson", tmp_path / "gt.geojson"
    pred.write_text(json.dumps(fc(1.5)))
    gt.write_text(json.dumps(fc(0.0)))
    result = invoke("evaluate-roads", pred, gt, "--resolution", 0.5, "--json")
    scores = {s["radius_m"]: s for s in json.loads(result.output)}
    # shifted 1.5 m east: the vertical lines match from 1.5 m on, the horizontal ones at once
    assert scores[0.5]["recall"] < 0.8
    assert scores[2.0]["precision"] > 0.97 and scores[2.0]["recall"] > 0.97


@pytest.mark.parametrize(("args", "message"), [
    (["--train-box", "1,1,5,5", "--resolution", 1, "IMG:junk"], "not a readable image"),
    (["--train-box", "0,0,1,1", "--resolution", 1, "IMG:tiny"], "too small"),
    (["--train-box", "100,146,1400,154", "--resolution", 0.5, "IMG:image"], "not inside"),
    (["--classifier", "learned", "--resolution", 0.5, "IMG:image"], "needs a training sample"),
    (["--resolution", 5, "IMG:image"], "coarser than"),
    (["--train-box", box(ROAD_BOX), "IMG:image"], "--resolution"),
    (["--train-box", box(ROAD_BOX), "--resolution", 0.5, "--classifier", "learned",
      "IMG:image"], "needs not-road pixels"),
    (["--train-box", "1,2,3", "--resolution", 0.5, "IMG:image"], "x0,y0,x1,y1"),
])
def test_bad_input_is_one_clear_line(files: dict[str, Path], tmp_path: Path, args: list,
                                     message: str) -> None:
    args = [files[a[4:]] if isinstance(a, str) and a.startswith("IMG:") else a for a in args]
    result = invoke("extract-roads", *args, "--out", tmp_path / "o.geojson")
    assert result.exit_code != 0
    assert message in result.output
    assert "Traceback" not in result.output
    assert not isinstance(result.exception, Exception) or isinstance(result.exception,
                                                                     SystemExit)
    assert not (tmp_path / "o.geojson").exists()


def test_no_road_is_an_empty_result_not_an_error(files: dict[str, Path], tmp_path: Path
                                                 ) -> None:
    out = tmp_path / "o.geojson"
    result = invoke("extract-roads", files["grass"], "--train-box", "0,0,20,20",
                    "--classifier", "spectral", "--resolution", 0.5, "--out", out)
    assert result.exit_code == 0, result.output
    assert "no road found" in result.output and "0 segments" in result.output
    assert json.loads(out.read_text())["features"] == []


def test_empty_training_mask_is_an_error(files: dict[str, Path], tmp_path: Path) -> None:
    empty = tmp_path / "empty.png"
    cv2.imwrite(str(empty), np.zeros((300, 400), np.uint8))
    result = invoke("extract-roads", files["image"], "--train-mask", empty, "--resolution", 0.5,
                    "--out", tmp_path / "o.geojson")
    assert result.exit_code == 1
    assert result.output.strip().count("\n") == 0
    assert "no road pixels" in result.output


def test_evaluate_bad_input(files: dict[str, Path], tmp_path: Path) -> None:
    bad = tmp_path / "bad.geojson"
    bad.write_text("{not json")
    result = invoke("evaluate-roads", bad, files["truth"])
    assert result.exit_code == 1 and "not a readable GeoJSON" in result.output
    result = invoke("evaluate-roads", files["junk"], files["truth"])
    assert result.exit_code == 1 and "not a readable image" in result.output
    result = invoke("evaluate-roads", tmp_path / "missing.png", files["truth"])
    assert result.exit_code == 1 and "no such file" in result.output
