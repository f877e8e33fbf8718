"""The road-extraction knobs a user may set, with their defaults and bounds: one definition.

Why one model: the knobs used to be written four times (the CLI options, the job API's
bounds, the queue runner's mapping and the pipeline's defaults), and the copies had drifted
apart (``--simplify`` defaulted to 0.5 m on the command line, 0.1 m everywhere else). Now the
``extract-roads`` / ``ingest roads`` options are built from these fields (:mod:`cli.fields`),
the ``ingest-roads`` job's parameters inherit them (so ``POST /jobs`` checks the same bounds
and documents the same defaults), and the pipeline takes its defaults from
:data:`DEFAULT_TUNING` (:func:`ingest.roads.pipeline.tuned_params`). The descriptions are the
CLI's help texts and the API schema's descriptions.

It lives in ``app`` and needs only pydantic because the HTTP service validates jobs without
loading the ingest code (``app`` never imports ``ingest``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

#: The road extraction classifiers (``ingest.roads.pipeline`` runs them).
Classifier = Literal["auto", "model", "adapted", "learned", "spectral"]


class RoadTuning(BaseModel):
    """The pipeline's tuning options, shared by ``extract-roads`` and ``ingest roads`` (and
    their job); sizes in metres."""

    classifier: Classifier = Field(
        default="auto",
        description="auto = the road model, adapted to the training sample when one is given; "
                    "learned/spectral = per-job classifiers (need a sample).")
    k: float = Field(
        default=3.0, gt=0, le=100,
        description="Spectral: keep pixels within k x mean training distance to the colour "
                    "line.")
    work_resolution: float = Field(
        default=0.5, ge=0, le=100,
        description="learned/spectral (and ipm-mosaic layers): average finer images down to "
                    "this many metres per pixel (0 = keep source); the road model uses its "
                    "own.")
    spur_max: float = Field(
        default=15.0, ge=0, le=1000, description="Longest hair (m) pruned from the skeleton.")
    simplify: float = Field(
        default=0.1, ge=0, le=100, description="RDP tolerance (m) for edge geometry.")


class SampleWidth(BaseModel):
    """How wide the road is around a sample's known centerlines (``ingest roads``)."""

    line_width: float = Field(
        default=6.0, gt=0, le=100,
        description="Road width (m) around --train-lines centerlines.")


DEFAULT_TUNING = RoadTuning()
DEFAULT_SAMPLE_WIDTH = SampleWidth()
