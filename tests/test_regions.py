"""Closed-form regions against the definitions they come from."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop._core.params import Hopper
from jaxhop._core.terrain import builtin_terrain, make_terrain, random_terrain
from jaxhop._models.flight import OK, touchdown
from jaxhop._planning.policies import (
    ascent_times,
    ascent_y_bounds,
    descent_sides,
    descent_times,
    descent_y_bounds,
    tall,
)
from jaxhop._planning.regions import (
    feasible_goal_contains,
    feasible_goal_contains_brute,
    goal_height_bounds,
    goal_height_bounds_printed,
    goal_position_bounds,
    template_domain_contains,
)
from jaxhop._planning.templates import paper_templates

HOP = Hopper()
TEMPLATES = paper_templates()


def _goal_grid(tmpl, n=41):
    yd = jnp.linspace(-5.0, 5.0, n)
    zr = jnp.linspace(0.01, 2.5, n)
    YD, ZR = jnp.meshgrid(yd, zr, indexing="ij")
    lo, hi = goal_position_bounds(YD, ZR, tmpl, HOP)
    return jnp.stack([(0.5 * (lo + hi)).ravel(), ZR.ravel(), YD.ravel()], 1)


# The template is an argument, so all 20 cases run on the same four compiled programs
# (eager `vmap`s compile every operation anew for each template's constants).
_closed_form = jax.jit(jax.vmap(feasible_goal_contains, (0, None, None)))
_brute = jax.jit(jax.vmap(feasible_goal_contains_brute, (0, None, None, None, None)),
                 static_argnums=(3, 4))


@pytest.mark.slow
@pytest.mark.parametrize("t", range(20))
def test_closed_form_goal_matches_definition(t):
    """Eq 6 by brute force (dense domain sample + deadbeat + limits) vs the closed form.

    The closed form uses the domain's exact extreme points, the brute force a finite sample,
    so the brute-force set may only be larger, and only near the boundary: the extra points
    must vanish as the sample gets denser.
    """
    tmpl = TEMPLATES.row(t)
    pts = _goal_grid(tmpl)
    cf = np.asarray(_closed_form(pts, tmpl, HOP))
    bf = np.asarray(_brute(pts, tmpl, HOP, 16, False))
    assert cf.sum() > 20
    assert not np.any(cf & ~bf), "closed form accepts a goal the definition rejects"
    extra = np.nonzero(bf & ~cf)[0]
    # The definition on the sample plus the domain's exact extreme points is the closed form.
    exact = np.asarray(_brute(pts, tmpl, HOP, 16, True))
    np.testing.assert_array_equal(exact, cf)
    if extra.size:
        # On the whole grid (one shape for every case), counted on the extra points.
        dense = np.asarray(_brute(pts, tmpl, HOP, 64, False))[extra]
        assert dense.sum() < extra.size


def test_goal_position_bounds_match_definition():
    """y-extent of Gf: every touchdown in [-l, l] must reach it with dy in the limits."""
    tmpl = TEMPLATES.row(12)
    ydot, zr = 0.4, 0.5
    lo, hi = goal_position_bounds(ydot, zr, tmpl, HOP)
    t_up = np.sqrt(2 * zr / HOP.g)
    for y in np.linspace(float(lo) - 0.05, float(hi) + 0.05, 41):
        y_lo = y - ydot * t_up
        dy_needed = y_lo - np.array([-0.075, 0.075])
        ok = np.all((dy_needed >= 0) & (dy_needed <= 0.25))
        assert ok == (float(lo) <= y <= float(hi)) or min(abs(y - lo), abs(y - hi)) < 1e-9


@pytest.mark.slow
def test_height_bounds_agree_with_membership():
    tmpl = TEMPLATES.row(8)
    yd, zr = np.meshgrid(np.linspace(-3, 2, 26), np.linspace(0.02, 2.4, 60), indexing="ij")
    yd, zr = jnp.asarray(yd.ravel()), jnp.asarray(zr.ravel())
    zl, zh = jax.vmap(goal_height_bounds, (0, None, None))(yd, tmpl, HOP)
    lo, hi = goal_position_bounds(yd, zr, tmpl, HOP)
    pts = jnp.stack([0.5 * (lo + hi), zr, yd], 1)
    inside = np.asarray(jax.vmap(feasible_goal_contains, (0, None, None))(pts, tmpl, HOP))
    expect = np.asarray((zr >= zl) & (zr <= zh))
    away = np.asarray(jnp.minimum(jnp.abs(zr - zl), jnp.abs(zr - zh)) > 1e-9)
    assert inside.sum() > 100
    np.testing.assert_array_equal(inside[away], expect[away])


def test_printed_equations_disagree_with_definition():
    """Eqs 47-48 as printed (min/max swapped, zdot not squared) are not the feasible set."""
    tmpl = TEMPLATES.row(12)
    zl_p, zh_p = (float(v) for v in goal_height_bounds_printed(0.3, tmpl, HOP))
    zl, zh = (float(v) for v in goal_height_bounds(0.3, tmpl, HOP))
    assert abs(zl_p - zl) > 0.05 or abs(zh_p - zh) > 0.05


@pytest.mark.slow
def test_domain_matches_touchdown_definition():
    """D(Phi) of eqs 38-41: touchdown of the nominal descent falls on [-l, l]."""
    rng = np.random.default_rng(0)
    flat = make_terrain([(-5.0, 5.0, 0.0)])
    fall, contains = jax.jit(touchdown), jax.jit(template_domain_contains)  # one compile each
    for _ in range(300):
        t = int(rng.integers(20))
        tmpl = TEMPLATES.row(t)
        z = jnp.array([rng.uniform(-0.6, 0.6), rng.uniform(0.01, 1.6), rng.uniform(-2.6, 2.6)])
        code, _, _, y_foot, _ = fall(jnp.array([z[0], z[1] + 1.0, z[2]]),
                                     jnp.array([0.0, -1.0]), flat, HOP)
        energy = 0.5 * HOP.m * z[2] ** 2 + HOP.m * HOP.g * z[1]
        expect = (code == OK and abs(float(y_foot)) <= 0.075 and tmpl.v_lo <= z[2] <= tmpl.v_hi
                  and tmpl.e_lo <= energy <= tmpl.e_hi)
        assert bool(contains(z, tmpl, HOP)) == bool(expect)


@pytest.mark.slow
def test_collision_free_bounds_match_simulated_descent_and_rise():
    """The y bounds used for instantiation agree with the simulator's touchdown test."""
    terrain = builtin_terrain("reference")
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(400):
        block = int(rng.integers(terrain.n_blocks))
        s, e, h = terrain.blocks()[block]
        ydot = rng.uniform(-2.5, 2.5)
        z = h + 1.0 + rng.uniform(0.02, 1.4)
        t_d = np.sqrt(2 * (z - h - 1.0) / HOP.g)
        y_td = rng.uniform(s + 0.01, e - 0.01)
        y = y_td - ydot * t_d
        lo, hi = (float(v) for v in descent_y_bounds(ydot, z, block, terrain, HOP))
        code, b, _, _, _ = touchdown(jnp.array([y, z, ydot]), jnp.array([0.0, -1.0]), terrain,
                                     HOP)
        clear = int(code) == OK and int(b) == block
        if min(abs(y - lo), abs(y - hi)) > 1e-9:
            assert clear == (lo < y < hi), (y, z, ydot, block, lo, hi, int(code), int(b))
            checked += 1
    assert checked > 350
    # Rising from the bottom of a 1.1 m deep well: a wall taller than the leg.
    well = make_terrain([(0.0, 1.0, 1.1), (1.0, 2.0, 0.0), (2.0, 3.0, 1.1)])
    lo, hi = ascent_y_bounds(0.5, 1.9, 1, well, HOP)
    assert float(hi) < 2.0 + 0.5 * np.sqrt(2 * 0.9 / HOP.g) and float(lo) > 1.0


@pytest.mark.slow
def test_bounds_on_a_grid_equal_the_bounds_of_each_cell():
    """The grid form of the collision bounds (block axis in front, fall and rise times per
    grid column) gives, cell by cell, the bounds of that one apex (to rounding: op by op,
    the two forms round differently in the last bit); and where no block stands `rho0`
    above another (`tall`), the rise's bound never binds."""
    well = make_terrain([(0.0, 1.0, 1.1), (1.0, 2.0, 0.0), (2.0, 2.5, 0.4), (2.5, 3.0, 1.1)])
    V, Z = jnp.meshgrid(jnp.linspace(-2.0, 2.0, 5), jnp.linspace(1.05, 2.6, 6), indexing="ij")
    lead = 0.01 * V
    for block in range(well.n_blocks):
        c_lo, c_hi = descent_y_bounds(V, Z, block, well, HOP, lead,
                                      descent_times(Z[:1], well, HOP))
        a_lo, a_hi = ascent_y_bounds(V, Z, block, well, HOP, ascent_times(Z[:1], block, well,
                                                                        HOP))
        for a in range(V.shape[0]):
            for b in range(V.shape[1]):
                one = descent_y_bounds(V[a, b], Z[a, b], block, well, HOP, lead[a, b])
                np.testing.assert_allclose([c_lo[a, b], c_hi[a, b]], one, rtol=0, atol=1e-12)
                one = ascent_y_bounds(V[a, b], Z[a, b], block, well, HOP)
                np.testing.assert_allclose([a_lo[a, b], a_hi[a, b]], one, rtol=0, atol=1e-12)
    assert tall(well, HOP)
    bound = ascent_y_bounds(V, Z, 1, well, HOP)
    assert np.isfinite(np.asarray(bound)).any()  # the wells' walls bind the rise from below

    # Only the blocks `descent_sides` lists are tested, with the same result.
    rough = random_terrain(jax.random.PRNGKey(3), 14.0, segments_per_block=(2, 4))
    for terrain in (well, rough):
        sides = descent_sides(terrain)
        assert sides.shape[2] < terrain.n_blocks or terrain is well
        for block in range(terrain.n_blocks):
            full = descent_y_bounds(V, Z, block, terrain, HOP, lead)
            pruned = descent_y_bounds(V, Z, block, terrain, HOP, lead, sides=sides[block])
            np.testing.assert_array_equal(np.asarray(full), np.asarray(pruned))

    flat_ish = builtin_terrain("reference")
    assert not tall(flat_ish, HOP)
    for block in range(flat_ish.n_blocks):
        lo, hi = ascent_y_bounds(V, Z + 0.5, block, flat_ish, HOP)
        assert np.all(np.asarray(lo) == -np.inf) and np.all(np.asarray(hi) == np.inf)


@pytest.mark.parametrize("where", ["well", "course"])
def test_rise_bounds_over_the_listed_blocks_equal_the_whole_terrains(where):
    # `ascent_sides` lists, for each take-off block, the blocks standing more than `rho0`
    # above it; the rise's bound over those alone is the whole terrain's, bit for bit.
    from jaxhop._core.batching import pad_terrain
    from jaxhop._planning.policies import ascent_sides
    from jaxhop.mppc import load_course
    from jaxhop.parkour import course_map, leg_hopper

    if where == "well":
        hop = HOP
        terrain = make_terrain([(0.0, 1.0, 1.1), (1.0, 2.0, 0.0), (2.0, 2.5, 0.4),
                                (2.5, 3.0, 1.1)])
        zs = jnp.linspace(1.05, 2.6, 6)
    else:
        hop = leg_hopper()
        course = load_course("mppc-hw-two-rounds")
        terrain = pad_terrain(course_map(course, course.environment, hop).plan, 128)
        zs = jnp.linspace(0.2, 0.9, 6)
    V, Z = jnp.meshgrid(jnp.linspace(-1.5, 1.5, 7), zs, indexing="ij")
    sides = ascent_sides(terrain, hop)
    own = np.arange(terrain.n_blocks)[:, None, None]
    assert (sides != own).any()  # some block stands high enough to bind a rise
    assert sides.shape[2] < terrain.n_blocks or where == "well"
    bound = False
    for block in range(terrain.n_blocks):
        full = np.asarray(ascent_y_bounds(V, Z, block, terrain, hop))
        pruned = np.asarray(ascent_y_bounds(V, Z, block, terrain, hop, sides=sides[block]))
        np.testing.assert_array_equal(full, pruned)
        bound |= bool(np.isfinite(full).any())
    assert bound

