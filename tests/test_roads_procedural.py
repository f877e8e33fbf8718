"""Procedural training scenes (domain randomisation) and their place in the crop sampler.

No torch needed: the generator and the sampler are numpy/OpenCV.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ingest.roads.model.data import Augment, CropSampler, Scene
from ingest.roads.model.procedural import procedural_scene


def test_a_scene_is_reproducible_and_well_formed() -> None:
    a = procedural_scene(np.random.default_rng(3), 128)
    b = procedural_scene(np.random.default_rng(3), 128)
    c = procedural_scene(np.random.default_rng(4), 128)
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)
    assert not np.array_equal(a[0], c[0])
    rgb, road, weight = a
    assert rgb.shape == (128, 128, 3) and road.shape == weight.shape == (128, 128)
    assert rgb.dtype == road.dtype == np.float32 and rgb.min() >= 0 and rgb.max() <= 1
    assert set(np.unique(road)) <= {0.0, 1.0} and weight.min() == 1


def test_most_scenes_hold_roads_and_roads_are_not_everything() -> None:
    rng = np.random.default_rng(0)
    shares = np.array([procedural_scene(rng, 128)[1].mean() for _ in range(40)])
    assert (shares > 0.005).mean() >= 0.75, shares
    assert shares.max() < 0.6 and 0.03 < np.median(shares) < 0.35, shares


def test_road_widths_are_in_metres() -> None:
    """The same seeds drawn at 0.25 m/px instead of 0.5: the roads (drawn before anything that
    could depend on their pixels) cover about twice the pixels."""
    coarse = sum(procedural_scene(np.random.default_rng(s), 256, 0.5)[1].sum()
                 for s in range(12))
    fine = sum(procedural_scene(np.random.default_rng(s), 256, 0.25)[1].sum()
               for s in range(12))
    assert 1.6 < fine / coarse < 2.4, fine / coarse


def test_the_sampler_mixes_procedural_crops_at_the_asked_share() -> None:
    """Crops of a real scene of uniform grey with no road, against procedural crops (roads
    drawn): the share of crops with road follows ``procedural_p``."""
    grey = Scene("grey", "test", np.full((300, 300, 3), 128, np.uint8),
                 np.zeros((300, 300), np.uint8), np.ones((300, 300), np.uint8))
    off = CropSampler([grey], 64, seed=1, augment=replace(Augment(), procedural_p=0.0))
    assert all(off.crop()[1].sum() == 0 for _ in range(20))
    half = CropSampler([grey], 64, seed=1, augment=replace(Augment(), procedural_p=0.5))
    with_road = sum(half.crop()[1].sum() > 0 for _ in range(80))
    assert 20 <= with_road <= 60, with_road


def test_a_source_weight_draws_its_scenes_more_often() -> None:
    """Two scenes of the same size, one all road ("rural"), one with none: equally often
    unweighted, about 9 in 10 with the rural source weighed 9 (``--source-weight``)."""
    size = (200, 200)
    urban = Scene("u", "urban", np.full((*size, 3), 90, np.uint8), np.zeros(size, np.uint8),
                  np.ones(size, np.uint8))
    rural = Scene("r", "rural", np.full((*size, 3), 160, np.uint8), np.ones(size, np.uint8),
                  np.ones(size, np.uint8))
    plain = CropSampler([urban, rural], 64, seed=2)
    weighed = CropSampler([urban, rural], 64, seed=2, source_weight={"rural": 9.0})
    assert np.allclose(plain.p, [0.5, 0.5]) and np.allclose(weighed.p, [0.1, 0.9])
    drawn = sum(weighed.crop()[1].mean() > 0.5 for _ in range(200))
    assert 160 <= drawn <= 195, drawn
