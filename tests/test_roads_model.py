"""The road model: training (CI-sized), ONNX export, tiled inference, zero-shot extraction.

Training and the ONNX-vs-torch check run on synthetic scenes made here (known roads), so they
need no shared data; the shipped model (``models/roads-v1``) is exercised on synthetic towns
and, in ``tests/test_roads_real.py``, on the shared validation imagery.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from cli.main import main
from ingest.roads import RoadsInputError
from ingest.roads.georef import Image
from ingest.roads.model.data import file_sha16, normalise, training_pairs
from ingest.roads.model.runtime import MODEL_DIR, load_model, predict
from ingest.roads.pipeline import ExtractParams, extract_roads
from ingest.roads.synthetic import Scene, grid_scene, render

torch = pytest.importorskip("torch", reason="the train extra (torch) is not installed")


def town(size: int = 320, spacing: int = 90, width: int = 8, seed: int = 0
         ) -> tuple[np.ndarray, np.ndarray]:
    """A 1 m/px synthetic town: road grid, roofs in the blocks."""
    return render(grid_scene(size, spacing, width, seed=seed))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pairs.json + three synthetic scenes (one held out), like the shared training set."""
    root = tmp_path_factory.mktemp("road_training")
    pairs = []
    for i, (spacing, split) in enumerate([(80, "train"), (110, "train"), (95, "holdout")]):
        rgb, road = town(192, spacing, 7, seed=i)
        cv2.imwrite(str(root / f"s{i}.png"), rgb[..., ::-1])
        cv2.imwrite(str(root / f"s{i}_gt.png"), road.astype(np.uint8) * 255)
        pairs.append({"image": f"s{i}.png", "mask": f"s{i}_gt.png", "m_per_px": 1.0,
                      "source": "synthetic", "split": split})
    (root / "pairs.json").write_text(json.dumps(pairs))
    return root


TINY = {"crop_px": 64, "batch": 4, "epochs": 3, "steps_per_epoch": 10, "lr": 3e-3}


@pytest.fixture(scope="module")
def tiny_run(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    from ingest.roads.model.train import TrainConfig, initial_loss, train

    out = tmp_path_factory.mktemp("model")
    config = TrainConfig(**TINY)
    report = train(dataset, out, config, progress=False)
    report["initial_loss"] = initial_loss(config, dataset)
    return out, report


def test_tiny_training_run_lowers_the_loss_and_writes_a_model(tiny_run: tuple[Path, dict]
                                                              ) -> None:
    out, report = tiny_run
    losses = [h["loss"] for h in report["history"]]
    assert losses[-1] < 0.8 * report["initial_loss"], (report["initial_loss"], losses)
    assert {p.name for p in out.iterdir()} >= {"model.onnx", "weights.pt", "training.json",
                                                "README.md"}
    card = (out / "README.md").read_text()
    assert "research use only" in card and "Per-epoch hold-out report" in card
    model = load_model(out / "model.onnx")
    assert model.resolution_m == 1.0 and model.threshold == report["threshold"]


def test_onnx_and_torch_agree(tiny_run: tuple[Path, dict]) -> None:
    from ingest.roads.model.net import RoadUNet

    out, _ = tiny_run
    net = RoadUNet()
    net.load_state_dict(torch.load(out / "weights.pt"))
    net.eval()
    x = np.random.default_rng(1).random((2, 3, 96, 160), dtype=np.float32)
    with torch.no_grad():
        logit, feats = net(torch.from_numpy(x))
    prob_onnx, feats_onnx = load_model(out / "model.onnx").session.run(None, {"rgb": x})
    np.testing.assert_allclose(prob_onnx, torch.sigmoid(logit).numpy(), atol=1e-5)
    np.testing.assert_allclose(feats_onnx, feats.numpy(), atol=1e-4)


def test_training_is_reproducible(dataset: Path, tiny_run: tuple[Path, dict],
                                  tmp_path: Path) -> None:
    from ingest.roads.model.train import TrainConfig, train

    out, first = tiny_run
    again = train(dataset, tmp_path, TrainConfig(**TINY), progress=False)
    assert [h["loss"] for h in again["history"]] == [h["loss"] for h in first["history"]]
    x = np.random.default_rng(2).random((1, 3, 64, 64), dtype=np.float32)
    a = load_model(out / "model.onnx").session.run(["road"], {"rgb": x})[0]
    b = load_model(tmp_path / "model.onnx").session.run(["road"], {"rgb": x})[0]
    np.testing.assert_array_equal(a, b)


def test_validation_images_are_kept_out_of_training(dataset: Path) -> None:
    keep_out = file_sha16(dataset / "s1.png")
    names = [p["image"] for p in training_pairs(dataset, {keep_out})]
    assert names == ["s0.png", "s2.png"]


# --- the shipped model ------------------------------------------------------------------

@pytest.fixture(scope="module")
def shipped() -> object:
    path = MODEL_DIR / "model.onnx"
    assert path.is_file(), "models/roads-v1/model.onnx is part of the repository"
    return load_model(path)


def test_tiled_inference_equals_untiled_away_from_the_border(shipped: object) -> None:
    """Tile borders change a few probabilities by a few hundredths (a tile's zero padding
    reaches ~100 px into a U-Net's deepest layer), never which pixels are road."""
    rgb, _ = town(900, 100, 8, seed=3)
    x = normalise(rgb[:880, :].astype(np.float32) / 255)
    whole, _ = predict(shipped, x, tile=1024, overlap=64)
    tiled, _ = predict(shipped, x, tile=512, overlap=128)
    assert whole.shape == tiled.shape == x.shape[:2]
    inner = (slice(64, -64), slice(64, -64))
    diff = np.abs(whole[inner] - tiled[inner])
    assert diff.mean() < 1e-3, diff.mean()
    same = (whole[inner] >= shipped.threshold) == (tiled[inner] >= shipped.threshold)
    assert same.mean() > 0.999, same.mean()


def synthetic_image(rgb: np.ndarray, resolution_m: float = 1.0) -> Image:
    pixels = rgb.astype(np.float32) / 255
    return Image(pixels if pixels.ndim == 3 else pixels[..., None], None, None, None,
                 resolution_m)


def recall_of(result, road: np.ndarray) -> float:
    """Share of drawn road centre pixels within 3 px of an extracted edge."""
    from ingest.roads.evaluate import rasterize_lines
    from ingest.roads.skeleton import thin

    pred = rasterize_lines(result.source_lines(), road.shape)
    near = cv2.dilate(pred.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    centre = thin(road)
    return float((near & centre).sum() / centre.sum())


def test_zero_shot_finds_a_synthetic_town(shipped: object) -> None:
    rgb, road = town(400, 100, 8)
    result = extract_roads(synthetic_image(rgb))
    assert result.classifier == "model"
    assert recall_of(result, road) > 0.8


def test_single_band_and_16_bit_images_work_like_rgb(shipped: object) -> None:
    rgb, road = town(400, 100, 8)
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    as_rgb = recall_of(extract_roads(synthetic_image(rgb)), road)
    one_band = recall_of(extract_roads(synthetic_image(grey)), road)
    # 12-bit data in a 16-bit container: dark before the stretch.
    deep = Image((rgb.astype(np.float32) * 16 / 65535), None, None, None, 1.0)
    sixteen = recall_of(extract_roads(deep), road)
    # Grey loses the grass/asphalt hue, which this scene relies on: measured 0.46 vs 0.92.
    assert one_band > 0.35 and abs(sixteen - as_rgb) < 0.05, (as_rgb, one_band, sixteen)


def test_no_road_gives_an_empty_result_and_all_road_does_not_crash(shipped: object) -> None:
    grass, _ = render(Scene((300, 300), seed=9))
    assert extract_roads(synthetic_image(grass)).graph.edges == []
    asphalt = np.full((300, 300, 3), 118, np.uint8)
    result = extract_roads(synthetic_image(asphalt))
    assert len(result.graph.edges) <= 2


def test_a_resolution_far_from_the_model_is_refused(shipped: object) -> None:
    rgb, _ = town(200, 60, 4)
    with pytest.raises(RoadsInputError, match="coarser than"):
        extract_roads(synthetic_image(rgb, resolution_m=5.0))
    # Far finer is fine: averaged down to the model's grid.
    fine = cv2.resize(rgb, (1600, 1600), interpolation=cv2.INTER_LINEAR)
    assert extract_roads(synthetic_image(fine, 0.25)).frame.resolution_m == pytest.approx(1.0)


def test_adapted_needs_a_sample(shipped: object) -> None:
    rgb, _ = town(200, 60, 6)
    with pytest.raises(RoadsInputError, match="needs a training sample"):
        extract_roads(synthetic_image(rgb), None, ExtractParams(classifier="adapted"))


def test_cli_zero_shot_just_works(tmp_path: Path, shipped: object) -> None:
    rgb, _ = town(300, 90, 8)
    image, out = tmp_path / "town.png", tmp_path / "roads.geojson"
    cv2.imwrite(str(image), rgb[..., ::-1])
    result = CliRunner().invoke(main, ["extract-roads", str(image), "--resolution", "1",
                                       "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "model classifier" in result.output
    doc = json.loads(out.read_text())
    assert len(doc["features"]) >= 4 and doc["coordinate_space"] == "pixel"
