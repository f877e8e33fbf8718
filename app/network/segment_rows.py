"""The statements that write ``road_segments`` rows: every insert of segments is built here.

Why one module: a segment row keeps a rule no constraint states, ``length_m`` is the
geodesic length of ``geom`` (``ugvmap network validate`` checks it), and four modules (the
importer's bulk publish, the create and split edits, the synthetic networks of the tests)
each spelt the insert and the length their own way. Callers give each column's SQL
expression; this module adds ``length_m`` from the geometry's. Plain SQL text, so SQLAlchemy
sessions (the edits, ``:name`` parameters) and raw psycopg connections (the COPY-staged
import, the synthetic grids, ``%s`` parameters) run the same statement.
"""

from __future__ import annotations

from collections.abc import Mapping


def geodesic_length(geom: str) -> str:
    """The SQL of a segment's ``length_m`` from its geometry's SQL (lon/lat, SRID 4326)."""
    return f"ST_Length(({geom})::geography)"


def on_nodes(geom: str, source: str, target: str) -> str:
    """The SQL of a line (``geom``) whose first and last points are replaced by the geometries
    of nodes ``source`` and ``target`` (SQL of their ids).

    Why in SQL: a segment's ends must be its nodes' very doubles (``ugvmap network validate``
    compares them exactly). Read back as GeoJSON text (15 decimals) a longitude such as
    1.6500000000000001 comes back one unit in the last place off; copied inside PostgreSQL
    it cannot."""
    node = "(SELECT geom FROM road_nodes WHERE id = {})"
    return (f"ST_SetPoint(ST_SetPoint({geom}, 0, {node.format(source)}), -1, "
            f"{node.format(target)})")


def insert_segments(columns: Mapping[str, str], rows: str | None = None, *,
                    returning: bool = False) -> str:
    """``INSERT INTO road_segments``: one row per row of ``rows`` (a ``FROM`` clause; None:
    exactly one row), each column set to its SQL expression in ``columns`` (which must set
    ``geom`` and must not set ``length_m``), ``RETURNING id`` when asked.

    Positional parameters come in the order of ``columns`` and then of ``rows``; ``geom``'s
    expression is written twice, so with positional parameters take the geometry from
    ``rows``."""
    if "geom" not in columns or "length_m" in columns:
        raise ValueError("a segment insert sets geom, and length_m follows from it")
    names = ", ".join((*columns, "length_m"))
    values = ", ".join((*columns.values(), geodesic_length(columns["geom"])))
    return (f"INSERT INTO road_segments ({names}) SELECT {values}"
            + (f" FROM {rows}" if rows is not None else "")
            + (" RETURNING id" if returning else ""))
