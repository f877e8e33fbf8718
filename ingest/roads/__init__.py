"""Road extraction: aerial/mosaic image (+ an optional training sample) -> road graph.

Stages, one module each, composed by :mod:`ingest.roads.pipeline`:
``model`` (the shipped road network, zero-shot or adapted; its own package) or ``classify``
(per-job classifiers) -> ``clean`` (morphology in metres) -> ``houses`` (rectangle-like blobs
out; colour classifiers) -> ``skeleton`` (thinning, spur pruning) -> ``topology`` (gap
bridging, crumbs) -> ``graph`` (nodes/edges with attributes) -> ``georef`` (pixel -> map
coordinates). ``evaluate`` and ``connectivity`` score centerlines against ground truth.
Everything here is a pure function of arrays and geometries: no database.
"""

from app.errors import UserError


class RoadsInputError(UserError):
    """Input the user can fix (bad sample, unreadable image...): shown as one line by the CLI."""
