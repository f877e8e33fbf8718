"""IPM ingest: a drive's panoramic frames + GNSS/INS poses -> stitched ground mosaic layer.

Stages, one module each, composed by :mod:`ingest.ipm.job`:
``panorama`` (the equirectangular camera model) and ``calibration`` (where the camera sits
on the vehicle) give ``lookup`` (the fixed ground-window -> panorama-pixel map, computed once
per drive); ``poses`` (read and interpolate the pose stream) or ``qrpose`` (poses stamped in
the frames) say where each frame was taken; ``frames`` reads frames robustly; ``place`` turns
one frame's ground patch into pixels of the survey's zone grid (``grid``); ``stitch``
accumulates them zone by zone with bounded memory and writes finished zones as zone mosaics
(image + ``.zone.json`` sidecar), which the raster ingest then registers atomically.
Everything but ``job`` is a pure function of arrays: no database.
"""


from app.errors import UserError


class IpmInputError(UserError):
    """Input the user can fix (bad calibration, poses, frames...): one line from the CLI."""
