"""A raster layer's labels: what a person says is or is not road on its imagery, stored so
that every later road extraction of the layer learns from it.

A label is a ``road`` line (along a road the model missed), a ``not_road`` line (along
something it drew wrongly) or a ``not_road`` polygon (an area with no road), in lon/lat. Its
input is GeoJSON (a Feature or a FeatureCollection whose features carry ``label``), the same
from the web map, the HTTP API and ``ugvmap layers labels --add``. A batch is written whole or
not at all: every feature is checked (shape, validity, on the layer's imagery) before any row
is written, and the per-layer limit is counted under a lock on the layer, so two editors
adding at once cannot pass it together.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import shapely
from shapely.geometry import shape
from sqlalchemy import Connection, text
from sqlalchemy.orm import Session

from app.db.models import LABEL_KINDS
from app.errors import InvalidValueError, LayerNotFoundError, NotFoundError

MAX_PER_REQUEST = 1_000
"""Labels one request may add: a person's strokes, not a bulk import of a road file."""
MAX_PER_LAYER = 10_000
"""Labels a layer may hold: the extraction burns every one into its sample."""
MAX_POSITIONS = 10_000
"""Positions in one label's geometry."""
FOOTPRINT_TOLERANCE_M = 2.0
"""How far past the edge of the layer's imagery a label may reach, in web-mercator metres (a
stroke ending on the edge, drawn on a zoomed-out map)."""
GEOMETRY_TYPES = {"road": ("LineString",), "not_road": ("LineString", "Polygon")}
PARTS = {"MultiLineString": "LineString", "MultiPolygon": "Polygon"}


@dataclass(frozen=True)
class NewLabel:
    """A checked label, ready to store: its kind and lon/lat geometry."""

    label: str
    geometry: shapely.Geometry


def _no_layer(slug: str) -> LayerNotFoundError:
    return LayerNotFoundError(f"no raster layer {slug[:100]!r}")


def layer_id(conn: Connection, slug: str, *, lock: bool = False) -> int:
    """The layer's id (LayerNotFoundError if none). ``lock``: hold the layer against other
    label writers and its deletion until the transaction ends (a key-share lock, so raster
    ingest and label reads go on)."""
    found = conn.execute(text(
        "SELECT id FROM layers WHERE slug = :slug" + (" FOR NO KEY UPDATE" if lock else "")),
        {"slug": slug}).scalar()
    if found is None:
        raise _no_layer(slug)
    return int(found)


def _positions_problem(coordinates: Any, depth: int) -> str | None:
    """Why ``coordinates`` (nested ``depth`` lists deep above the positions) are not lon/lat
    positions, or None."""
    if not isinstance(coordinates, list | tuple):  # tuples: a Python caller's
        return "coordinates must be arrays of [lon, lat] positions"
    if depth == 0:
        if len(coordinates) not in (2, 3) or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in coordinates):
            return "positions must be [lon, lat] pairs of finite numbers"
        lon, lat = coordinates[:2]
        if not (-180 <= lon <= 180 and -90 <= lat <= 90):
            return "positions must lie within lon -180..180, lat -90..90"
        return None
    if depth == 1 and len(coordinates) > MAX_POSITIONS:
        return f"a label may have at most {MAX_POSITIONS} positions"
    return next((p for c in coordinates if (p := _positions_problem(c, depth - 1))), None)


def _geometries(label: str, value: Any) -> tuple[list[shapely.Geometry], str | None]:
    """The label's geometries (a multi-geometry split into its parts), or why ``value`` is
    not a geometry this kind of label may have."""
    allowed = GEOMETRY_TYPES[label]
    kind = str(value.get("type")) if isinstance(value, dict) else ""
    if kind not in allowed and PARTS.get(kind, "") not in allowed:
        return [], f"a {label} label must be a GeoJSON {' or '.join(allowed)}"
    depth = {"LineString": 1, "Polygon": 2, "MultiLineString": 2, "MultiPolygon": 3}[kind]
    problem = _positions_problem(value.get("coordinates"), depth)
    if problem:
        return [], problem
    try:
        geometry = shapely.force_2d(shape({"type": kind, "coordinates": value["coordinates"]}))
    except (ValueError, TypeError, shapely.errors.ShapelyError) as exc:
        return [], f"not a valid {kind} ({exc})"[:200]
    parts = list(geometry.geoms) if kind in PARTS else [geometry]
    if not parts or any(p.is_empty for p in parts):
        return [], "the geometry is empty"
    for part in parts:
        if isinstance(part, shapely.LineString) and part.length == 0:
            return [], "a line needs two different positions"
        if not part.is_valid:
            return [], f"invalid geometry: {shapely.is_valid_reason(part)}"
    return parts, None


def parse_labels(body: Any, default_label: str | None = None) -> list[NewLabel]:
    """The labels of a GeoJSON Feature or FeatureCollection, every feature checked; one
    InvalidValueError naming each bad feature, so nothing of a faulty batch is written.
    A feature's ``label`` property says what it is (``default_label`` where it has none)."""
    if isinstance(body, dict) and body.get("type") == "Feature":
        features, prefix = [body], "feature"
    elif isinstance(body, dict) and body.get("type") == "FeatureCollection" \
            and isinstance(body.get("features"), list):
        features, prefix = body["features"], "features"
    else:
        raise InvalidValueError("the body must be a GeoJSON Feature or FeatureCollection",
                                errors={"type": "must be Feature or FeatureCollection"})
    if not features:
        raise InvalidValueError("the FeatureCollection has no features",
                                errors={"features": "must not be empty"})
    if len(features) > MAX_PER_REQUEST:
        raise InvalidValueError(
            f"{len(features)} labels in one request; at most {MAX_PER_REQUEST}",
            errors={"features": f"at most {MAX_PER_REQUEST} per request"})
    labels: list[NewLabel] = []
    problems: dict[str, str] = {}
    for i, feature in enumerate(features):
        where = prefix if prefix == "feature" else f"features[{i}]"
        if not isinstance(feature, dict) or feature.get("type") != "Feature":
            problems[where] = "must be a GeoJSON Feature"
            continue
        properties = feature.get("properties") or {}
        label = properties.get("label", default_label) if isinstance(properties, dict) \
            else None
        if label not in LABEL_KINDS:
            problems[f"{where}.properties.label"] = f"must be one of {', '.join(LABEL_KINDS)}"
            continue
        parts, problem = _geometries(label, feature.get("geometry"))
        if problem:
            problems[f"{where}.geometry"] = problem
        labels.extend(NewLabel(label, part) for part in parts)
    if problems:
        first = next(iter(problems.items()))
        raise InvalidValueError(f"{len(problems)} of {len(features)} labels refused, nothing "
                                f"stored; {first[0]}: {first[1]}", errors=dict(
                                    list(problems.items())[:50]))
    if len(labels) > MAX_PER_REQUEST:
        raise InvalidValueError(
            f"{len(labels)} labels (multi-geometries split into parts) in one request; at "
            f"most {MAX_PER_REQUEST}", errors={"features": f"at most {MAX_PER_REQUEST}"})
    return labels


def _feature(row: Any) -> dict[str, Any]:
    return {"type": "Feature", "id": row.id, "geometry": json.loads(row.geometry),
            "properties": {"label": row.label, "created_by": row.created_by,
                           "created_at": row.created_at.isoformat()}}


SELECT = ("SELECT id, label, ST_AsGeoJSON(geom, 9) AS geometry, created_by, created_at "
          "FROM layer_labels ")


def list_labels(conn: Connection, slug: str) -> list[dict[str, Any]]:
    """The layer's labels as GeoJSON Features, oldest first."""
    rows = conn.execute(text(SELECT + "WHERE layer_id = :id ORDER BY id"),
                        {"id": layer_id(conn, slug)})
    return [_feature(r) for r in rows]


def _off_the_imagery(conn: Connection, layer: int, labels: list[NewLabel]) -> list[int]:
    """Indexes of the labels not on the layer's imagery: not covered by its sources'
    footprints (widened by :data:`FOOTPRINT_TOLERANCE_M`; all of them when it has none)."""
    return list(conn.execute(text(
        "WITH imagery AS (SELECT ST_Buffer(ST_Union(footprint), :tolerance) AS area "
        "  FROM raster_sources WHERE layer_id = :layer) "
        "SELECT t.i - 1 FROM unnest(CAST(:wkbs AS bytea[])) WITH ORDINALITY AS t(wkb, i), "
        "imagery WHERE imagery.area IS NULL OR NOT ST_CoveredBy("
        "  ST_Transform(ST_GeomFromWKB(t.wkb, 4326), 3857), imagery.area) ORDER BY t.i"),
        {"layer": layer, "tolerance": FOOTPRINT_TOLERANCE_M,
         "wkbs": [shapely.to_wkb(n.geometry) for n in labels]}).scalars())


def add_labels(session: Session, slug: str, labels: list[NewLabel],
               created_by: str) -> list[dict[str, Any]]:
    """Store ``labels`` (checked by :func:`parse_labels`) on the layer, all or none: refused
    when any lies off the layer's imagery or the layer would hold more than
    :data:`MAX_PER_LAYER`. Returns the stored labels as Features."""
    conn = session.connection()
    layer = layer_id(conn, slug, lock=True)
    off = _off_the_imagery(conn, layer, labels)
    if off:
        raise InvalidValueError(
            f"{len(off)} of {len(labels)} labels lie (partly) outside the imagery of layer "
            f"{slug!r}, nothing stored; draw labels on the layer's images",
            errors={f"labels[{i}].geometry": "outside the layer's imagery" for i in off[:50]})
    held: int = conn.execute(text("SELECT count(*) FROM layer_labels WHERE layer_id = :id"),
                        {"id": layer}).scalar_one()
    if held + len(labels) > MAX_PER_LAYER:
        raise InvalidValueError(
            f"layer {slug!r} holds {held} labels; {len(labels)} more would pass the limit of "
            f"{MAX_PER_LAYER}, nothing stored; delete some first",
            errors={"features": f"at most {MAX_PER_LAYER} per layer"})
    rows = conn.execute(text(
        "INSERT INTO layer_labels (layer_id, label, geom, created_by) "
        "SELECT :layer, t.label, ST_GeomFromWKB(t.wkb, 4326), :by "
        "FROM unnest(CAST(:labels AS text[]), CAST(:wkbs AS bytea[])) AS t(label, wkb) "
        "RETURNING id, label, ST_AsGeoJSON(geom, 9) AS geometry, created_by, created_at"),
        {"layer": layer, "by": created_by, "labels": [n.label for n in labels],
         "wkbs": [shapely.to_wkb(n.geometry) for n in labels]}).all()
    return [_feature(r) for r in sorted(rows, key=lambda r: r.id)]


def delete_label(session: Session, slug: str, label_id: int) -> None:
    """Delete one of the layer's labels (NotFoundError if it has no such label)."""
    conn = session.connection()
    deleted = conn.execute(text(
        "DELETE FROM layer_labels WHERE layer_id = :layer AND id = :id RETURNING id"),
        {"layer": layer_id(conn, slug), "id": label_id}).scalar()
    if deleted is None:
        raise NotFoundError(f"layer {slug[:100]!r} has no label {label_id}")


def clear_labels(session: Session, slug: str) -> int:
    """Delete all of the layer's labels; how many there were."""
    conn = session.connection()
    return conn.execute(text("DELETE FROM layer_labels WHERE layer_id = :layer"),
                        {"layer": layer_id(conn, slug)}).rowcount
