"""The collision ellipse from a car's size: semi-axes, stated as such."""

from __future__ import annotations

import numpy as np
import pytest

import mmdopt
from mmdopt.geometry import OBSTACLE_FOOTPRINT


def test_the_footprint_of_two_cars_is_their_half_sizes_plus_the_margin():
    fp = mmdopt.Footprint.from_vehicle(5.0, 2.0, 0.5)
    assert (fp.a, fp.b) == (3.0, 2.5)  # semi-axes: 2.5 + 0 + 0.5 along, 1 + 1 + 0.5 across
    long = mmdopt.Footprint.from_vehicle(4.8, 1.9, 0.3, obstacle_length=12.0, obstacle_width=2.5)
    assert long.a == pytest.approx(2.4 + (6.0 - 2.5) + 0.3) and long.b == pytest.approx(2.5)


def test_a_car_in_the_next_lane_is_clear_of_the_footprint_and_one_in_contact_is_not():
    """The trap of reading a, b as overall sizes: with the paper's semi-axes (4.5, 3.5) a car
    3.5 m to the side is on the boundary; a footprint from the cars' sizes keeps it clear, and
    a car whose body overlaps the ego's is inside."""
    fp = mmdopt.Footprint.from_vehicle(4.8, 1.9, 0.3)
    K = 5
    ego = np.zeros((K, 2))
    beside = np.tile([[0.0, 3.5]], (1, 1, K, 1)).reshape(1, 1, K, 2)
    touching = np.tile([[4.0, 1.5]], (1, 1, K, 1)).reshape(1, 1, K, 2)  # rear corner overlaps
    assert mmdopt.collision_free_count(ego, beside, a=fp.a, b=fp.b).joint == 1
    assert mmdopt.collision_free_count(ego, touching, a=fp.a, b=fp.b).joint == 0
    # the paper's semi-axes put the car in the next lane on the boundary: counted as met
    assert mmdopt.collision_free_count(ego, beside, a=4.5, b=3.5).joint == 0
    assert max(OBSTACLE_FOOTPRINT.offsets) == 2.5


@pytest.mark.parametrize(
    "kw", [dict(length=0.0), dict(width=-1.0), dict(margin=-0.1), dict(length=float("nan"))]
)
def test_bad_sizes_are_refused_by_name(kw):
    args = dict(length=4.8, width=1.9, margin=0.5) | kw
    with pytest.raises(ValueError, match=next(iter(kw))):
        mmdopt.Footprint.from_vehicle(**args)


def test_a_footprint_is_set_on_the_config_by_its_section_name():
    fp = mmdopt.Footprint.from_vehicle(4.8, 1.9, 0.5)
    cfg = mmdopt.MMDOptConfig().replace(footprint=fp)
    assert cfg.safety.footprint == fp
    with pytest.raises(ValueError, match="together"):
        mmdopt.MMDOptConfig().replace(footprint=fp, a=2.0)
