"""Job kinds that run as one task: the same work as their ``ugvmap ingest`` command.

Each commits its result and the job's success in one transaction
(:func:`~app.jobs.rows.succeed_in`): a worker killed before the commit left nothing, and the
retried task redoes it; a retry after the commit finds the job succeeded and does nothing.
"""

from __future__ import annotations

from pathlib import Path

from app.db.session import get_engine, session_scope
from app.jobs.kinds import NetworkParams, RoadsParams
from app.jobs.lease import Lease
from app.jobs.rows import succeed_in


def ingest_network(job_id: int, params: NetworkParams) -> None:
    """Import a road file as a network (``ugvmap ingest network``)."""
    from ingest.network import import_network

    with Lease(get_engine(), job_id), session_scope() as session:
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
                                  labels=params.labels, review_labels=params.review_labels)
        succeed_in(session.connection(), job_id, "; ".join(done.lines()))
