"""Foothold sensing: the map the adaptive controller corrects with the footholds it senses,
and the BHop stance computed with the sensed height on a block the map has wrong."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop._control.decisions import in_global_domain
from jaxhop._control.foothold import (
    MEMORY,
    corrected_heights,
    footholds_init,
    mapped_height,
    remember,
)
from jaxhop._control.runloop import RunConfig, World, step
from jaxhop._core.params import Disturbance, Hopper
from jaxhop._core.result import Result
from jaxhop._core.terrain import make_terrain
from jaxhop._execution.batches import sweep_grid
from jaxhop._planning.cache import get_plan

HOP = Hopper()
MAP = make_terrain([(0.0, 1.0, 0.0), (1.0, 2.0, 0.3), (2.5, 4.0, 0.1)])


def _remember_all(footholds):
    mem = footholds_init()
    for t, foot in enumerate(footholds):
        mem = remember(mem, jnp.asarray(foot, float), True, t)
    return mem


def test_corrected_map_takes_the_latest_sensing_per_block():
    mem = _remember_all([(1.5, 0.42), (3.0, 0.05), (1.2, 0.37)])
    np.testing.assert_array_equal(np.asarray(corrected_heights(mem, MAP)), [0.0, 0.37, 0.05])


def test_a_foothold_on_a_shared_edge_corrects_the_block_nearer_in_height():
    # y = 1.0 is the end of block 0 (0.0) and the start of block 1 (0.3).
    low = corrected_heights(_remember_all([(1.0, 0.02)]), MAP)
    high = corrected_heights(_remember_all([(1.0, 0.28)]), MAP)
    np.testing.assert_array_equal(np.asarray(low), [0.02, 0.3, 0.1])
    np.testing.assert_array_equal(np.asarray(high), [0.0, 0.28, 0.1])
    assert float(mapped_height(jnp.array([1.0, 0.25]), MAP.heights, MAP)) == 0.3
    assert np.isnan(float(mapped_height(jnp.array([2.2, 0.0]), MAP.heights, MAP)))  # hole


def test_the_memory_keeps_the_newest_footholds_and_ignores_unsensed_strides():
    feet = [(0.5, 0.01 * (i + 1)) for i in range(MEMORY + 3)]
    mem = _remember_all(feet)
    assert float(corrected_heights(mem, MAP)[0]) == pytest.approx(0.01 * (MEMORY + 3))
    assert sorted(np.asarray(mem.t).tolist()) == list(range(3, MEMORY + 3))
    kept = remember(mem, jnp.array([3.0, 9.0]), False, MEMORY + 3)
    np.testing.assert_array_equal(np.asarray(corrected_heights(kept, MAP)),
                                  np.asarray(corrected_heights(mem, MAP)))


@pytest.fixture(scope="module")
def wrong_map():
    """A plan built on a map whose middle block is perceived 0.1 m too high."""
    true = make_terrain([(0.0, 3.0, 0.0), (3.0, 6.0, 0.2), (6.0, 9.0, 0.0)],
                        goal=(7.5, 1.3, 0.0), name="steps")
    perceived = true.with_heights(np.array([0.0, 0.3, 0.0]))
    plan = get_plan(perceived, None)
    grid = sweep_grid(true, 0.5, 0.25, 0.1)
    grid = grid[(grid[:, 0] > 2.4) & (grid[:, 0] < 3.4)]
    return plan, true, grid[in_global_domain(grid, plan.tables(), HOP)]


@pytest.mark.slow
def test_bhop_stance_on_a_misperceived_block_reaches_the_goal_with_the_sensed_height(wrong_map):
    plan, true, states = wrong_map
    world = World(plan.tables(), true, HOP, Disturbance())
    key = jax.random.key(0)
    runs = {}
    for c in ("paper", "adaptive"):
        config = RunConfig(jnp.asarray(plan.goal), controller=c)
        one = lambda z, config=config: step(z, key, 0, world, config)  # noqa: E731
        runs[c] = jax.jit(jax.vmap(one))(jnp.asarray(states))
    ad, pa = runs["adaptive"], runs["paper"]
    on_wrong = (np.asarray(ad.code) == Result.RUNNING) & (np.asarray(ad.foothold[:, 1]) == 0.2)
    assert on_wrong.sum() >= 5
    goal = np.asarray(plan.goals)[np.asarray(ad.policy)]
    miss = np.max(np.abs(np.asarray(ad.next_apex) - goal), axis=1)[on_wrong]
    miss_paper = np.max(np.abs(np.asarray(pa.next_apex) - goal), axis=1)[on_wrong]
    exact = miss < 1e-9
    assert exact.mean() >= 0.8  # the rest: controls clipped to the template's limits
    assert np.all(miss_paper[exact] > 1e-3)  # the paper's controller inverts the 0.3 m map
