"""The road model: training (CI-sized), ONNX export, tiled inference, zero-shot extraction.

Training (with the pretrained encoder), resuming a cut-off run and the ONNX-vs-torch check run
on synthetic scenes made here (known roads), so they need no shared data; the shipped model
(``models/roads-v2``) is exercised on synthetic towns at ground resolutions from 0.05 to 1.2 m,
on images smaller than one tile and along image borders and, in ``tests/test_roads_real.py``,
on the shared validation imagery.
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
from ingest.roads.model.runtime import MODEL_DIR, load_model, predict, quarter
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


TINY = {"crop_px": 64, "batch": 4, "epochs": 3, "steps_per_epoch": 10, "lr": 3e-3, "threads": 1}


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
    assert model.resolution_m == 0.5 and model.threshold == report["threshold"]
    assert report["config"]["arch"] == "lite0" and report["config"]["pretrained"]


def test_the_bigger_encoder_trains_and_exports_too(dataset: Path, tmp_path: Path) -> None:
    """``--arch lite2`` (the ablation of a bigger pretrained encoder): the same tiny run lowers
    the loss and writes a model whose ONNX answers like its weights."""
    from ingest.roads.model.train import TrainConfig, initial_loss, train

    config = TrainConfig(**TINY, arch="lite2")
    report = train(dataset, tmp_path, config, progress=False)
    losses = [h["loss"] for h in report["history"]]
    assert losses[-1] < 0.8 * initial_loss(config, dataset), losses
    x = np.random.default_rng(3).random((1, 3, 64, 96), dtype=np.float32)
    (prob, *_), (prob_onnx, *_) = _torch_and_onnx("lite2", tmp_path, x)
    np.testing.assert_allclose(prob_onnx, prob, atol=1e-5)
    assert "EfficientNet-Lite2" in (tmp_path / "README.md").read_text()


def _torch_and_onnx(arch: str, out: Path, x: np.ndarray
                    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(probability, features, encoder context) of ``x`` from ``out``'s weights.pt run by
    torch, and from its model.onnx run by onnxruntime."""
    from ingest.roads.model.net import build

    net = build(arch, pretrained=False)
    net.load_state_dict(torch.load(out / "weights.pt"))
    net.eval()
    with torch.no_grad():
        logit, feats, context = net.with_context(torch.from_numpy(x))
    return ([torch.sigmoid(logit).numpy(), feats.numpy(), context.numpy()],
            load_model(out / "model.onnx").session.run(None, {"rgb": x}))


def test_onnx_and_torch_agree(tiny_run: tuple[Path, dict]) -> None:
    out, _ = tiny_run
    x = np.random.default_rng(1).random((2, 3, 96, 160), dtype=np.float32)
    (prob, feats, context), (prob_onnx, feats_onnx, context_onnx) = _torch_and_onnx(
        "lite0", out, x)
    np.testing.assert_allclose(prob_onnx, prob, atol=1e-5)
    np.testing.assert_allclose(feats_onnx, feats, atol=1e-4)
    # The encoder's stride 4, 8 and 16 maps at stride 4 (24 + 40 + 112 channels)
    assert context_onnx.shape == (2, 176, 24, 40)
    np.testing.assert_allclose(context_onnx, context, atol=1e-4)
    assert load_model(out / "model.onnx").feature_outputs == ("features", "context")


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


def test_a_cut_off_run_resumes_to_the_same_model(dataset: Path, tiny_run: tuple[Path, dict],
                                                 tmp_path: Path) -> None:
    """Stopped after its first epoch (a time limit of 0), then resumed: the same losses,
    hold-out scores and weights as the run that was never cut."""
    from ingest.roads.model.train import TrainConfig, train

    out, uncut = tiny_run
    cut = train(dataset, tmp_path, TrainConfig(**TINY), progress=False, time_limit_min=0)
    assert [h["epoch"] for h in cut["history"]] == [1]
    assert (tmp_path / "model.onnx").is_file()  # usable already
    resumed = train(dataset, tmp_path, TrainConfig(**TINY), progress=False, resume=True)
    assert [h["loss"] for h in resumed["history"]] == [h["loss"] for h in uncut["history"]]
    assert resumed["holdout"] == uncut["holdout"]
    a, b = torch.load(out / "weights.pt"), torch.load(tmp_path / "weights.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(RoadsInputError, match="other settings"):
        train(dataset, tmp_path, TrainConfig(**{**TINY, "lr": 1e-3}), progress=False,
              resume=True)


def test_validation_images_are_kept_out_of_training(dataset: Path) -> None:
    keep_out = file_sha16(dataset / "s1.png")
    names = [p["image"] for p in training_pairs(dataset, {keep_out})]
    assert names == ["s0.png", "s2.png"]


# --- the shipped model ------------------------------------------------------------------

@pytest.fixture(scope="module")
def shipped() -> object:
    path = MODEL_DIR / "model.onnx"
    assert path.is_file(), "models/roads-v2/model.onnx is part of the repository"
    return load_model(path)


def test_tiled_inference_equals_untiled_away_from_the_border(shipped: object) -> None:
    """Tile borders change a few probabilities by a few hundredths, never which pixels are
    road: the stride-16 encoder sees further than the 128 px overlap, so a tile's predictions
    near its edge weigh almost nothing (cubic blend ramp; with a linear one the mean change
    was 6x larger and 0.2 % of decisions differed)."""
    rgb, _ = town(900, 100, 8, seed=3)
    x = normalise(rgb[:880, :].astype(np.float32) / 255)
    whole, _ = predict(shipped, x, tile=1024, overlap=64)
    tiled, _ = predict(shipped, x, tile=512, overlap=128)
    assert whole.shape == tiled.shape == x.shape[:2]
    inner = (slice(64, -64), slice(64, -64))
    diff = np.abs(whole[inner] - tiled[inner])
    assert diff.mean() < 1e-3 and np.percentile(diff, 99) < 0.02, diff.mean()
    same = (whole[inner] >= shipped.threshold) == (tiled[inner] >= shipped.threshold)
    assert same.mean() > 0.999, same.mean()


def test_features_come_at_quarter_resolution_aligned_with_the_image(shipped: object) -> None:
    """What the adaptation reads is stitched at a quarter of the resolution: the decoder's
    features, cell (i, j) the mean of pixels 4i..4i+3, 4j..4j+3 of the network's own output
    (odd edges included), then (asked for) the encoder's context as the network gives it at
    stride 4;
    tiling changes them as little as it changes the probability. They come as one C-ordered
    array, so the adaptation reads the channels as a matrix without copying 400 MB of them
    (a view into the padded grid cost a Massachusetts tile 0.8 s)."""
    rgb, _ = town(300, 100, 8, seed=5)
    x = normalise(rgb[:283, :277].astype(np.float32) / 255)
    prob, feats = predict(shipped, x, features=True, context=True, tile=512, overlap=64)
    assert prob.shape == (283, 277) and feats is not None
    assert feats.shape == (16 + 176, 71, 70)
    decoder_only = predict(shipped, x, features=True, tile=512, overlap=64)[1]
    assert decoder_only is not None
    np.testing.assert_array_equal(decoder_only, feats[:16])
    # One tile of 416 px (the image and its overlap rounded up to the 16 px grid), the
    # image reflected into it as predict pads it.
    padded = np.pad(x, ((64, 416 - 283 - 64), (64, 416 - 277 - 64), (0, 0)), mode="reflect")
    decoder, context = shipped.session.run(["features", "context"],
                                           {"rgb": padded.transpose(2, 0, 1)[None].copy()})
    # A last cell past the image's edge also holds the next (padding) pixels' features.
    np.testing.assert_allclose(feats[:16], quarter(decoder[0][:, 64:64 + 284, 64:64 + 280]),
                               atol=1e-5)
    np.testing.assert_allclose(feats[16:], context[0][:, 16:16 + 71, 16:16 + 70], atol=1e-5)
    _, tiled = predict(shipped, x, features=True, context=True, tile=256, overlap=64)
    assert tiled is not None and tiled.shape == feats.shape
    assert feats.flags.c_contiguous and tiled.flags.c_contiguous
    inner = (slice(None), slice(16, -16), slice(16, -16))
    assert np.abs(tiled[inner] - feats[inner]).mean() < 0.05 * np.abs(feats[inner]).mean()


def synthetic_image(rgb: np.ndarray, resolution_m: float = 1.0) -> Image:
    pixels = rgb.astype(np.float32) / 255
    return Image(pixels if pixels.ndim == 3 else pixels[..., None], None, None, None,
                 resolution_m)


def recall_of(result, road: np.ndarray, radius_px: int = 3) -> float:
    """Share of drawn road centre pixels within ``radius_px`` of an extracted edge."""
    from ingest.roads.evaluate import rasterize_lines
    from ingest.roads.skeleton import thin

    pred = rasterize_lines(result.source_lines(), road.shape)
    side = 2 * radius_px + 1
    near = cv2.dilate(pred.astype(np.uint8), np.ones((side, side), np.uint8)).astype(bool)
    centre = thin(road)
    return float((near & centre).sum() / centre.sum())


@pytest.fixture(scope="module")
def town_roads(shipped: object) -> tuple[np.ndarray, np.ndarray, object]:
    """A 400 m synthetic town (rgb, road) and its zero-shot extraction, run once: the first
    test checks it, the second compares single-band and 16-bit extractions against it."""
    rgb, road = town(400, 100, 8)
    return rgb, road, extract_roads(synthetic_image(rgb))


def test_zero_shot_finds_a_synthetic_town(town_roads: tuple) -> None:
    _, road, result = town_roads
    assert result.classifier == "model"
    assert recall_of(result, road) > 0.8


def test_single_band_and_16_bit_images_work_like_rgb(shipped: object, town_roads: tuple
                                                    ) -> None:
    """12-bit data in a 16-bit container (dark before the stretch) gives what 8-bit RGB gives;
    a single band is read as grey. How well grey imagery works is measured on a real tile
    (``tests/test_roads_real.py``): this cartoon town in grey is one tone of grass against
    roofs and roads of one lighter tone, which says little about panchromatic imagery."""
    rgb, road, rgb_result = town_roads
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    as_rgb = recall_of(rgb_result, road)
    one_band = extract_roads(synthetic_image(grey))
    assert one_band.frame.resolution_m == pytest.approx(shipped.resolution_m)
    deep = Image((rgb.astype(np.float32) * 16 / 65535), None, None, None, 1.0)
    sixteen = recall_of(extract_roads(deep), road)
    assert as_rgb > 0.8 and abs(sixteen - as_rgb) < 0.05, (as_rgb, sixteen)


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
    result = extract_roads(synthetic_image(fine, 0.125))
    assert result.frame.resolution_m == pytest.approx(shipped.resolution_m)


@pytest.mark.parametrize("resolution_m", [0.05, 0.2, 1.2])
def test_roads_are_found_from_005_to_12_m_per_pixel(shipped: object, resolution_m: float
                                                   ) -> None:
    """The same 7 m wide roads drawn at three ground resolutions: enlarged (1.2 m) or averaged
    down (0.05 m) to the model's grid, each is found."""
    size_m, spacing_m, width_m = 240, 80, 7
    px = round(size_m / resolution_m)
    scene = grid_scene(px, round(spacing_m / resolution_m), max(2, round(width_m / resolution_m)),
                       seed=5)
    rgb, road = render(scene)
    result = extract_roads(synthetic_image(rgb, resolution_m))
    assert recall_of(result, road, max(3, round(1.5 / resolution_m))) > 0.8, resolution_m


def test_an_image_smaller_than_one_tile_is_reflected_not_zero_padded(shipped: object) -> None:
    """A 90 x 70 m image (far under the network's receptive field): the road across it is
    found end to end, edge to edge."""
    rgb, road = render(Scene((140, 180), roads=[[(0, 70), (179, 62)]], road_width_px=14,
                             seed=2))
    result = extract_roads(synthetic_image(rgb, 0.5))
    assert recall_of(result, road) > 0.8
    xs = np.concatenate([line[:, 0] for line in result.source_lines()])
    assert xs.min() < 15 and xs.max() > 165, (xs.min(), xs.max())


def test_a_road_along_the_image_border_is_found(shipped: object) -> None:
    """A road whose edge is the image's top edge: half of its cross-section is outside."""
    rgb, road = render(Scene((300, 400), roads=[[(0, 2), (399, 2)], [(200, 2), (200, 299)]],
                             road_width_px=14, seed=4))
    result = extract_roads(synthetic_image(rgb, 0.5))
    assert recall_of(result, road) > 0.75


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


@pytest.mark.parametrize(("flags", "native"), [
    ("fpu sse avx2 fma", False), ("avx2 avx512f avx512_bf16", True), ("avx2 amx_bf16", True)])
def test_bf16_only_where_the_cpu_does_it(tmp_path: Path, flags: str, native: bool) -> None:
    """The recipe's bf16 autocast, emulated on an AVX2-only EPYC, took 225 s for one batch
    (fp32: ~6 s): ``roads train`` uses it by default only where the CPU has it."""
    from ingest.roads.model.train import native_bf16

    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(f"processor\t: 0\nflags\t\t: {flags}\n", encoding="utf-8")
    assert native_bf16(cpuinfo) is native
    assert native_bf16(tmp_path / "missing") is False


def test_a_config_trains_in_bf16_only_where_the_cpu_does_it() -> None:
    """Not only the CLI: a ``TrainConfig`` made in code (the tests' tiny runs, a bench) trains
    in bf16 only on such a CPU (always bf16, each tiny run here took 47 s instead of 10)."""
    from ingest.roads.model.train import TrainConfig, native_bf16

    assert TrainConfig().bf16 is native_bf16()
    assert TrainConfig(bf16=True).bf16 is True


@pytest.mark.parametrize("weight", ["rural", "rural=x", "rural=0", "=2"])
def test_a_bad_source_weight_is_refused_before_training(tmp_path: Path, weight: str) -> None:
    result = CliRunner().invoke(main, ["roads", "train", "--data", str(tmp_path), "--out",
                                       str(tmp_path / "out"), "--source-weight", weight])
    assert result.exit_code == 2 and "--source-weight" in result.output, result.output
    assert not (tmp_path / "out").exists()
