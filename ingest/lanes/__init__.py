"""Painted lane markings from imagery fine enough to show them (IPM mosaics, drone orthophotos).

:mod:`.paint` finds bright thin paint (a white top-hat with hysteresis), :mod:`.trace` turns
each painted blob into a measured piece of line, :mod:`.classify` joins dashes across their
gaps and names each line's kind and colour, :mod:`.extract` runs the chain on an image and
writes GeoJSON. All are pure functions of arrays, tested without a database.
"""

from __future__ import annotations

from app.errors import UserError

#: Coarsest imagery read: a lane line is 0.10–0.20 m wide, so coarser pixels blur it away.
MAX_RESOLUTION_M = 0.2


class LanesInputError(UserError):
    """Input the user can fix (imagery too coarse, unreadable image): one line on the CLI."""


def check_resolution(resolution_m: float) -> None:
    """Refuse imagery too coarse to show lane markings, before anything is computed."""
    if not resolution_m > 0:
        raise LanesInputError(f"resolution must be a positive number of metres, "
                              f"not {resolution_m}")
    if resolution_m > MAX_RESOLUTION_M:
        raise LanesInputError(
            f"imagery at {resolution_m:.3g} m/px is too coarse for lane markings (a painted "
            f"line is 0.1-0.2 m wide): give imagery of {MAX_RESOLUTION_M} m/px or finer")
