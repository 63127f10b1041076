"""Situated and instantiated stride policies (section III-C, eqs 8, 30-31, 34).

A situated policy is a template on a segment, numbered `s = segment * n_templates + t`.
An instantiated policy is a situated policy `i` with a goal `Zg` chosen in
`Gf(i) ∩ D(j)` for some situated `j` it can prepare; `Zg` maximises the margin to the
boundary of the intersection, sampled on a grid over `(ydot, z)` where the `y` extent is an
interval in closed form.

Collision-free regions (`docs/decisions.md`, "Collision-free regions"): the domain of a
policy on segment `j` excludes apex states whose foot meets another block (top or wall)
before reaching the segment, and a goal of policy `i` must be reachable without the COM
meeting a block while it sweeps in stance and rises to the goal. For fixed `(ydot, z)` both
conditions are bounds on `y` (derivation in docs/decisions.md), so the `y` extent stays an
interval.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._core.batching import bucket
from .._core.params import Hopper
from .._core.terrain import Segments, Terrain
from .._models.bhop import safe_sqrt
from .._models.flight import OK, touchdown
from .regions import (
    domain_height_bounds,
    feasible_goal_contains,
    foot_lead,
    goal_height_bounds,
    goal_position_bounds,
    template_domain_contains,
)
from .templates import Templates

#: Slack (m) of the goal-policy test in `y` for a global goal on a segment boundary
#: (`|y - py| = l` within it): it lies on the edge of both neighbours' `Gf`, and `y - py`
#: rounds either way (`goal_policy_margin`, `goal_y_slack`).
GOAL_Y_TOL = 1e-9


def goal_y_slack(y, py, half_length):
    """`GOAL_Y_TOL` where `y` lies on an end of the segment centred at `py`, else 0."""
    return jnp.where(jnp.abs(jnp.abs(y - py) - half_length) <= GOAL_Y_TOL, GOAL_Y_TOL, 0.0)


class SituatedTable(eqx.Module):
    """Arrays that locate situated policies on a terrain (for jitted lookups).

    Attributes:
        centre: `(n_seg, 2)` segment centres `(y, h)`.
        seg_block: `(n_seg,)` block of each segment.
        edge_distance: `(n_seg,)` `de(p)` of each segment.
        block_first: `(n_blocks,)` first segment of each block; `block_count` how many.
        block_left: `(n_blocks,)` left end of the first segment of each block.
    """

    centre: jnp.ndarray
    seg_block: jnp.ndarray
    edge_distance: jnp.ndarray
    block_first: jnp.ndarray
    block_count: jnp.ndarray
    block_left: jnp.ndarray


def situated_table(terrain: Terrain, segs: Segments, seg_length: float) -> SituatedTable:
    blocks = np.asarray(segs.block)
    n_blocks = terrain.n_blocks
    count = np.bincount(blocks, minlength=n_blocks)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    left = np.asarray(terrain.starts, float).copy()
    centre = np.asarray(segs.centre)
    for b in range(n_blocks):
        if count[b]:
            left[b] = centre[first[b], 0] - 0.5 * seg_length
    return SituatedTable(segs.centre, segs.block, segs.edge_distance, jnp.asarray(first),
                         jnp.asarray(count), jnp.asarray(left))


def candidate_situated(apex, table: SituatedTable, templates: Templates, terrain: Terrain,
                       hopper: Hopper, window=None):
    """Situated policies whose (collision-free) domain contains `apex`.

    The nominal descent of the foot (straight below the COM; for SLIP-adjusted templates
    `Y` of eq 37 ahead of it) on `terrain` gives the first touchdown. A situated policy's
    domain contains the apex iff that touchdown is on its segment and the template's
    velocity and energy ranges hold relative to its height. `window` (static): `touchdown`
    tests only that many blocks around the descent (`landing_window`), the same result.

    Returns:
        `(ids, mask)`: `(3 * n_templates,)` situated ids near the touchdown and which of them
        contain the apex.
    """
    lead = foot_lead(apex[2], templates)
    code, block, _, y_foot, _ = touchdown(apex, jnp.stack([lead, -hopper.rho0]), terrain,
                                          hopper, window=window)
    seg_len = templates.segment
    k = jnp.floor((y_foot - table.block_left[block]) / seg_len).astype(jnp.int32)
    n_on = table.block_count[block]
    local = jnp.clip(k + jnp.arange(-1, 2), 0, jnp.maximum(n_on - 1, 0))
    segs = table.block_first[block] + local
    py, h = table.centre[segs, 0], table.centre[segs, 1]
    on_seg = (jnp.abs(y_foot - py) <= 0.5 * seg_len + 1e-12) & (n_on > 0) & (code == OK)
    on_seg = on_seg & (jnp.arange(3) == 0) | on_seg & (local != jnp.roll(local, 1))
    nt = templates.n
    ids = (segs[:, None] * nt + jnp.arange(nt)[None, :]).reshape(-1)

    def contains(t, py_, h_):
        rel = jnp.stack([apex[0] - py_, apex[1] - h_ - hopper.rho0, apex[2]])
        return template_domain_contains(rel, templates.row(t), hopper)

    inside = jax.vmap(jax.vmap(contains, (0, None, None)), (None, 0, 0))(
        jnp.arange(nt), py, h)
    return ids, (inside & on_seg[:, None]).reshape(-1)


def landing_window(points, templates: Templates, terrain: Terrain, hopper: Hopper,
                   step: int = 8):
    """The `window` of `candidate_situated` for apexes `points` `(n, 3)`: how many blocks
    the widest of their nominal descents can meet (`touchdown`'s paths of the foot and the
    COM until the foot falls to the hole depth), rounded up to a multiple of `step` so that
    similar batches share a program; None (every block) where that is most of them, or a
    descent starts at (or within 1e-9 m of) the hole depth or below it.

    Computed on the host with 1e-6 m of slack around each path, more than the device's
    `REACH_PAD`, so the device's window holds every block that meets its paths.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    n = terrain.n_blocks
    if pts.shape[0] == 0:
        return None
    starts, ends = np.asarray(terrain.starts), np.asarray(terrain.ends)
    g, rho0 = float(hopper.g), float(hopper.rho0)
    y, z, ydot = pts[:, 0], pts[:, 1], pts[:, 2]
    fy = y + np.asarray(foot_lead(ydot, templates))  # on the host: no JAX op per batch size
    fall = z - rho0 - (float(np.min(np.asarray(terrain.heights))) - rho0)
    if np.any(fall < 1e-9) or not np.all(np.isfinite(pts)):
        return None
    drift = ydot * np.sqrt(2.0 * fall / g)
    lo = np.minimum(y, fy) + np.minimum(drift, 0.0) - 1e-6
    hi = np.maximum(y, fy) + np.maximum(drift, 0.0) + 1e-6
    count = np.searchsorted(starts, hi, side="right") - np.searchsorted(ends, lo, side="left")
    width = -(-max(int(count.max()), 1) // step) * step
    return None if 2 * width > n else width


# --- region bounding boxes -------------------------------------------------------------


def template_boxes(templates: Templates, hopper: Hopper, n_grid: int = 2001):
    """Axis-aligned boxes of `Gf` and `D` per template, relative coordinates.

    Returns:
        `(gf_box, d_box)`, each `(n_templates, 3, 2)` with rows `(y_rel, zr, ydot)`.
    """
    def one(t):
        tmpl = templates.row(t)
        r_hi = jnp.sqrt(2.0 * tmpl.e_hi / hopper.m)
        v = jnp.linspace(-1.0, 1.0, n_grid) * jnp.maximum(tmpl.k_hi, 1.0) * r_hi * 1.05
        zl, zh = jax.vmap(goal_height_bounds, (0, None, None))(v, tmpl, hopper)
        ok = zh >= zl
        step = v[1] - v[0]
        v_lo = jnp.min(jnp.where(ok, v, jnp.inf)) - step
        v_hi = jnp.max(jnp.where(ok, v, -jnp.inf)) + step
        z_lo = jnp.maximum(jnp.min(jnp.where(ok, zl, jnp.inf)) - 1e-3, 0.0)
        z_hi = jnp.max(jnp.where(ok, zh, -jnp.inf)) + 1e-3
        corners = jnp.array([[v_lo, z_lo], [v_lo, z_hi], [v_hi, z_lo], [v_hi, z_hi]])
        ylo, yhi = goal_position_bounds(corners[:, 0], corners[:, 1], tmpl, hopper)
        gf = jnp.array([[jnp.min(ylo), jnp.max(yhi)], [z_lo, z_hi], [v_lo, v_hi]])
        dvl, dvh = tmpl.v_lo, tmpl.v_hi
        vmax2 = jnp.maximum(dvl**2, dvh**2)
        vmin2 = jnp.where((dvl <= 0) & (dvh >= 0), 0.0, jnp.minimum(dvl**2, dvh**2))
        mg = hopper.m * hopper.g
        dz_lo = jnp.maximum((tmpl.e_lo - 0.5 * hopper.m * vmax2) / mg, 0.0)
        dz_hi = (tmpl.e_hi - 0.5 * hopper.m * vmin2) / mg
        shift = jnp.array([dvl, dvh])[:, None] * safe_sqrt(
            2.0 * jnp.array([dz_lo, dz_hi]) / hopper.g)[None, :]
        shift = shift + foot_lead(jnp.array([dvl, dvh]), tmpl)[:, None]
        l = tmpl.half_length
        d = jnp.array([[-l - jnp.max(shift), l - jnp.min(shift)], [dz_lo, dz_hi], [dvl, dvh]])
        return gf, d

    return jax.vmap(one)(jnp.arange(templates.n))


def candidate_pairs(gf_world: np.ndarray, d_world: np.ndarray, chunk: int = 256):
    """Pairs `(i, j)` whose boxes of `Gf(i)` and `D(j)` overlap in `(y, z, ydot)`, sorted by
    `(i, j)`.

    Each chunk of `Gf` boxes is tested only against the domains whose `y` start lies
    between the chunk's lowest `y` less the widest domain and its highest `y`: no other
    domain can overlap any of its boxes in `y`. Situated policies come in segment order,
    so a chunk covers a short stretch of the map (on a course map with 5 094 situated
    policies: a few hundred domains per chunk instead of all of them). No boxes on either
    side: no pairs.
    """
    if d_world.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    by_start = np.argsort(d_world[:, 0, 0], kind="stable")
    starts = d_world[by_start, 0, 0]
    # A hair wider than the widest domain: the window test must never lose a pair to the
    # rounding of `start - widest`.
    widest = float(np.max(d_world[:, 0, 1] - d_world[:, 0, 0])) * (1 + 1e-9) + 1e-9
    rows, cols = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for start in range(0, gf_world.shape[0], chunk):
        g = gf_world[start:start + chunk]
        lo = np.searchsorted(starts, np.min(g[:, 0, 0]) - widest, side="left")
        hi = np.searchsorted(starts, np.max(g[:, 0, 1]), side="right")
        near = np.sort(by_start[lo:hi])
        d = d_world[near]
        overlap = np.all((g[:, None, :, 0] <= d[None, :, :, 1])
                         & (d[None, :, :, 0] <= g[:, None, :, 1]), axis=2)
        r, c = np.nonzero(overlap)
        rows.append(r + start)
        cols.append(near[c])
    return np.concatenate(rows), np.concatenate(cols)


# --- collision-free y bounds ---------------------------------------------------------------


def _blocks(terrain: Terrain, ndim: int):
    """The terrain's `(heights, starts, ends)` shaped `(n_blocks, 1, ..., 1)` to broadcast
    against apex arrays of `ndim` dimensions (a block axis in front)."""
    shape = (-1,) + (1,) * ndim
    return (terrain.heights.reshape(shape), terrain.starts.reshape(shape),
            terrain.ends.reshape(shape))


def descent_times(z, terrain: Terrain, hopper: Hopper):
    """`(n_blocks, *z.shape)` times the foot takes to fall from apex height `z` to each
    block's top."""
    heights, _, _ = _blocks(terrain, jnp.ndim(z))
    return safe_sqrt(2.0 * (z - hopper.rho0 - heights) / hopper.g)


def _side_lists(higher, starts, ends, step: int) -> np.ndarray:
    """`(n_blocks, 2, K)`: for each block `b`, the blocks `c` with `higher[b, c]` on its left,
    then those on its right, in block order, each list padded with `b` itself. `K` is a
    multiple of `step`, so that maps that differ a little share one shape."""
    sides = np.stack([higher & (ends[None, :] <= starts[:, None]),
                      higher & (starts[None, :] >= ends[:, None])], 1)  # [b, side, c]
    k = bucket(int(sides.sum(2).max()), step)
    out = np.repeat(np.arange(higher.shape[0])[:, None, None], 2, 1).repeat(k, 2)
    b, side, c = np.nonzero(sides)
    out[b, side, (np.cumsum(sides, 2) - 1)[b, side, c]] = c  # in block order on each side
    return out.astype(np.int32)


def _within(window, starts, ends):
    """`[b, c]`: whether block `c` reaches `window[b]`: its right end `>= window[b, 0]` for
    a block left of `b`, its left end `<= window[b, 1]` otherwise (no window: all)."""
    if window is None:
        return True
    lo, hi = window[:, :1], window[:, 1:]
    return np.where(ends[None, :] <= starts[:, None], ends[None, :] >= lo,
                    starts[None, :] <= hi)


def descent_sides(terrain: Terrain, step: int = 4, window=None) -> np.ndarray:
    """`(n_blocks, 2, K)`: for each landing block, the blocks that can bind its descent
    bounds: the higher ones on its left, then those on its right (`descent_y_bounds`), each
    padded with the landing block itself (never higher than itself). `K` is a multiple of
    `step`, so that maps that differ a little share one shape.

    `window`: `(n_blocks, 2)`, for each landing block a `y` interval outside which no
    block's bound can bind (`Layout.side_windows`); the higher blocks whose near end lies
    outside it are left out."""
    heights, starts, ends = (np.asarray(x) for x in (terrain.heights, terrain.starts,
                                                     terrain.ends))
    higher = (heights[None, :] > heights[:, None]) & _within(window, starts, ends)
    return _side_lists(higher, starts, ends, step)


def ascent_sides(terrain: Terrain, hopper: Hopper, step: int = 4, window=None) -> np.ndarray:
    """`(n_blocks, 2, K)`: for each take-off block, the blocks that can bind its rise
    (`ascent_y_bounds`): those standing more than `rho0` above it, on its left, then on its
    right, padded with the take-off block itself (never that far above itself). The test
    keeps 1e-9 m of slack, so the lists hold every block the kernel's own test admits.
    `window`: as in `descent_sides`, per take-off block."""
    heights, starts, ends = (np.asarray(x) for x in (terrain.heights, terrain.starts,
                                                     terrain.ends))
    rise = heights[None, :] - (heights[:, None] + float(hopper.rho0))
    return _side_lists((rise > -1e-9) & _within(window, starts, ends), starts, ends, step)


def descent_y_bounds(ydot, z, block, terrain: Terrain, hopper: Hopper, lead=0.0, t_h=None,
                     sides=None):
    """Apex `y` interval from which the descending foot meets no block before `block`.

    For `ydot > 0` a higher block `b` left of the landing block is cleared iff the foot has
    passed its right end `e_b` when it falls to `H_b`: `y > e_b - ydot t_H`; mirrored for
    `ydot < 0`. The apex must also lie over the map. A foot `lead` ahead of the COM shifts
    the first two bounds by `-lead` (SLIP-adjusted templates, eq 37).

    `ydot`, `z` and `lead` may be arrays of one shape (a grid of apexes); `t_h`: their
    `descent_times`, where the caller has them (they depend on `z` alone); `sides`: the
    landing block's row of `descent_sides`, to test only the blocks that can bind.
    """
    ndim = max(jnp.ndim(ydot), jnp.ndim(z), jnp.ndim(lead))
    heights, starts, ends = _blocks(terrain, ndim)
    t_h = descent_times(z, terrain, hopper) if t_h is None else t_h
    left_of, right_of = (slice(None), slice(None)) if sides is None else (sides[0], sides[1])
    h = terrain.heights[block]
    left = ((heights[left_of] > h) & (ends[left_of] <= terrain.starts[block]) & (ydot > 0))
    right = ((heights[right_of] > h) & (starts[right_of] >= terrain.ends[block]) & (ydot < 0))
    lo = jnp.max(jnp.where(left, ends[left_of] - ydot * t_h[left_of] - lead, -jnp.inf), axis=0)
    hi = jnp.min(jnp.where(right, starts[right_of] - ydot * t_h[right_of] - lead, jnp.inf),
                 axis=0)
    return jnp.maximum(lo, terrain.starts[0]), jnp.minimum(hi, terrain.ends[-1])


def ascent_times(z, block, terrain: Terrain, hopper: Hopper):
    """`(t_up, t_h)`: the rise time from `block`'s virtual ground to the apex at height `z`,
    and `(n_blocks, *z.shape)` times the rise takes to reach each block's top (`t_up` for
    blocks above `z`)."""
    heights, _, _ = _blocks(terrain, jnp.ndim(z))
    z_lo = terrain.heights[block] + hopper.rho0
    t_up = safe_sqrt(2.0 * (z - z_lo) / hopper.g)
    zdot = hopper.g * t_up
    rise = heights - z_lo
    t_h = jnp.where(heights < z, (zdot - safe_sqrt(zdot**2 - 2.0 * hopper.g * rise)) / hopper.g,
                    t_up)
    return t_up, t_h


def ascent_y_bounds(ydot, z, block, terrain: Terrain, hopper: Hopper, times=None,
                    sides=None):
    """Goal apex `y` interval for which the COM, lifting off from `block`, meets no block.

    The COM sweeps at `h + rho0` from the touchdown (on `block`) to the liftoff point
    `y - ydot t_up`, then rises. A block `b` to the right with `H_b > h + rho0` is cleared iff
    the COM is still left of `s_b` when it has risen to `H_b` (or at the apex, if it never
    does): `y_lo + max(ydot, 0) t_H < s_b`; mirrored on the left.

    `ydot` and `z` may be arrays of one shape; `times`: their `ascent_times`, where the
    caller has them (they depend on `z` alone); `sides`: the take-off block's row of
    `ascent_sides`, to test only the blocks that can bind.
    """
    ndim = max(jnp.ndim(ydot), jnp.ndim(z))
    heights, starts, ends = _blocks(terrain, ndim)
    t_up, t_h = ascent_times(z, block, terrain, hopper) if times is None else times
    left_of, right_of = (slice(None), slice(None)) if sides is None else (sides[0], sides[1])
    y_lo_shift = ydot * t_up

    def higher(of):
        return heights[of] - (terrain.heights[block] + hopper.rho0) > 0

    right = higher(right_of) & (starts[right_of] >= terrain.ends[block])
    left = higher(left_of) & (ends[left_of] <= terrain.starts[block])
    hi = jnp.min(jnp.where(right, starts[right_of] + y_lo_shift
                           - jnp.maximum(ydot, 0) * t_h[right_of], jnp.inf), axis=0)
    lo = jnp.max(jnp.where(left, ends[left_of] + y_lo_shift
                           - jnp.minimum(ydot, 0) * t_h[left_of], -jnp.inf), axis=0)
    return lo, hi


def tall(terrain: Terrain, hopper: Hopper) -> bool:
    """Whether some block stands higher than another's virtual ground `h + rho0`: the test
    `ascent_y_bounds` makes of every block (`higher`), in the same arithmetic."""
    heights = np.asarray(terrain.heights)
    return bool(np.any(heights[None, :] - (heights[:, None] + float(hopper.rho0)) > 0))


# --- goal choice on a grid ----------------------------------------------------------------


def _axis_margin(mask, spacing, axis):
    """Distance along `axis` from each cell to the nearest cell outside `mask`.

    The region boundary is taken halfway between an inside and an outside cell; the grid's
    own edges count as boundary (the grid spans the overlap of the regions' boxes).
    """
    n = mask.shape[axis]
    shape = [1] * mask.ndim
    shape[axis] = n
    idx = jnp.arange(n).reshape(shape)
    prev_out = jax.lax.cummax(jnp.where(mask, -1, idx), axis=axis)
    next_out = jax.lax.cummin(jnp.where(mask, n, idx), axis=axis, reverse=True)
    return (jnp.minimum(idx - prev_out, next_out - idx) - 0.5) * spacing


class PairGrid(eqx.Module):
    """Static sampling sizes of the intersection grid."""

    n_v: int = eqx.field(static=True, default=16)
    n_z: int = eqx.field(static=True, default=16)


def _velocity_grid(v0, v1, grid: PairGrid):
    """The `n_v` cell centres of a pair's velocity range `[v0, v1]`, and their spacing."""
    dv = (v1 - v0) / grid.n_v
    return v0 + (jnp.arange(grid.n_v) + 0.5) * dv, dv


def _height_limits(vs, tmpl_i, tmpl_j, hopper: Hopper):
    """`(4, n_v)`: relative `z` limits `(lo, hi)` of `Gf(i)`, then of `D(j)`, at each `ydot`."""
    gzl, gzh = jax.vmap(goal_height_bounds, (0, None, None))(vs, tmpl_i, hopper)
    dzl, dzh = jax.vmap(domain_height_bounds, (0, None, None))(vs, tmpl_j, hopper)
    return jnp.stack([gzl, gzh, dzl, dzh])


def pair_limits(templates: Templates, hopper: Hopper, v_box, grid: PairGrid):
    """`(n_t, n_t, 4, n_v)`: `_height_limits` of every template pair `(i, j)` on its velocity
    grid over `v_box[i, j]` (the overlap of `Gf(i)`'s and `D(j)`'s `ydot` ranges).

    A pair's velocity grid, and so these limits, depend on its two templates alone, not on
    where they are situated: computed once per template pair, not once per candidate pair
    (the most costly part of screening them).
    """
    nt = templates.n

    def one(ti, tj):
        vs, _ = _velocity_grid(v_box[ti, tj, 0], v_box[ti, tj, 1], grid)
        return _height_limits(vs, templates.row(ti), templates.row(tj), hopper)

    ti, tj = jnp.meshgrid(jnp.arange(nt), jnp.arange(nt), indexing="ij")
    return jax.vmap(jax.vmap(one))(ti, tj)


def _pair_grid(ti, seg_i, tj, seg_j, box, table: SituatedTable, templates: Templates,
               hopper: Hopper, grid: PairGrid, limits=None):
    """The `(ydot, z)` grid of a pair with each region's `z` limits and `y` extents.

    `limits`: the `pair_limits` of the templates, where the caller has them.
    """
    tmpl_i, tmpl_j = templates.row(ti), templates.row(tj)
    py_i, h_i = table.centre[seg_i, 0], table.centre[seg_i, 1]
    py_j, h_j = table.centre[seg_j, 0], table.centre[seg_j, 1]
    rho0 = hopper.rho0
    (z0, z1), (v0, v1) = box[0], box[1]
    vs, dv = _velocity_grid(v0, v1, grid)
    dz = (z1 - z0) / grid.n_z
    zs = z0 + (jnp.arange(grid.n_z) + 0.5) * dz

    if limits is None:
        gzl, gzh, dzl, dzh = _height_limits(vs, tmpl_i, tmpl_j, hopper)
    else:
        gzl, gzh, dzl, dzh = limits[ti, tj]
    gzl, gzh = gzl + h_i + rho0, gzh + h_i + rho0
    dzl, dzh = dzl + h_j + rho0, dzh + h_j + rho0
    # D(j) needs zr > 0 strictly; stay a hair above the virtual ground.
    dzl = jnp.maximum(dzl, h_j + rho0 + 1e-6)
    V, Z = jnp.meshgrid(vs, zs, indexing="ij")
    g_lo, g_hi = goal_position_bounds(V, Z - h_i - rho0, tmpl_i, hopper)
    shift_j = V * safe_sqrt(2.0 * (Z - h_j - rho0) / hopper.g) + foot_lead(V, tmpl_j)
    l = templates.half_length
    return {"V": V, "Z": Z, "dv": dv, "dz": dz, "gzl": gzl, "gzh": gzh, "dzl": dzl,
            "dzh": dzh, "g_lo": g_lo + py_i, "g_hi": g_hi + py_i,
            "d_lo": py_j - shift_j - l, "d_hi": py_j - shift_j + l}


def pair_may_intersect(ti, seg_i, tj, seg_j, box, table: SituatedTable, templates: Templates,
                       hopper: Hopper, grid: PairGrid, limits=None):
    """Whether `Gf(i) ∩ D(j)` has a grid cell before the collision clauses are applied.

    The collision clauses only shrink the `y` extents, so a pair rejected here is empty in
    `pair_goal` too; this cheap pass (no per-block work) screens the candidate pairs.
    `limits`: as in `_pair_grid`.
    """
    c = _pair_grid(ti, seg_i, tj, seg_j, box, table, templates, hopper, grid, limits)
    zl = jnp.maximum(c["gzl"], c["dzl"])[:, None]
    zh = jnp.minimum(c["gzh"], c["dzh"])[:, None]
    y_lo = jnp.maximum(c["g_lo"], c["d_lo"])
    y_hi = jnp.minimum(c["g_hi"], c["d_hi"])
    return jnp.any((c["Z"] >= zl) & (c["Z"] <= zh) & (y_hi > y_lo))


def pair_goal(ti, seg_i, tj, seg_j, box, table: SituatedTable, templates: Templates,
              terrain: Terrain, hopper: Hopper, grid: PairGrid, rise: bool = True,
              limits=None, sides=None):
    """Best goal in `Gf(i) ∩ D(j)` for one candidate pair.

    Arguments:
        ti, tj: template indices; seg_i, seg_j: segment indices.
        box: `(2, 2)` overlap of the two boxes in `(z, ydot)` (world `z`).
        rise: whether any block stands higher than another by more than `rho0` (`tall`);
            without one the rise's collision clause (`ascent_y_bounds`) never binds and is
            skipped, which leaves every result as it is.
        limits: the templates' `pair_limits`, where the caller has them.
        sides: the terrain's `(descent_sides, ascent_sides)`, where the caller has them.

    Returns:
        `(found, goal, margin, margin_d)`: whether the intersection is non-empty, the goal
        `(y, z, ydot)` maximising the margin to the intersection's boundary, that margin, and
        the goal's margin to `∂D(j)` alone (used in the safety measure, eq 34).
    """
    c = _pair_grid(ti, seg_i, tj, seg_j, box, table, templates, hopper, grid, limits)
    V, Z, dv, dz, dzl, dzh = c["V"], c["Z"], c["dv"], c["dz"], c["dzl"], c["dzh"]
    tmpl_j = templates.row(tj)
    b_i, b_j = table.seg_block[seg_i], table.seg_block[seg_j]
    zl = jnp.maximum(c["gzl"], dzl)[:, None]
    zh = jnp.minimum(c["gzh"], dzh)[:, None]
    # The fall and rise times depend on the cell's height alone: once per grid column.
    zs = Z[:1]
    c_lo, c_hi = descent_y_bounds(V, Z, b_j, terrain, hopper, foot_lead(V, tmpl_j),
                                  descent_times(zs, terrain, hopper),
                                  None if sides is None else sides[0][b_j])
    if rise:
        a_lo, a_hi = ascent_y_bounds(V, Z, b_i, terrain, hopper,
                                     ascent_times(zs, b_i, terrain, hopper),
                                     None if sides is None else sides[1][b_i])
    else:
        a_lo, a_hi = -jnp.inf, jnp.inf
    dom_lo, dom_hi = jnp.maximum(c["d_lo"], c_lo), jnp.minimum(c["d_hi"], c_hi)
    y_lo = jnp.maximum(jnp.maximum(c["g_lo"], a_lo), dom_lo)
    y_hi = jnp.minimum(jnp.minimum(c["g_hi"], a_hi), dom_hi)

    mask = (Z >= zl) & (Z <= zh) & (y_hi > y_lo)
    y_mid = 0.5 * (y_lo + y_hi)
    margin = jnp.minimum(jnp.minimum(0.5 * (y_hi - y_lo), jnp.minimum(Z - zl, zh - Z)),
                         jnp.minimum(_axis_margin(mask, dz, 1), _axis_margin(mask, dv, 0)))
    # Many cells tie (the y width is the same in every cell); rounding to 1 nm makes the
    # first of the tied cells win whatever the last bits of the arithmetic are.
    margin = jnp.where(mask, jnp.round(margin, 9), -jnp.inf)
    best = jnp.argmax(margin)
    a, b = jnp.unravel_index(best, margin.shape)

    mask_d = ((Z >= dzl[:, None]) & (Z <= dzh[:, None]) & (dom_hi > dom_lo)
              & (V >= tmpl_j.v_lo) & (V <= tmpl_j.v_hi))
    y_g = y_mid[a, b]
    margin_d = jnp.minimum(
        jnp.minimum(y_g - dom_lo[a, b], dom_hi[a, b] - y_g),
        jnp.minimum(jnp.minimum(Z[a, b] - dzl[a], dzh[a] - Z[a, b]),
                    # Only the goal's cell's margins: along its row and its column.
                    jnp.minimum(_axis_margin(mask_d[a][None, :], dz, 1)[0, b],
                                _axis_margin(mask_d[:, b][:, None], dv, 0)[a, 0])))
    goal = jnp.stack([y_g, Z[a, b], V[a, b]])
    return jnp.any(mask), goal, margin[a, b], margin_d


def goal_policy_margin(goal, ti, seg_i, table: SituatedTable, templates: Templates,
                       terrain: Terrain, hopper: Hopper, n_steps: int = 50):
    """Whether situated `(ti, seg_i)` can reach the global goal, and the goal's margin.

    The margin is the smallest distance, along `y`, `z` and `ydot`, from `goal` to the
    boundary of `Gf(i)` restricted to collision-free rises (steps of 1 cm / 1 cm/s). The goal
    itself, where it lies on an end of the segment, is tested with `GOAL_Y_TOL` of slack in
    `y`, so that a goal on the boundary between two segments belongs to both
    (docs/decisions.md, "Goals on segment boundaries").
    """
    tmpl = templates.row(ti)
    if tmpl.slip is not None and tmpl.slip.keep_direction:
        # A SLIP stride cannot stop on the spot: the last strides creep onto a goal at rest
        # through the domain of its own segment, so a goal policy's goal may lie up to a
        # segment behind the touchdown (docs/decisions.md, "Direction rule").
        tmpl = dataclasses.replace(
            tmpl, slip=dataclasses.replace(tmpl.slip, direction_slack=1.0))
    py, h = table.centre[seg_i, 0], table.centre[seg_i, 1]
    b = table.seg_block[seg_i]

    def ok(g, y_tol=0.0):
        rel = jnp.stack([g[0] - py, g[1] - h - hopper.rho0, g[2]])
        lo, hi = ascent_y_bounds(g[2], g[1], b, terrain, hopper)
        return feasible_goal_contains(rel, tmpl, hopper, y_tol) & (g[0] > lo) & (g[0] < hi)

    steps = 0.01 * jnp.arange(1, n_steps + 1)
    eye = jnp.eye(3)
    probes = goal[None, None, None, :] + (jnp.array([-1.0, 1.0])[None, :, None, None]
                                          * steps[None, None, :, None]
                                          * eye[:, None, None, :])
    inside = jax.vmap(jax.vmap(jax.vmap(ok)))(probes)
    first_out = jnp.argmin(inside, axis=2)
    dist = jnp.where(jnp.all(inside, axis=2), steps[-1], steps[first_out] - 0.005)
    reached = ok(goal, goal_y_slack(goal[0], py, templates.half_length))
    return reached, jnp.where(reached, jnp.min(dist), -jnp.inf)


def goal_robustness(goal, table: SituatedTable, templates: Templates, terrain: Terrain,
                    hopper: Hopper, half_width):
    """Safety sampling: fraction of a box of perturbed goals that some situated domain holds.

    The box `goal + {-1, 0, 1}^3 * half_width` (27 probes) stands for where a disturbed
    stride may end. A probe outside every situated domain (beyond the template set's
    velocity or energy range on the block it would land on, over a hole, into a wall) is a
    state from which no policy can continue.
    """
    _, inside = probe_candidates(goal, table, templates, terrain, hopper, half_width)
    return jnp.mean(jnp.any(inside, axis=1).astype(float))


#: The goal's own place among its `probe_box` (offset `(0, 0, 0)`: the goal, bit for bit).
PROBE_CENTRE = 13


def probe_box(goal, half_width):
    """`(27, 3)`: the safety-sampling probes `goal + {-1, 0, 1}^3 * half_width`."""
    offsets = jnp.stack(jnp.meshgrid(*[jnp.arange(-1.0, 2.0)] * 3, indexing="ij"), -1)
    return goal + offsets.reshape(-1, 3) * half_width


def probe_candidates(goal, table: SituatedTable, templates: Templates, terrain: Terrain,
                     hopper: Hopper, half_width):
    """`candidate_situated` of each probe of `probe_box`: `(27, 3 * n_templates)` ids and
    masks."""
    return jax.vmap(candidate_situated, (0, None, None, None, None))(
        probe_box(goal, half_width), table, templates, terrain, hopper)
