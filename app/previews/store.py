"""Asking for a road preview and reading it back.

A preview is a ``road-preview`` job (:mod:`app.jobs.kinds`): the server does not extract
(``app`` never imports ``ingest``), it checks the window and queues the job, which a worker
runs (``ugvmap serve`` starts one beside the server). The job's id is the preview's; its row
says queued / running / failed and how far it got, and the result is a ``road_previews`` row,
written only if the layer was still at the version the preview was asked for.

Why a size limit: a preview answers a person looking at the map, within seconds. A view of
:data:`MAX_VIEW_PX` pixels a side at the layer's finest resolution extracts in a few seconds
on two cores; a whole region is ``ugvmap ingest roads``' work, not a click's.
"""

from __future__ import annotations

import math
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import ConflictError, InvalidValueError, LayerNotFoundError, NotFoundError
from app.jobs.queue import enqueue

MAX_VIEW_PX = 2048
"""The widest view a preview extracts, in pixels of the layer's finest resolution."""
MAX_LAT = 85.05
"""Web mercator's edge: the layer's grid ends there."""
EARTH_M = 2 * math.pi * 6378137
KIND = "road-preview"


def _no_layer(slug: str) -> LayerNotFoundError:
    return LayerNotFoundError(f"no raster layer {slug[:100]!r}")


def parse_bbox(body: Any) -> tuple[float, float, float, float]:
    """``{"bbox": [minlon, minlat, maxlon, maxlat]}`` -> the box; 422 naming what is wrong."""
    if not isinstance(body, dict) or set(body) != {"bbox"}:
        raise InvalidValueError('the body must be {"bbox": [minlon, minlat, maxlon, maxlat]}',
                                errors={"body": "must have only 'bbox'"})
    box = body["bbox"]
    if not (isinstance(box, list) and len(box) == 4 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in box)):
        raise InvalidValueError("bbox must be four numbers: minlon, minlat, maxlon, maxlat",
                                errors={"bbox": "must be four finite numbers"})
    x0, y0, x1, y1 = (float(v) for v in box)
    if not (-180 <= x0 < x1 <= 180 and -MAX_LAT <= y0 < y1 <= MAX_LAT):
        raise InvalidValueError(
            f"bbox must be minlon < maxlon in -180..180 and minlat < maxlat in "
            f"-{MAX_LAT}..{MAX_LAT} (degrees)", errors={"bbox": "is not a lon/lat box"})
    return x0, y0, x1, y1


def request_preview(session: Session, slug: str, bbox: tuple[float, float, float, float]
                    ) -> int:
    """Queue a preview of ``bbox`` on layer ``slug`` in the caller's transaction; its id.

    Refused (422) when the view meets none of the layer's imagery, or is wider than
    :data:`MAX_VIEW_PX` pixels at the layer's finest resolution."""
    row = session.execute(text(
        "SELECT l.version, l.maxzoom, ST_XMax(e) - ST_XMin(e) AS w, "
        " ST_YMax(e) - ST_YMin(e) AS h, EXISTS (SELECT 1 FROM raster_sources s "
        "  WHERE s.layer_id = l.id AND ST_Intersects(s.footprint, e)) AS meets "
        "FROM layers l, ST_Transform(ST_MakeEnvelope(:x0, :y0, :x1, :y1, 4326), 3857) e "
        "WHERE l.slug = :slug"),
        {"slug": slug, "x0": bbox[0], "y0": bbox[1], "x1": bbox[2], "y1": bbox[3]}).first()
    if row is None:
        raise _no_layer(slug)
    if not row.meets:
        raise InvalidValueError(f"the view does not meet layer {slug}'s imagery: move the "
                                "map over the layer", errors={"bbox": "is off the layer"})
    pixel_m = EARTH_M / 256 / 2 ** row.maxzoom
    width, height = round(row.w / pixel_m), round(row.h / pixel_m)
    if max(width, height) > MAX_VIEW_PX:
        raise InvalidValueError(
            f"the view is {width} x {height} px at layer {slug}'s finest resolution (z"
            f"{row.maxzoom}); a preview extracts at most {MAX_VIEW_PX} x {MAX_VIEW_PX} px: "
            "zoom in", errors={"bbox": f"is wider than {MAX_VIEW_PX} px of the layer"})
    return enqueue(session, KIND, {"layer": slug, "bbox": list(bbox),
                                   "layer_version": row.version})


def read_preview(session: Session, slug: str, preview_id: int) -> dict[str, Any]:
    """The preview as the API shows it: its job's state and, once done, its roads (a GeoJSON
    FeatureCollection with each road's confidence), the classifier, whether the labels were
    used (``sample``: the held-out figures that decided it; null when zero-shot), the labels
    it learned from and its seconds. 404 unless it is a preview of this layer."""
    row = session.execute(text(
        "SELECT j.status, j.progress, j.message, j.error, j.params, p.result "
        "FROM ingest_jobs j LEFT JOIN road_previews p ON p.job_id = j.id "
        "WHERE j.id = :id AND j.kind = :kind AND j.params->>'layer' = :slug"),
        {"id": preview_id, "kind": KIND, "slug": slug}).first() \
        if 0 < preview_id < 2**63 else None
    if row is None:
        raise NotFoundError(f"layer {slug[:100]} has no preview {preview_id}")
    return {"id": preview_id, "layer": slug, "bbox": row.params["bbox"],
            "layer_version": row.params["layer_version"], "status": row.status,
            "progress": row.progress, "message": row.message, "error": row.error,
            "result": row.result}


def stored_preview(session: Session, slug: str, preview_id: int) -> Any:
    """The stored result of a finished preview of ``slug`` (404 if none), with whether the
    layer is still at the preview's version; the layer row share-locked until the
    transaction ends, so no re-ingest commits while the preview is accepted."""
    row = session.execute(text(
        "SELECT p.job_id, p.layer_version, l.id AS layer_id, l.version AS current, p.result, "
        "ST_AsText(p.bbox) AS bbox "
        "FROM road_previews p JOIN layers l ON l.id = p.layer_id "
        "WHERE p.job_id = :id AND l.slug = :slug FOR SHARE OF l"),
        {"id": preview_id, "slug": slug}).first() if 0 < preview_id < 2**63 else None
    if row is None:
        state = read_preview(session, slug, preview_id)["status"]  # 404 if none at all
        raise ConflictError(f"preview {preview_id} is {state}, with no roads to accept: "
                            + ("preview again" if state == "failed" else "wait for it"))
    return row
