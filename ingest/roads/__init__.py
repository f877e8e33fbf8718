"""Road extraction: aerial/mosaic image + a small training sample -> topological road graph.

Stages, one module each, composed by :mod:`ingest.roads.pipeline`:
``classify`` (road pixels) -> ``clean`` (morphology in metres) -> ``houses`` (rectangle-like
blobs out) -> ``skeleton`` (thinning, spur pruning) -> ``graph`` (nodes/edges with attributes)
-> ``georef`` (pixel -> map coordinates). ``evaluate`` scores centerlines against ground truth.
Everything here is a pure function of arrays and geometries: no database.
"""


class RoadsInputError(ValueError):
    """Input the user can fix (bad sample, unreadable image...): shown as one line by the CLI."""
