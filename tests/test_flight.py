"""Touchdown and failure semantics on hand-built cases (docs/decisions.md, "Execution")."""

import jax.numpy as jnp
import pytest

from jaxhop._control.decisions import bhop_stride
from jaxhop._core.params import Hopper
from jaxhop._core.terrain import make_terrain
from jaxhop._models.flight import COLLISION, HOLE, OFF_MAP, OK, touchdown

HOP = Hopper()
FOOT = jnp.array([0.0, -1.0])


def test_touchdown_on_unplanned_higher_block():
    # Aiming for the low block at y ~ 1.5, but a 0.3 m step at [1.0, 1.2] is met first.
    t = make_terrain([(0.0, 1.0, 0.0), (1.0, 1.2, 0.3), (1.2, 3.0, 0.0)])
    apex = jnp.array([0.6, 1.5, 1.5])  # foot path reaches z = 0.3 at t = 0.247, y = 0.97
    code, block, time, y_foot, _ = touchdown(apex, FOOT, t, HOP)
    assert int(code) == COLLISION  # the foot meets the step's side wall below its top
    apex = jnp.array([0.7, 1.5, 1.5])  # now at z = 0.3 the foot is at y = 1.07: on its top
    code, block, time, y_foot, _ = touchdown(apex, FOOT, t, HOP)
    assert int(code) == OK and int(block) == 1
    assert float(time) == pytest.approx(((0.5 - 0.3) * 2 / HOP.g) ** 0.5)
    assert 1.0 <= float(y_foot) <= 1.2


def test_wall_collision_and_stride_result():
    t = make_terrain([(0.0, 1.0, 0.0), (1.0, 2.0, 0.45)])
    apex = jnp.array([0.8, 1.4, 1.0])  # foot at 0.4 m height crosses y = 1 below the 0.45 top
    code, *_ = touchdown(apex, FOOT, t, HOP)
    assert int(code) == COLLISION
    nxt, code, _ = bhop_stride(apex, jnp.array([0.1, 0.0, 1.0]), t, HOP)
    assert int(code) == COLLISION


def test_hole_and_off_map():
    t = make_terrain([(0.0, 1.0, 0.0), (2.0, 3.0, 0.0)])
    code, *_ = touchdown(jnp.array([1.5, 1.3, 0.0]), FOOT, t, HOP)
    assert int(code) == HOLE
    code, *_ = touchdown(jnp.array([2.9, 1.5, 1.0]), FOOT, t, HOP)
    assert int(code) == OFF_MAP
    code, *_ = touchdown(jnp.array([-0.5, 1.5, 0.0]), FOOT, t, HOP)
    assert int(code) == OFF_MAP


def test_wind_shifts_touchdown():
    t = make_terrain([(0.0, 3.0, 0.0)])
    apex = jnp.array([1.0, 1.5, 0.0])
    _, _, time, y_calm, _ = touchdown(apex, FOOT, t, HOP, 0.0)
    _, _, _, y_wind, v = touchdown(apex, FOOT, t, HOP, -0.2)
    assert float(y_wind - y_calm) == pytest.approx(-0.1 * float(time) ** 2)
    assert float(v[0]) == pytest.approx(-0.2 * float(time))


def test_rise_into_overhanging_block_is_a_collision():
    # Liftoff at the bottom of a well whose right wall is taller than the leg: a fast rise
    # to the right enters the wall.
    t = make_terrain([(0.0, 1.0, 0.0), (1.0, 2.0, 1.3)])
    apex = jnp.array([0.7, 1.3, 0.0])
    nxt, code, _ = bhop_stride(apex, jnp.array([0.2, -0.6, 1.0]), t, HOP)
    assert int(code) == COLLISION
