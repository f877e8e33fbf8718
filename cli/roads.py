"""``ugvmap extract-roads`` / ``evaluate-roads`` (no database) and ``ugvmap ingest roads``.

Heavy imports (OpenCV, scikit-learn) happen inside the commands so ``ugvmap --help`` stays
instant. User mistakes are :class:`~app.errors.UserError` (``RoadsInputError`` among them),
shown as one line by the CLI root.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import click

from app.errors import UserError
from app.road_tuning import RoadTuning, SampleWidth
from cli.fields import field_option, model_options
from cli.jobs import absolute, enqueue_job, queue_option
from cli.resurvey import check_update, update_options
from cli.rules import RULE_OPTIONS, given_rules, rule_options

if TYPE_CHECKING:
    from ingest.roads.pipeline import ExtractParams

#: The pipeline's tuning options, shared by ``extract-roads`` and ``ingest roads``.
extraction_options = model_options(RoadTuning)


@contextmanager
def _memory_hint() -> Iterator[None]:
    """Running out of memory on a big image is a user-fixable setting, not a crash."""
    try:
        yield
    except MemoryError as exc:
        raise UserError("out of memory: try a coarser --work-resolution") from exc


def _box(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
         ) -> list[tuple[int, int, int, int]]:
    boxes = []
    for value in values:
        try:
            x0, y0, x1, y1 = (int(float(v)) for v in value.split(","))
        except ValueError:
            raise click.BadParameter(f"{value!r} is not x0,y0,x1,y1 (pixels)") from None
        boxes.append((x0, y0, x1, y1))
    return boxes


def extract_params(**tuning: Any) -> ExtractParams:
    """The pipeline parameters from the shared tuning options (:data:`extraction_options`)."""
    from ingest.roads.pipeline import tuned_params

    return tuned_params(RoadTuning(**tuning))


@click.command("extract-roads")
@click.argument("image", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--train-box", "train_boxes", multiple=True, callback=_box,
              help="Box of road x0,y0,x1,y1 in source pixels (repeatable).")
@click.option("--not-road-box", "not_road_boxes", multiple=True, callback=_box,
              help="Box of not-road x0,y0,x1,y1 (repeatable); enables the learned classifier.")
@click.option("--train-mask", type=click.Path(path_type=Path, dir_okay=False),
              help="Label image, same size: 255 = road, 128 = not road, 0 = unlabelled.")
@extraction_options
@click.option("--resolution", type=float, help="Metres per pixel (required without georeference).")
@click.option("--out", "out_path", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output GeoJSON (LineStrings; nodes in the 'nodes' member).")
@click.option("--debug-dir", type=click.Path(path_type=Path, file_okay=False),
              help="Write binary / cleaned / houses-removed / skeleton PNGs here.")
def extract_roads(image: Path, train_boxes: list, not_road_boxes: list, train_mask: Path | None,
                  resolution: float | None, out_path: Path, debug_dir: Path | None,
                  **tuning: Any) -> None:
    """Extract the road network of IMAGE into GeoJSON.

    With no sample the shipped road model runs zero-shot; a sample (--train-box,
    --not-road-box, --train-mask) adapts it to this job. An image without roads gives an
    empty FeatureCollection (and says so), not an error.
    """
    from ingest.roads.classify import training_labels
    from ingest.roads.georef import read_band, read_image
    from ingest.roads.pipeline import extract_roads

    with _memory_hint():
        img = read_image(image, resolution)
        mask = read_band(train_mask)[0] if train_mask else None
        labels = (training_labels(img.pixels.shape[:2], train_boxes, not_road_boxes, mask)
                  if train_boxes or not_road_boxes or mask is not None else None)
        result = extract_roads(img, labels, extract_params(**tuning), debug_dir=debug_dir,
                               progress=sys.stderr.isatty())
        try:
            out_path.write_text(json.dumps(result.geojson()))
        except OSError as exc:
            raise UserError(f"cannot write {out_path}: {exc.strerror}") from exc
    if not result.graph.edges:
        click.echo(f"no road found in {image} ({result.classifier} classifier)"
                   + (f"; see the images in {debug_dir}" if debug_dir else " (see --debug-dir)"),
                   err=True)
    junctions = sum(n.is_junction for n in result.graph.nodes)
    click.echo(f"{len(result.graph.edges)} segments, {len(result.graph.nodes)} nodes "
               f"({junctions} junctions), {result.classifier} classifier -> {out_path}")
    if result.sample_note:
        click.echo(result.sample_note)


@click.command("evaluate-roads")
@click.argument("pred", type=click.Path(path_type=Path, dir_okay=False))
@click.argument("gt", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--resolution", type=float,
              help="Metres per pixel (pixel inputs), or grid size for two map-coordinate files "
                   "(default 0.5).")
@click.option("--max-radius", type=int, default=20, show_default=True,
              help="Largest buffer radius in pixels (radii 1..N).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def evaluate_roads(pred: Path, gt: Path, resolution: float | None, max_radius: int,
                   as_json: bool) -> None:
    """Buffer precision / recall / quality of PRED centerlines against GT.

    Each of PRED and GT is a GeoJSON of centerlines or a mask image (road >= 128).
    """
    from ingest.roads.evaluate import buffer_scores, load_centerlines, scores_json

    with _memory_hint():
        if max_radius < 1:
            raise UserError("--max-radius must be at least 1")
        p, g, res = load_centerlines(pred, gt, resolution)
        if not g.any():
            raise UserError(f"{gt}: the ground truth has no road")
        scores = buffer_scores(p, g, range(1, max_radius + 1), res)
    if as_json:
        click.echo(scores_json(scores))
        return
    click.echo(f"{'radius px':>9} {'radius m':>8} {'precision':>9} {'recall':>7} {'quality':>7}")
    for s in scores:
        metres = f"{s.radius_m:8.2f}" if s.radius_m is not None else f"{'-':>8}"
        click.echo(f"{s.radius_px:9.0f} {metres} {s.precision:9.3f} {s.recall:7.3f} "
                   f"{s.quality:7.3f}")


def _lonlat_box(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
                ) -> list[tuple[float, float, float, float]]:
    boxes = []
    for value in values:
        try:
            x0, y0, x1, y1 = (float(v) for v in value.split(","))
        except ValueError:
            raise click.BadParameter(f"{value!r} is not minlon,minlat,maxlon,maxlat") from None
        if not (-180 <= x0 < x1 <= 180 and -90 <= y0 < y1 <= 90):
            raise click.BadParameter(f"{value!r} is not minlon,minlat,maxlon,maxlat in degrees")
        boxes.append((x0, y0, x1, y1))
    return boxes


@click.command("roads")
@click.option("--layer", "slug", required=True, help="Raster layer to extract roads from.")
@click.option("--network", required=True, help="Network to write (created if new).")
@click.option("--train-box", "train_boxes", multiple=True, callback=_lonlat_box,
              help="Box of road minlon,minlat,maxlon,maxlat (repeatable).")
@click.option("--not-road-box", "not_road_boxes", multiple=True, callback=_lonlat_box,
              help="Box of not-road minlon,minlat,maxlon,maxlat (repeatable).")
@click.option("--train-lines", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="GeoJSON of known road centerlines (lon/lat): near = road, far = not road.")
@field_option("line_width", SampleWidth.model_fields["line_width"])
@extraction_options
@rule_options
@click.option("--no-labels", "use_labels", is_flag=True, default=True, flag_value=False,
              help="Leave out the layer's stored labels (`ugvmap layers labels`).")
@click.option("--no-review-labels", "use_review", is_flag=True, default=True,
              flag_value=False,
              help="Leave out the review of the networks extracted from the layer (deleted "
                   "extracted segments: not road; drawn, moved or edited ones: road).")
@click.option("--replace", is_flag=True, help="Replace the network if it exists.")
@update_options
@queue_option
def ingest_roads(slug: str, network: str, train_boxes: list, not_road_boxes: list,
                 train_lines: Path | None, line_width: float, use_labels: bool,
                 use_review: bool, replace: bool, update: bool, tolerances: dict[str, float],
                 queued: bool, **options: Any) -> None:
    """Extract the roads of raster layer SLUG into road network NETWORK (PostGIS).

    The road model runs zero-shot without a sample and adapts to one when given; on an
    ipm-mosaic layer the drive's own trajectory is the sample. The layer's stored labels and
    the review of the networks extracted from it are added to the sample (the report says
    how many of each). Attributes (lanes, class,
    speed, junctions, confidence) follow the network's rules (`ugvmap network settings`),
    overridden for this job by the rule options.
    """
    check_update(replace, update, tolerances)
    rules = given_rules(options)
    tuning = {k: v for k, v in options.items() if k not in RULE_OPTIONS}
    if queued:
        enqueue_job("ingest-roads", {
            "layer": slug, "network": network, "replace": replace, "update": update,
            "tolerances": tolerances, "train_boxes": train_boxes,
            "not_road_boxes": not_road_boxes, "train_lines": absolute(train_lines),
            "line_width": line_width, "labels": use_labels, "review_labels": use_review,
            "rules": rules.overrides(), **tuning})
        return
    from app.db.session import session_scope
    from app.jobs.recorder import JobRecorder
    from ingest.roads.layer import ingest_layer_roads
    from ingest.roads.sample import given_sample

    with _memory_hint():
        sample = given_sample(train_boxes, not_road_boxes, train_lines, line_width)
        with JobRecorder("ingest-roads", network,
                         {"layer": slug, **tuning, "rules": rules.overrides()}), \
                session_scope() as session:
            done = ingest_layer_roads(session, slug, network, sample, extract_params(**tuning),
                                      rules=rules, replace=replace,
                                      progress=sys.stderr.isatty(), labels=use_labels,
                                      review_labels=use_review, update=update,
                                      tolerances=tolerances)
    for line in done.lines():
        click.echo(line)


@click.group("roads")
def roads() -> None:
    """The road model: train it (needs the ``train`` extra: torch)."""


def _name_numbers(values: tuple[str, ...]) -> dict[str, float]:
    """``NAME=NUMBER`` options (repeatable) as a dict."""
    out = {}
    for value in values:
        name, _, number = value.partition("=")
        try:
            out[name] = float(number)
        except ValueError:
            raise click.BadParameter(f"{value!r}: expected NAME=NUMBER") from None
    return out


def _augment_option(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
                    ) -> dict[str, float]:
    from dataclasses import fields

    from ingest.roads.model.data import Augment

    known = {f.name for f in fields(Augment)}
    out = _name_numbers(values)
    for name in out:
        if name not in known:
            raise click.BadParameter(f"{name!r}: not one of {', '.join(sorted(known))}")
    return out


def _source_weight_option(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
                          ) -> dict[str, float]:
    out = _name_numbers(values)
    for name, weight in out.items():
        if not name or not weight > 0:
            raise click.BadParameter(f"{name}={weight}: a source name and a weight above 0")
    return out


@roads.command("train")
@click.option("--data", type=click.Path(path_type=Path, file_okay=False, exists=True),
              required=True, help="Folder with pairs.json (image, mask, m_per_px per pair).")
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False),
              required=True, help="Model folder to write (model.onnx, README.md, ...).")
@click.option("--exclude-images", "exclude_dirs", multiple=True,
              type=click.Path(path_type=Path, file_okay=False, exists=True),
              help="Never train on images byte-identical to one under this folder "
                   "(the validation set; repeatable).")
@click.option("--arch", type=click.Choice(["lite0", "lite2", "unet"]), default="lite0",
              show_default=True,
              help="lite0: pretrained EfficientNet-Lite0 encoder (v2); lite2: the bigger "
                   "EfficientNet-Lite2 (an ablation); unet: v1's, from scratch.")
@click.option("--scratch", is_flag=True, help="lite0/lite2: random encoder weights (the "
              "ablation).")
@click.option("--epochs", type=int, default=30, show_default=True)
@click.option("--steps-per-epoch", type=int, default=100, show_default=True)
@click.option("--batch", type=int, default=8, show_default=True)
@click.option("--crop", type=int, default=256, show_default=True, help="Crop side in pixels.")
@click.option("--resolution", type=float, default=0.5, show_default=True,
              help="Ground resolution (m/px) the model works at.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--augment", "augment", multiple=True, callback=_augment_option,
              metavar="NAME=VALUE",
              help="Change one augmentation (probability or range; repeatable), e.g. "
                   "jpeg_p=0 switches JPEG artefacts off.")
@click.option("--max-scenes", type=int, help="Use only the first N scenes (quick runs).")
@click.option("--source-weight", "source_weight", multiple=True, callback=_source_weight_option,
              metavar="SOURCE=WEIGHT",
              help="Draw scenes of this pairs.json source WEIGHT times as often (repeatable), "
                   "e.g. rural_cn_hq=10 for a kind the rest of the data lacks.")
@click.option("--threads", type=int, default=2, show_default=True,
              help="CPU threads (1 trains faster on a machine busy with other work).")
@click.option("--resume", is_flag=True,
              help="Carry on from OUT/checkpoint.pt (a run cut off; same options).")
@click.option("--time-limit", type=float, metavar="MINUTES",
              help="Stop after the first epoch that ends past this (carry on with --resume).")
@click.option("--init", "init", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="Start from this weights.pt of an earlier run of the same --arch "
                   "(fine-tuning with a new recipe).")
@click.option("--lr", type=float, default=2e-3, show_default=True,
              help="Peak learning rate of the one-cycle schedule (lower to fine-tune).")
@click.option("--bf16/--fp32", "bf16", default=None,
              help="bfloat16 autocast or float32 (default: bf16 where the CPU does it natively, "
                   "AVX-512 BF16 or AMX; emulated, a batch took ~80x longer).")
def roads_train(data: Path, out_dir: Path, exclude_dirs: tuple[Path, ...], arch: str,
                scratch: bool, epochs: int, steps_per_epoch: int, batch: int, crop: int,
                resolution: float, seed: int, augment: dict[str, float],
                max_scenes: int | None, source_weight: dict[str, float], threads: int, resume: bool,
                time_limit: float | None, init: Path | None, lr: float,
                bf16: bool | None) -> None:
    """Train the road segmentation model and export it to ONNX with its model card."""
    try:
        from ingest.roads.model.train import TrainConfig, native_bf16, train
    except ImportError as exc:
        raise UserError(f"training needs torch: pip install -e '.[train]' ({exc})") from exc
    from dataclasses import replace

    from ingest.roads.model.data import Augment, file_sha16, image_hashes
    from ingest.roads.model.net import Arch

    if crop % 16:
        raise UserError("--crop must be a multiple of 16 (the network's grid)")
    with _memory_hint():
        exclude = sorted(set().union(*(image_hashes(d) for d in exclude_dirs)))
        config = TrainConfig(arch=cast(Arch, arch), pretrained=not scratch, resolution_m=resolution,
                             crop_px=crop, batch=batch, epochs=epochs,
                             steps_per_epoch=steps_per_epoch, seed=seed, max_scenes=max_scenes,
                             threads=threads, augment=replace(Augment(), **augment),
                             exclude=exclude, lr=lr, source_weight=source_weight,
                             bf16=native_bf16() if bf16 is None else bf16,
                             init=None if init is None else str(init.resolve()),
                             init_sha16=None if init is None else file_sha16(init))
        report = train(data, out_dir, config, progress=True, resume=resume,
                       time_limit_min=time_limit)
    click.echo(f"best epoch {report['best_epoch']}: hold-out F1 {report['holdout']['f1']:.3f} "
               f"at threshold {report['threshold']:.2f}; {report['train_minutes']:.1f} min -> "
               f"{out_dir / 'model.onnx'}")
