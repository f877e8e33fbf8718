"""Where the road is, from the road model, for the markings of an image nobody located.

Why: paint is found by contrast (:mod:`.paint`) and kept where the ground around it is grey
(:func:`.paint.near_road`), and on satellite patches grey roofs, pavements and car parks pass
that test: most false lines there were on roofs, and dashes of roof texture were chained
across 16 m into long "dashed" lines. The road model knows a roof from a road; kept within
``reach_m`` of where it sees road (a kerb-side edge line lies on the road's border), the
markings of the 12 OpenSatMap patches went from P / R 0.23 / 0.55 to 0.51 / 0.53 at 0.5 m.

It is only asked where it can answer: aerial or satellite imagery (``MIN_RESOLUTION_M`` or
coarser; the road model learned from 0.3-1 m imagery of that kind) spanning ``MIN_SIDE_M``
(a 30 m drone crop is 60 of the model's pixels, too little context to see a road in), where
it sees some road (else it does not know the imagery). A vehicle's IPM mosaic (0.05 m/px) is
not asked: on the synthetic drive the model's road left out the road's borders, and marking
recall fell from 0.99 to 0.91 and the boundaries' p95 from 0.12 m to 2.8 m. ``ingest lanes``
does not use it either: a network's segments already say where the roads are.
"""

from __future__ import annotations

import cv2
import numpy as np

from ingest.roads.clean import metres_to_px
from ingest.roads.georef import Image, resize

MIN_RESOLUTION_M = 0.1
"""Finer imagery (a drive's mosaic, a low drone) is not asked."""
MIN_SIDE_M = 48.0
"""Shortest side of ground an image must span for the road model to be asked."""
MIN_ROAD_SHARE = 0.02
"""Below this share of road pixels the model is taken to not know the imagery."""


def model_road(image: Image, reach_m: float = 1.5) -> np.ndarray | None:
    """Bool mask on the image's grid: within ``reach_m`` of road as the road model sees it;
    ``None`` where it cannot tell (see the module's docstring)."""
    from ingest.roads.pipeline import ExtractParams, model_mask

    rows, cols = image.pixels.shape[:2]
    if image.resolution_m < MIN_RESOLUTION_M or min(rows, cols) * image.resolution_m < MIN_SIDE_M:
        return None
    binary, field, _, _ = model_mask(image, None, False, ExtractParams())
    if binary.mean() < MIN_ROAD_SHARE:
        return None
    road = (resize(field.values, (rows, cols), cv2.INTER_LINEAR) >= field.level).astype(np.uint8)
    size = 2 * metres_to_px(reach_m, image.resolution_m) + 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.dilate(road, disc).astype(bool)
