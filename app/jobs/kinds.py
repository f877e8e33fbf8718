"""The kinds of batch job, their parameters and the code that runs them: one table to extend.

A kind's parameters are a pydantic model, so ``POST /jobs`` and ``ugvmap ingest ... --queue``
refuse bad input (422 per field / one line) before anything is queued. ``runner`` names the
function a worker calls (``module:function``) instead of importing it: the HTTP service
validates and enqueues without loading the ingest code (``app`` never imports ``ingest``).
Adding a kind (the IPM ingest, say) is one model and one row in :data:`JOB_KINDS`.

Paths are paths on the workers' file system and must be absolute: a worker's working
directory is not the caller's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    ValidationError,
    field_validator,
    model_validator,
)
from pyproj import CRS
from pyproj.exceptions import CRSError

from app.db.models import LAYER_KINDS, SLUG_RE
from app.errors import InvalidValueError
from app.network.resurvey.matching import Tolerances
from app.network.settings import AttributeRules
from app.road_tuning import RoadTuning, SampleWidth


def _absolute(path: str) -> str:
    if "\x00" in path or not PurePosixPath(path).is_absolute():
        raise ValueError("must be an absolute path on the workers' file system")
    return path


def _lonlat_box(box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    x0, y0, x1, y1 = box
    if not (all(map(math.isfinite, box)) and -180 <= x0 < x1 <= 180 and -90 <= y0 < y1 <= 90):
        raise ValueError("must be [minlon, minlat, maxlon, maxlat] in degrees")
    return box


ServerPath = Annotated[str, StringConstraints(max_length=4096), AfterValidator(_absolute)]
Slug = Annotated[str, StringConstraints(pattern=SLUG_RE)]
LonLatBox = Annotated[tuple[float, float, float, float], AfterValidator(_lonlat_box)]


class JobParams(BaseModel):
    """Parameters of one job kind; unknown keys are refused (a typo must not be ignored)."""

    model_config = ConfigDict(extra="forbid")

    @property
    def target(self) -> str:
        """The layer or network the job writes (the ``target`` column of its row)."""
        raise NotImplementedError


class RasterParams(JobParams):
    """``ingest-raster``: one task per source, then the layer registered once."""

    sources: list[ServerPath] = Field(min_length=1, max_length=10_000)
    layer: Slug
    title: str | None = Field(default=None, max_length=200)
    kind: str = "orthophoto"
    crs: str | None = Field(default=None, max_length=2000)
    priority: int = Field(default=0, ge=-(2**31), lt=2**31)
    gcps: ServerPath | None = None
    gcp_method: Literal["poly1", "poly2", "tps"] = "poly1"
    replace: bool = False
    """Re-ingest files already in the layer in place of their old sources (else refused)."""
    add: bool = False
    """Add sources apart from the layer's area as separate areas (else refused)."""

    @field_validator("crs")
    @classmethod
    def _known_crs(cls, crs: str | None) -> str | None:
        if crs is not None:
            try:
                CRS.from_user_input(crs)
            except CRSError:
                raise ValueError("is not a CRS PROJ knows (e.g. EPSG:32633)") from None
        return crs

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, kind: str) -> str:
        if kind not in LAYER_KINDS:
            raise ValueError(f"must be one of {', '.join(LAYER_KINDS)}")
        return kind

    @model_validator(mode="after")
    def _one_source_with_gcps(self) -> RasterParams:
        if self.gcps is not None and len(self.sources) != 1:
            raise ValueError("gcps georeferences exactly one source")
        return self

    @property
    def target(self) -> str:
        """The layer."""
        return self.layer


def _tolerances(values: dict[str, float]) -> dict[str, float]:
    """Overrides of the re-survey matching's tolerances, checked when the job is asked for
    (a 422 naming the fault), not when a worker runs it."""
    unknown = sorted(set(values) - set(Tolerances.__dataclass_fields__))
    if unknown:
        raise ValueError(f"unknown tolerance {unknown[0][:40]!r}; known: "
                         + ", ".join(Tolerances.__dataclass_fields__))
    Tolerances(**values)
    return values


MatchTolerances = Annotated[dict[str, float], AfterValidator(_tolerances)]


class NetworkParams(JobParams):
    """``ingest-network``: a road file imported as a network."""

    file: ServerPath
    network: Slug
    replace: bool = False
    update: bool = False
    """Propose the file's changes as a change set (``--update``) instead of importing it."""
    tolerances: MatchTolerances = Field(default_factory=dict, max_length=20)

    @property
    def target(self) -> str:
        """The network."""
        return self.network


class RoadsParams(JobParams, RoadTuning, SampleWidth):
    """``ingest-roads``: a raster layer's roads extracted into a network; the tuning and the
    sample's line width are :mod:`app.road_tuning`'s fields (the CLI options' too)."""

    layer: Slug
    network: Slug
    replace: bool = False
    update: bool = False
    """Propose the extraction's changes as a change set (``--update``)."""
    tolerances: MatchTolerances = Field(default_factory=dict, max_length=20)
    train_boxes: list[LonLatBox] = Field(default_factory=list, max_length=1000)
    not_road_boxes: list[LonLatBox] = Field(default_factory=list, max_length=1000)
    train_lines: ServerPath | None = None
    labels: bool = True
    """Add the layer's stored labels to the sample."""
    review_labels: bool = True
    """Add the review of the networks extracted from the layer to the sample."""
    rules: AttributeRules | None = None
    """Attribute rules for this job on top of the network's (speed_kph, classes, ...)."""

    @property
    def target(self) -> str:
        """The network."""
        return self.network


class PreviewParams(JobParams):
    """``road-preview``: the roads of one window of a raster layer, extracted with the layer's
    labels as the sample and stored as a preview (``POST /layers/{slug}/previews`` queues
    it, having checked the window's size); nothing is written to any network."""

    layer: Slug
    bbox: LonLatBox
    layer_version: int = Field(ge=1, lt=2**31)
    """The layer version the preview is of: if the layer is re-ingested before the preview
    finishes, the preview fails and stores nothing."""

    @property
    def target(self) -> str:
        """The layer."""
        return self.layer


class LanesParams(JobParams):
    """``ingest-lanes``: a raster layer's lane markings stored as the lanes and lane boundaries
    of a network's segments."""

    layer: Slug
    network: Slug

    @property
    def target(self) -> str:
        """The network."""
        return self.network


@dataclass(frozen=True)
class JobKind:
    """A row of the table: how to check a job's parameters and what runs it."""

    params: type[JobParams]
    runner: str  # "module:function(job_id, params)", imported by the worker only


JOB_KINDS: dict[str, JobKind] = {
    "ingest-raster": JobKind(RasterParams, "ingest.queue.raster:run"),
    "ingest-network": JobKind(NetworkParams, "ingest.queue.runners:ingest_network"),
    "ingest-roads": JobKind(RoadsParams, "ingest.queue.runners:ingest_roads"),
    "road-preview": JobKind(PreviewParams, "ingest.queue.runners:road_preview"),
    "ingest-lanes": JobKind(LanesParams, "ingest.queue.runners:ingest_lanes"),
}


def validate_job(kind: Any, params: Any) -> JobParams:
    """The job's parameters as their model; 422 ``InvalidValue`` naming each bad field."""
    if not isinstance(kind, str) or kind not in JOB_KINDS:
        raise InvalidValueError(f"kind must be one of {', '.join(JOB_KINDS)}",
                                errors={"kind": f"must be one of {', '.join(JOB_KINDS)}"})
    if not isinstance(params, dict):
        raise InvalidValueError("params must be a JSON object",
                                errors={"params": "must be a JSON object"})
    try:
        return JOB_KINDS[kind].params.model_validate(params)
    except ValidationError as exc:
        errors: dict[str, str] = {}
        for err in exc.errors():
            field = ".".join(str(p) for p in ("params", *err["loc"]))
            errors.setdefault(field, err["msg"])
        raise InvalidValueError.naming(errors) from None
