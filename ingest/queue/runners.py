"""Job kinds that run as one task: the same work as their ``ugvmap ingest`` command.

Each commits its result and the job's success in one transaction
(:func:`~app.jobs.rows.succeed_in`): a worker killed before the commit left nothing, and the
retried task redoes it; a retry after the commit finds the job succeeded and does nothing.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.session import get_engine, session_scope
from app.jobs.kinds import LanesParams, NetworkParams, PreviewParams, RoadsParams
from app.jobs.lease import Lease
from app.jobs.rows import record_progress, succeed_in

if TYPE_CHECKING:
    from ingest.roads.taught import Taught


def ingest_network(job_id: int, params: NetworkParams) -> None:
    """Import a road file as a network (``ugvmap ingest network``)."""
    from ingest.network import import_network

    with Lease(get_engine(), job_id), session_scope() as session:
        if params.update:
            from app.network.resurvey.matching import Tolerances
            from ingest.network.update import update_from_file

            proposed = update_from_file(session, Path(params.file), params.network,
                                        tol=Tolerances(**params.tolerances))
            succeed_in(session.connection(), job_id,
                       f"change set {proposed['id']}: {proposed['counts']}")
            return
        summary = import_network(session, Path(params.file), params.network,
                                 replace=params.replace)
        succeed_in(session.connection(), job_id,
                   f"network {summary.network}: {summary.segments} segments, "
                   f"{summary.nodes} nodes")


def ingest_roads(job_id: int, params: RoadsParams) -> None:
    """Extract a raster layer's roads into a network (``ugvmap ingest roads``)."""
    from ingest.roads.layer import ingest_layer_roads
    from ingest.roads.pipeline import tuned_params
    from ingest.roads.sample import given_sample

    sample = given_sample(params.train_boxes, params.not_road_boxes,
                          Path(params.train_lines) if params.train_lines else None,
                          params.line_width)
    tuning = tuned_params(params)
    with Lease(get_engine(), job_id), session_scope() as session:
        done = ingest_layer_roads(session, params.layer, params.network, sample, tuning,
                                  rules=params.rules, replace=params.replace,
                                  update=params.update, tolerances=params.tolerances,
                                  labels=params.labels, review_labels=params.review_labels)
        succeed_in(session.connection(), job_id, "; ".join(done.lines()))


def ingest_lanes(job_id: int, params: LanesParams) -> None:
    """Store a layer's lane markings as a network's lanes (``ugvmap ingest lanes``)."""
    from app.jobs.recorder import Throttle
    from ingest.lanes.layer import ingest_layer_lanes

    throttle = Throttle(lambda f, m: record_progress(job_id, f, m))
    with Lease(get_engine(), job_id), session_scope() as session:
        done = ingest_layer_lanes(session, params.layer, params.network, throttle)
        succeed_in(session.connection(), job_id, "; ".join(done.lines()))


def road_preview(job_id: int, params: PreviewParams) -> None:
    """Extract the roads of a window of a layer (``POST /layers/{slug}/previews``) and store
    them as the preview, unless the layer was re-ingested since the preview was asked for:
    the version is checked under a share lock on the layer row in the transaction that
    stores the result, so a re-ingest committing meanwhile either came first (the preview
    fails, nothing stored) or waits for the preview to commit."""
    from ingest.roads.layer import window_roads
    from ingest.roads.pipeline import ExtractParams
    from ingest.roads.taught import taught

    started = time.monotonic()
    with Lease(get_engine(), job_id):
        record_progress(job_id, 0.1, "extracting the roads of the view")
        with session_scope() as session:
            team = taught(session, params.layer)
            try:
                lines, extraction = window_roads(session, params.layer, params.bbox,
                                                 team.sample, ExtractParams())
            except Exception:  # a re-ingest may have taken the files: say that instead
                _refuse_stale(session, params)
                raise
        record_progress(job_id, 0.9, f"storing {len(lines)} roads")
        features = [{"type": "Feature", "geometry": {"type": "LineString",
                                                     "coordinates": line.coords},
                     "properties": dataclasses.asdict(line.attributes)} for line in lines]
        result = {"type": "FeatureCollection", "features": features,
                  "classifier": extraction.classifier, "sample": extraction.sample_note,
                  "labels": taught_counts(team),
                  "seconds": round(time.monotonic() - started, 2)}
        with session_scope() as session:
            layer_id = _refuse_stale(session, params)
            session.execute(text(
                "INSERT INTO road_previews (job_id, layer_id, layer_version, bbox, result) "
                "VALUES (:id, :layer, :version, ST_MakeEnvelope(:x0, :y0, :x1, :y1, 4326), "
                "CAST(:result AS jsonb))"),
                {"id": job_id, "layer": layer_id, "version": params.layer_version,
                 "x0": params.bbox[0], "y0": params.bbox[1], "x1": params.bbox[2],
                 "y1": params.bbox[3], "result": json.dumps(result)})
            succeed_in(session.connection(), job_id,
                       f"{len(lines)} roads in {result['seconds']} s "
                       f"({extraction.classifier}"
                       + (f"; {extraction.sample_note})" if extraction.sample_note else ")"))


def _refuse_stale(session: Session, params: PreviewParams) -> int:
    """The layer's id, its row share-locked until the transaction ends; refused when the
    layer is gone or no longer at the preview's version."""
    from ingest.roads import RoadsInputError

    row = session.execute(text("SELECT id, version FROM layers WHERE slug = :slug FOR SHARE"),
                          {"slug": params.layer}).first()
    if row is None:
        raise RoadsInputError(f"layer {params.layer!r} was deleted while the preview ran")
    if row.version != params.layer_version:
        raise RoadsInputError(
            f"layer {params.layer!r} was re-ingested while the preview ran (version "
            f"{params.layer_version}, now {row.version}): nothing stored; preview again")
    return int(row.id)


def taught_counts(team: Taught) -> dict[str, int]:
    """How many road and not-road labels (the layer's and its review's) a preview learned
    from, for the web map's summary."""
    labels, review = team.labels, team.review
    road = (labels.road_lines if labels else 0) + (
        review.drawn + review.moved + review.confirmed if review else 0)
    not_road = (labels.not_road_lines + labels.not_road_areas if labels else 0) + (
        review.deleted if review else 0)
    return {"road": road, "not_road": not_road}
