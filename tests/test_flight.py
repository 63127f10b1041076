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


def _course_terrain_and_apexes(n=20_000, seed=0):
    # A course map (70 blocks padded to 96, holes-free but with many narrow obstacles and
    # margin bands) and apexes over it: random ones, and ones whose foot or COM starts
    # exactly on a block edge.
    import numpy as np

    from jaxhop._core.batching import pad_terrain
    from jaxhop.mppc import load_course
    from jaxhop.parkour import course_map, leg_hopper

    hop = leg_hopper()
    course = load_course("mppc-hw-dynamic-4")
    terrain = pad_terrain(course_map(course, course.environment, hop).plan, 96)
    rng = np.random.default_rng(seed)
    starts, ends = np.asarray(terrain.starts), np.asarray(terrain.ends)
    h = np.asarray(terrain.heights)
    y = rng.uniform(starts[0] - 0.1, ends[-1] + 0.1, n)
    y[: n // 4] = rng.choice(np.concatenate([starts, ends]), n // 4)
    apex = np.stack([y, rng.uniform(h.min() + 0.01, h.max() + 0.6, n),
                     rng.uniform(-1.5, 1.5, n)], 1)
    return terrain, apex, hop


@pytest.mark.parametrize("model", ["bhop", "slip"])
def test_touchdown_in_a_window_of_blocks_is_the_whole_terrains(model):
    # The planner's touchdowns look only at the blocks around the descent
    # (`landing_window`): the same code, block, time, foot position and velocity, bit for
    # bit, as over every block, with the foot straight below the COM (BHop templates) or
    # eq 37's lead ahead of it (SLIP-adjusted).
    import jax
    import numpy as np

    from jaxhop._planning.policies import landing_window
    from jaxhop._planning.regions import foot_lead
    from jaxhop.parkour import leg_templates

    terrain, apex, hop = _course_terrain_and_apexes()
    tm = leg_templates(hop, model=model)
    width = landing_window(apex, tm, terrain, hop)
    assert width is not None and width <= terrain.n_blocks // 2

    def run(window):
        def one(a):
            offset = jnp.stack([foot_lead(a[2], tm), -hop.rho0])
            return touchdown(a, offset, terrain, hop, window=window)

        return [np.asarray(x) for x in jax.jit(jax.vmap(one))(jnp.asarray(apex))]

    full, win = run(None), run(width)
    assert {OK, COLLISION, OFF_MAP} <= set(full[0].tolist())
    for a, b in zip(full, win):
        assert np.array_equal(a, b)
    # A window too narrow for the widest descents changes some outcomes: the test sees it.
    narrow = run(2)
    assert not all(np.array_equal(a, b) for a, b in zip(full, narrow))
