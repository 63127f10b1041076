"""Reactive plans on a course map, built in full or updated incrementally (issue 8).

`build_course_plan` runs the stages of `jaxhop.build_plan` (situate, candidate pairs,
screen, instantiate, goal policies, prepares, safety sampling, deploy) with one change:
policies are situated only on the map's allowed blocks (restricted floor and margin
bands carry segments, so that `Plan.table()` stays consistent, but none of their situated
policies is ever instantiated, prepared or deployed). It keeps what an update needs: every
screened pair's result, the prepares rows and the robustness scores.

With `previous`, `build_course_plan` updates such a plan for a new course map (a
snapshot) and recomputes only what the change can affect. The *changed blocks* are every
block that is not in both maps with the same `(start, end, plan height, true height,
kind)`, old and new versions alike. Situated policies on unchanged blocks keep their
segment (their ids are remapped); those on changed blocks are *new*. Then:

* a pair `(i, j)` is recomputed iff `i` or `j` is new, or a changed block can bind one of
  its collision clauses in some cell of its grid (`_Context.ascent_binds` on `i`'s segment,
  `_Context.descent_binds` on `j`'s; closed-form bounds of the clauses of
  `ascent_y_bounds` / `descent_y_bounds`). Only blocks higher than the segment (`h + rho0`
  for the rise) count, on the side the velocity range can reach, within the distance the
  COM (foot) covers while it is below the block's top. All other pairs keep their screened
  result, goal and margins; a recomputed old pair keeps its old screen (it depends on no
  block);
* a prepares row `P[a, :]` is remapped from the old row iff the goal is unchanged and its
  nominal descent meets no changed block (`_Context.touched`: the foot's `y` while it is
  below the block's top, until it reaches the lowest block); a robustness score likewise
  for the whole probe box;
* goal policies are reused iff every candidate is an old policy and no changed block can
  bind the ascent bounds at the goal's probes (`_goal_binds`); deployment is redone.

docs/parkour_reactive.md derives each test. A change of the map's ends, of its lowest
height (which the hole test uses) or of the goal, or SLIP-adjusted templates, fall back to
a full build. Instantiated policies are kept in a canonical order (goal policies by
situated id, then pairs by `(situated, target)`), so an update and a full build of the
same map feed `deploy` the same arrays.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from .._deploy import by_robustness, deploy
from .._graph import count_edges
from .._params import Hopper
from .._plan import SAFETY_WE, SAFETY_WG, Plan
from .._policies import (
    PairGrid,
    SituatedTable,
    candidate_pairs,
    candidate_situated,
    goal_policy_margin,
    pair_goal,
    pair_may_intersect,
    situated_table,
    template_boxes,
)
from .._templates import Templates, template_scales
from .._terrain import Terrain, segments
from ._map import CourseMap

_PAIR_CHUNK = 4096
_ROW_CHUNK = 8192
#: Probe points per chunk of safety sampling (27 per policy).
_PROBE_CHUNK = 65536
#: Safety-sampling probe half-widths of `jaxhop.build_plan` (m, m, m/s) for the 1 m hopper;
#: Froude-scaled for other hoppers.
PROBE = 0.2
_PAD = 1e-6
_TOL = 1e-9
_GRID = PairGrid()


def _screen(ti, si, tj, sj, boxes, table, templates, hopper, grid):
    return jax.vmap(pair_may_intersect, (0, 0, 0, 0, 0, None, None, None, None))(
        ti, si, tj, sj, boxes, table, templates, hopper, grid)


def _pairs(ti, si, tj, sj, boxes, table, templates, terrain, hopper, grid):
    return jax.vmap(pair_goal, (0, 0, 0, 0, 0, None, None, None, None, None))(
        ti, si, tj, sj, boxes, table, templates, terrain, hopper, grid)


def _rows(goals, allowed, table, templates, terrain, hopper):
    ids, inside = jax.vmap(candidate_situated, (0, None, None, None, None))(
        goals, table, templates, terrain, hopper)
    return ids, inside & allowed[ids]


def _offsets(half_width) -> np.ndarray:
    """`(27, 3)` safety-sampling probe offsets: the corners, edge and face centres and
    centre of the box `+- half_width` (`jaxhop.build_plan`'s probes)."""
    grid = np.stack(np.meshgrid(*[np.arange(-1.0, 2.0)] * 3, indexing="ij"), -1)
    return grid.reshape(-1, 3) * np.asarray(half_width, float)


def _held(points, allowed, table, templates, terrain, hopper):
    """Whether an allowed situated policy's domain holds each probe point."""
    def held(p):
        ids, inside = candidate_situated(p, table, templates, terrain, hopper)
        return jnp.any(inside & allowed[ids])

    return jax.vmap(held)(points)


def _goal_policies(goal, ti, si, table, templates, terrain, hopper):
    return jax.vmap(goal_policy_margin, (None, 0, 0, None, None, None, None))(
        goal, ti, si, table, templates, terrain, hopper)


_screen_jit = jax.jit(_screen, static_argnames=("grid",))
_pairs_jit = jax.jit(_pairs, static_argnames=("grid",))
_rows_jit = jax.jit(_rows)
_held_jit = jax.jit(_held)
_goal_jit = jax.jit(_goal_policies)


def _padded(fn, n, chunk, *arrays, small=False):
    """Run `fn(*chunk_of_arrays)` over `n` items in fixed-size chunks.

    Two chunk sizes only (others would recompile, seconds, in an update): `chunk`, and
    `chunk // 8`. A full build uses `chunk` (`chunk // 8` if that holds all `n`). An
    update (`small`) runs whole `chunk`s while that many items remain and `chunk // 8` for
    the rest, so that padding the last chunk wastes at most `chunk // 8` items of work.
    """
    outs = None
    if small:
        big, tail = chunk, chunk // 8
    else:
        big = tail = chunk // 8 if n <= chunk // 8 else chunk
    start = 0
    while start < n:
        c = big if n - start >= big else tail
        stop = min(start + c, n)
        idx = np.arange(start, start + c).clip(max=n - 1)
        res = fn(*[jnp.asarray(a[idx]) for a in arrays])
        res = res if isinstance(res, tuple) else (res,)
        res = [np.asarray(r)[: stop - start] for r in res]
        if outs is None:
            outs = [[] for _ in res]
        for o, r in zip(outs, res):
            o.append(r)
        start = stop
    if outs is None:
        return None
    return tuple(np.concatenate(o) for o in outs)


@dataclasses.dataclass
class CoursePlan:
    """A deployed plan on a course map plus what an incremental update reuses.

    Attributes:
        cmap: the course map.
        plan: the `jaxhop.Plan` (its `terrain` is the planner's map `cmap.plan`).
        pair_key: `(n_screened,)` sorted keys `i * n_situated + j` of the screened pairs.
        pair_found, pair_goal, pair_margin, pair_margin_d: their `pair_goal` results.
        pair_inst: instantiated index of each screened pair (-1: empty intersection, or
            dropped).
        probe_held: `(n_instantiated, 27)` whether each safety-sampling probe of each
            policy is held (`robustness` is its mean; goal policies: all true). An
            update recomputes only the probes whose descents can meet a change.
        stats: counts and stage timings (`seconds` in total); `recomputed_*` for updates.
    """

    cmap: CourseMap
    plan: Plan
    pair_key: np.ndarray
    pair_found: np.ndarray
    pair_goal: np.ndarray
    pair_margin: np.ndarray
    pair_margin_d: np.ndarray
    pair_inst: np.ndarray
    stats: dict
    probe_held: np.ndarray | None = None


def _segments(terrain: Terrain, seg_length: float):
    """`segments` with centres rounded to 1e-12 m.

    `course_map` puts segments on an absolute grid, but `segments` computes a centre from
    its block's start, so the same segment in a re-cut block differs in the last bits. An
    update reuses results computed with the old centre; rounding makes both the same
    number, so an update stays bit for bit equal to a full rebuild.
    """
    segs = segments(terrain, seg_length)
    return dataclasses.replace(segs, centre=jnp.round(segs.centre, 12))


class _Context:
    """Everything about a course map that the stages share."""

    def __init__(self, cmap: CourseMap, templates: Templates, hopper: Hopper):
        self.cmap, self.templates, self.hopper = cmap, templates, hopper
        terrain = cmap.plan
        self.terrain = terrain
        self.segs = _segments(terrain, templates.seg_length)
        self.table = situated_table(terrain, self.segs, templates.seg_length)
        self.nt, self.n_seg = templates.n, self.segs.n
        self.n_sit = self.nt * self.n_seg
        self.t_of = np.arange(self.n_sit) % self.nt
        self.s_of = np.arange(self.n_sit) // self.nt
        seg_block = np.asarray(self.segs.block)
        self.sit_allowed = np.asarray(cmap.allowed)[seg_block][self.s_of]
        gf_rel, d_rel = _boxes(templates, hopper)
        centre = np.asarray(self.segs.centre)
        self.py = centre[self.s_of, 0]
        offset = np.stack([self.py, centre[self.s_of, 1] + hopper.rho0, np.zeros(self.n_sit)], 1)
        self.gf_world = gf_rel[self.t_of] + offset[:, :, None]
        self.d_world = d_rel[self.t_of] + offset[:, :, None]
        scale = template_scales(hopper)
        self.probe = np.array([PROBE * scale["length"]] * 2 + [PROBE * scale["velocity"]])
        self.h_min = float(np.min(np.asarray(terrain.heights)))
        # For the dependency tests of updates (`ascent_binds`, `descent_binds`, `touched`).
        self.h = centre[self.s_of, 1]
        self.l = 0.5 * templates.seg_length
        arr = templates.as_array()
        self.dy_lo, self.dy_hi = arr[self.t_of, 4], arr[self.t_of, 5]
        starts, ends = np.asarray(terrain.starts), np.asarray(terrain.ends)
        self.contiguous = bool(np.all(starts[1:] == ends[:-1]))
        self.floor = self.h_min if self.contiguous else self.h_min - hopper.rho0
        # Padded copies for the jitted stages: a snapshot that adds blocks or segments
        # then reuses the compiled code (zero-width blocks at the map's end, segments with
        # no block; neither can be touched down on nor bind a collision clause).
        nb = _bucket(terrain.n_blocks + 1, 32)
        ns = _bucket(self.n_seg + 1, 128)
        self.jterrain = _pad_terrain(terrain, nb)
        t = self.table
        end = float(np.asarray(terrain.ends)[-1])
        k = ns - self.n_seg
        self.jtable = SituatedTable(
            jnp.concatenate([t.centre, jnp.tile(jnp.array([[1e6, 0.0]]), (k, 1))]),
            jnp.concatenate([t.seg_block, jnp.full(k, terrain.n_blocks - 1, t.seg_block.dtype)]),
            jnp.concatenate([t.edge_distance, jnp.zeros(k)]),
            jnp.concatenate([t.block_first, jnp.full(nb - terrain.n_blocks, self.n_seg,
                                                      t.block_first.dtype)]),
            jnp.concatenate([t.block_count, jnp.zeros(nb - terrain.n_blocks,
                                                      t.block_count.dtype)]),
            jnp.concatenate([t.block_left, jnp.full(nb - terrain.n_blocks, end)]))
        self.jallowed = jnp.asarray(np.concatenate([self.sit_allowed,
                                                    np.zeros(k * self.nt, bool)]))

    def candidate_pairs(self, row_aff=None, col_aff=None):
        """Candidate pairs among allowed situated policies, sorted by `(row, col)`.

        With masks: only pairs with an affected row or an affected column.
        """
        allowed = self.sit_allowed
        if row_aff is None:
            idx = np.nonzero(allowed)[0]
            r, c = candidate_pairs(self.gf_world[idx], self.d_world[idx])
            return idx[r], idx[c]
        a_rows = np.nonzero(allowed & row_aff)[0]
        cols_all = np.nonzero(allowed)[0]
        r1, c1 = _overlaps(self.gf_world[a_rows], self.d_world[cols_all])
        b_rows = np.nonzero(allowed & ~row_aff)[0]
        a_cols = np.nonzero(allowed & col_aff)[0]
        r2, c2 = _overlaps(self.gf_world[b_rows], self.d_world[a_cols])
        rows = np.concatenate([a_rows[r1], b_rows[r2]])
        cols = np.concatenate([cols_all[c1], a_cols[c2]])
        key = rows.astype(np.int64) * self.n_sit + cols
        srt = np.argsort(key)
        return rows[srt], cols[srt]

    def ascent_binds(self, idx, z1, v0, v1, blocks):
        """Whether a block of `blocks` can bind an ascent bound of situated `idx`.

        `ascent_y_bounds` on the segment of `idx`, at cells with `ydot in [v0, v1]` and apex
        `z <= z1`: a block `(s, e, H)` higher than `h + rho0` to the right gives `u = s +
        ydot t_up - max(ydot, 0) t_H`, and `Gf`'s upper end is `g = py - l + dy_hi + ydot
        t_up` (`goal_position_bounds`), so `u - g = s - (py - l + dy_hi) - max(ydot, 0) t_H`
        with `t_H <= min(sqrt(2 (H - h - rho0) / g), t_up)`. If that is `>= 0` in every
        cell the block never cuts `y_hi`. Mirrored on the left (`y_lo`, `ydot < 0`).
        """
        py, base = self.py[idx], self.h[idx] + self.hopper.rho0
        g = self.hopper.g
        t_up = np.sqrt(2.0 * np.maximum(z1 - base, 0.0) / g)
        up, down = np.maximum(v1, 0.0), np.maximum(-v0, 0.0)
        reach_hi = py - self.l + self.dy_hi[idx]
        reach_lo = py + self.l + self.dy_lo[idx]
        out = np.zeros(np.shape(idx), bool)
        for s, e, height in blocks:
            rise = height - base
            higher = rise > -_TOL
            if not higher.any():
                continue
            t = np.minimum(np.sqrt(2.0 * np.maximum(rise, 0.0) / g), t_up)
            right = s >= py
            out |= higher & np.where(right, s - reach_hi < up * t + _PAD,
                                     reach_lo - e < down * t + _PAD)
        return out

    def descent_binds(self, idx, z1, v0, v1, blocks):
        """Whether a block of `blocks` can bind a descent bound of situated `idx`.

        `descent_y_bounds` for a domain on the segment of `idx` (cells as in
        `ascent_binds`): a higher block left of it gives `c = e - ydot t_H - lead` against
        the domain's lower end `d = py - l - ydot t_h - lead` (`t_h` the fall to the
        segment), so `c - d = e - (py - l) + ydot (t_h - t_H)`, and `0 <= t_h - t_H <=
        min(sqrt(2 (H - h) / g), t_h)`. If `c <= d` in every cell the block never cuts the
        domain's `y` interval (nor, therefore, the intersection's). Mirrored on the right.
        """
        py, h = self.py[idx], self.h[idx]
        g = self.hopper.g
        t_h = np.sqrt(2.0 * np.maximum(z1 - h - self.hopper.rho0, 0.0) / g)
        up, down = np.maximum(v1, 0.0), np.maximum(-v0, 0.0)
        out = np.zeros(np.shape(idx), bool)
        for s, e, height in blocks:
            dh = height - h
            higher = height > h  # exactly the kernel's test (equal heights are common)
            if not higher.any():
                continue
            t = np.minimum(np.sqrt(2.0 * np.maximum(dh, 0.0) / g), t_h)
            left = s < py
            out |= higher & np.where(left, (v1 > 0) & ((py - self.l) - e < up * t + _PAD),
                                     (v0 < 0) & (s - (py + self.l) < down * t + _PAD))
        return out

    def affected(self, blocks):
        """Rows (`Gf` side, ascent) and columns (domain side, descent) a block can bind."""
        gf, d = self.gf_world, self.d_world
        idx = np.arange(self.n_sit)
        return (self.ascent_binds(idx, gf[:, 1, 1], gf[:, 2, 0], gf[:, 2, 1], blocks),
                self.descent_binds(idx, d[:, 1, 1], d[:, 2, 0], d[:, 2, 1], blocks))

    def pair_binds(self, rows, cols, blocks):
        """Pairs whose `pair_goal` a block can change (cells: the boxes' overlap)."""
        z1 = np.minimum(self.gf_world[rows, 1, 1], self.d_world[cols, 1, 1])
        v0 = np.maximum(self.gf_world[rows, 2, 0], self.d_world[cols, 2, 0])
        v1 = np.minimum(self.gf_world[rows, 2, 1], self.d_world[cols, 2, 1])
        return (self.ascent_binds(rows, z1, v0, v1, blocks)
                | self.descent_binds(cols, z1, v0, v1, blocks))

    def touched(self, goals, blocks, half_width=None):
        """Whether the descending foot from apexes `goals` (or any probe of the box
        `goals +- half_width`) can meet a block of `blocks` before `touchdown` decides.

        The foot falls from `(y, z - rho0)` with speed `ydot`; it is below a block's top `H`
        from `t_H = sqrt(2 (z - rho0 - H) / g)` on, and by `t_end` (the fall to the lowest
        block, or to the hole depth where the map has gaps) `touchdown` has found its event.
        The block can only enter the result if its extent meets the foot's `y` on
        `[t_H, t_end]`. Otherwise the touchdown (block, time, foot position) is decided by
        the other blocks, and `candidate_situated` looks only at the landing block's
        segments.
        """
        hw = np.zeros(3) if half_width is None else np.asarray(half_width, float)
        g, rho0 = self.hopper.g, self.hopper.rho0
        y_lo, y_hi = goals[:, 0] - hw[0], goals[:, 0] + hw[0]
        z_lo, z_hi = goals[:, 1] - hw[1], goals[:, 1] + hw[1]
        v_lo, v_hi = goals[:, 2] - hw[2], goals[:, 2] + hw[2]
        t_end = np.sqrt(2.0 * np.maximum(z_hi - rho0 - self.floor, 0.0) / g)
        out = np.zeros(goals.shape[0], bool)
        for s, e, height in blocks:
            t_h = np.minimum(np.sqrt(2.0 * np.maximum(z_lo - rho0 - height, 0.0) / g), t_end)
            c = np.stack([v_lo * t_h, v_lo * t_end, v_hi * t_h, v_hi * t_end])
            out |= (y_lo + c.min(0) <= e + _PAD) & (y_hi + c.max(0) >= s - _PAD)
        return out


_BOX_CACHE: dict = {}


def _bucket(n: int, step: int) -> int:
    return max(step, step * -(-n // step))


def _pad_terrain(t: Terrain, n: int) -> Terrain:
    k = n - t.n_blocks
    end, h = t.ends[-1], t.heights[-1]
    return Terrain(jnp.concatenate([t.starts, jnp.full(k, end)]),
                   jnp.concatenate([t.ends, jnp.full(k, end)]),
                   jnp.concatenate([t.heights, jnp.full(k, h)]), t.name, None)


def _boxes(templates: Templates, hopper: Hopper):
    key = (templates.as_array().tobytes(), templates.seg_length, float(hopper.m),
           float(hopper.g), float(hopper.rho0))
    if key not in _BOX_CACHE:
        _BOX_CACHE[key] = tuple(np.asarray(x) for x in template_boxes(templates, hopper))
    return _BOX_CACHE[key]


def _overlaps(gf, d):
    if gf.shape[0] == 0 or d.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return candidate_pairs(gf, d)


def _changed(old: CourseMap, new: CourseMap):
    """Blocks not in both maps.

    Returns `(k, 3)` rows `(start, end, plan height)` of every block that is in one map
    only (both versions of a changed block), plus the zero-width padding blocks at the
    map's end (`_pad_terrain`) where the last block changed.
    """
    so, sn = old.signature(), new.signature()
    old_set, new_set = set(so), set(sn)
    diff = [sig for sig in so if sig not in new_set] + [sig for sig in sn if sig not in old_set]
    rows = [sig[:3] for sig in diff]
    if so[-1] != sn[-1]:
        rows += [(so[-1][1], so[-1][1], so[-1][2]), (sn[-1][1], sn[-1][1], sn[-1][2])]
    return np.array(rows, float).reshape(-1, 3)


def _landing_changes(old: CourseMap, old_segs, ctx: _Context, blocks: np.ndarray):
    """The parts of the changed `blocks` where a touchdown can be looked up differently.

    `candidate_situated` depends on the map only through the touchdown (the first block
    the falling foot meets) and the allowed segments of the landing block within one
    segment of the foot. Where a block was only re-cut (same height, same kind, and the
    same grid segment covering each point; `course_map` keeps floor segments on the
    lattice grid), neither changes. So the result can differ only within one segment of a point
    where the plan height, the kind or the covering segment differs between the maps.
    `old`, `old_segs`: the old map and its `_segments`; `ctx`: the new map's context.

    Returns:
        `(k, 3)` rows `(start, end, height)` for `touched`: every such interval, widened by
        one segment on each side, once at each map's height there.
    """
    if blocks.shape[0] == 0:
        return blocks
    seg = ctx.templates.seg_length
    maps = []
    for m, segs in ((old, old_segs), (ctx.cmap, ctx.segs)):
        t = m.plan
        maps.append((np.asarray(t.starts), np.asarray(t.ends), np.asarray(t.heights),
                     np.asarray(m.kind), np.asarray(segs.centre)[:, 0],
                     np.asarray(segs.block)))
    cuts = np.unique(np.concatenate([blocks[:, 0], blocks[:, 1]]
                                    + [np.concatenate([st, en]) for st, en, *_ in maps]))
    lo, hi = blocks[:, 0].min(), blocks[:, 1].max()
    cuts = cuts[(cuts >= lo) & (cuts <= hi)]
    rows = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a < 1e-12 or not np.any((blocks[:, 0] <= a) & (blocks[:, 1] >= b)):
            continue
        mid = 0.5 * (a + b)
        state = []
        for st, en, h, kind, centre, block in maps:
            k = int(np.searchsorted(st, mid, side="right")) - 1
            inside = 0 <= k and mid < en[k]
            on = np.nonzero((block == k) & (np.abs(centre - mid) <= 0.5 * seg))[0]
            state.append((float(h[k]) if inside else None, int(kind[k]) if inside else -1,
                          round(float(centre[on[0]]), 9) if inside and on.size else None))
        if state[0] != state[1]:
            for h in {x[0] for x in state if x[0] is not None}:
                rows.append((a - seg, b + seg, h))
    return np.array(rows, float).reshape(-1, 3)


def build_course_plan(cmap: CourseMap, templates: Templates, hopper: Hopper, *,
                      grid: PairGrid = _GRID, pickbest=by_robustness,
                      previous: CoursePlan | None = None) -> CoursePlan:
    """A full build (`previous=None`) or an incremental update from `previous`.

    Arguments:
        cmap: the course map (`course_map`).
        templates, hopper: e.g. `scaled_templates(hopper)` and `leg_hopper()`.
        grid, pickbest: as `jaxhop.build_plan`.
        previous: a plan of the same course for an earlier environment, built with the
            same templates, hopper and grid.

    Returns:
        The `CoursePlan`.
    """
    t_start, c_start = time.perf_counter(), time.process_time()
    stages, cpu_stages, mark = {}, {}, [t_start, c_start]

    def lap(name):
        now, cnow = time.perf_counter(), time.process_time()
        stages[name] = round(now - mark[0], 4)
        cpu_stages[name] = round(cnow - mark[1], 4)
        mark[0], mark[1] = now, cnow

    ctx = _Context(cmap, templates, hopper)
    goal = np.asarray(cmap.goal, float)
    n_sit = ctx.n_sit
    changed, old_sit_to_new, landing = None, None, None
    if previous is not None:
        old_terrain = previous.plan.terrain
        same_ends = (np.asarray(old_terrain.starts)[0] == np.asarray(ctx.terrain.starts)[0]
                     and np.asarray(old_terrain.ends)[-1] == np.asarray(ctx.terrain.ends)[-1])
        same_min = float(np.min(np.asarray(old_terrain.heights))) == ctx.h_min
        same_goal = np.array_equal(previous.plan.goal, goal)
        if (same_ends and same_min and same_goal and templates.slip is None
                and previous.plan.templates.n == templates.n):
            changed = _changed(previous.cmap, cmap)
            old_segs = _segments(old_terrain, previous.plan.templates.seg_length)
            landing = _landing_changes(previous.cmap, old_segs, ctx, changed)
            old_sit_to_new = _situated_map(previous.cmap, old_segs, ctx)
            old_starts = np.asarray(old_terrain.starts)
            if not (ctx.contiguous and np.all(old_starts[1:] == np.asarray(old_terrain.ends)[:-1])):
                ctx.floor = ctx.h_min - hopper.rho0  # gaps: the foot may fall to the hole depth
        else:
            previous = None

    inc = previous is not None
    if previous is None:
        rows, cols = ctx.candidate_pairs()
        reuse_keys = np.zeros(0, np.int64)
        reuse_pos = np.zeros(0, np.int64)
        known = np.zeros(rows.size, np.int64) - 1
    else:
        # A pair's result depends on the map only through the bounds of the blocks that
        # can bind it (`ascent_binds`, `descent_binds`): it is recomputed iff one of its
        # policies is new or a changed block (either version) can bind it. Rows (columns)
        # that such a block can bind on their whole `Gf` (domain) box are enumerated; every
        # other candidate pair is an old one with both policies kept.
        row_aff, col_aff = ctx.affected(changed)
        new_to_old = np.full(n_sit, -1, np.int64)
        kept = old_sit_to_new >= 0
        new_to_old[old_sit_to_new[kept]] = np.nonzero(kept)[0]
        fresh = new_to_old < 0
        rows, cols = ctx.candidate_pairs(row_aff | fresh, col_aff | fresh)
        n_old = previous.plan.n_situated
        o_r, o_c = previous.pair_key // n_old, previous.pair_key % n_old
        n_r, n_c = old_sit_to_new[o_r], old_sit_to_new[o_c]
        ok = (n_r >= 0) & (n_c >= 0)
        ok[ok] = ~row_aff[n_r[ok]] & ~col_aff[n_c[ok]]
        reuse_pos = np.nonzero(ok)[0]
        reuse_keys = n_r[reuse_pos] * n_sit + n_c[reuse_pos]
        # Of the enumerated pairs with both policies kept, look the old result up (the
        # screen depends on no block: an old pair not screened stays so); recompute those
        # a changed block can bind.
        both = np.nonzero(~fresh[rows] & ~fresh[cols])[0]
        old_keys = new_to_old[rows[both]] * n_old + new_to_old[cols[both]]
        pos = np.searchsorted(previous.pair_key, old_keys)
        pos = pos.clip(max=max(previous.pair_key.size - 1, 0))
        hit = (previous.pair_key.size > 0) & (previous.pair_key[pos] == old_keys)
        binds = ctx.pair_binds(rows[both], cols[both], changed)
        look = ~binds & hit
        reuse_keys = np.concatenate([reuse_keys, rows[both[look]].astype(np.int64) * n_sit
                                     + cols[both[look]]])
        reuse_pos = np.concatenate([reuse_pos, pos[look]])
        need = fresh[rows] | fresh[cols]
        need[both[binds & hit]] = True
        # For recomputed pairs that were screened before: their old position (screen skipped).
        known = np.full(rows.size, -1, np.int64)
        known[both[binds & hit]] = pos[binds & hit]
        rows, cols, known = rows[need], cols[need], known[need]
    n_pairs = rows.size
    keys = rows.astype(np.int64) * n_sit + cols
    lap("candidate_pairs")
    boxes = np.stack([np.maximum(ctx.gf_world[rows, 1:, 0], ctx.d_world[cols, 1:, 0]),
                      np.minimum(ctx.gf_world[rows, 1:, 1], ctx.d_world[cols, 1:, 1])], axis=2)
    args = (ctx.t_of[rows], ctx.s_of[rows], ctx.t_of[cols], ctx.s_of[cols], boxes)
    screen = known >= 0
    todo = np.nonzero(~screen)[0]
    if todo.size:
        (screen[todo],) = _padded(
            lambda *a: _screen_jit(*a, ctx.jtable, templates, hopper, grid),
            todo.size, 4 * _PAIR_CHUNK, *(a[todo] for a in args), small=inc)
    lap("screen")
    sc = np.nonzero(screen)[0]
    if sc.size:
        found, goals, margin, margin_d = _padded(
            lambda *a: _pairs_jit(*a, ctx.jtable, templates, ctx.jterrain, hopper, grid),
            sc.size, _PAIR_CHUNK, *(a[sc] for a in args), small=inc)
    else:
        found, goals, margin, margin_d = (np.zeros(0, bool), np.zeros((0, 3)), np.zeros(0),
                                          np.zeros(0))
    lap("instantiate")

    # Merge reused and computed screened pairs in key order.
    pk = np.concatenate([reuse_keys, keys[sc]])
    p_found = np.concatenate([previous.pair_found[reuse_pos] if inc else np.zeros(0, bool),
                              found])
    p_goal = np.concatenate([previous.pair_goal[reuse_pos] if inc else np.zeros((0, 3)),
                             goals])
    p_margin = np.concatenate([previous.pair_margin[reuse_pos] if inc else np.zeros(0),
                               margin])
    p_margin_d = np.concatenate([previous.pair_margin_d[reuse_pos] if inc
                                 else np.zeros(0), margin_d])
    # The old instantiated policy of each pair whose goal is unchanged: its prepares row
    # and robustness depend on nothing else (and on the blocks, tested below).
    recomputed_old = np.full(sc.size, -1, np.int64)
    if inc:
        k = known[sc]
        same = k >= 0
        same[same] = np.all(previous.pair_goal[k[same]] == goals[same], axis=1) & (
            previous.pair_found[k[same]] == found[same])
        recomputed_old[same] = previous.pair_inst[k[same]]
    old_inst = np.concatenate([previous.pair_inst[reuse_pos] if inc
                               else np.zeros(0, np.int64), recomputed_old])
    srt = np.argsort(pk, kind="stable")
    pk, p_found, p_goal, p_margin, p_margin_d, old_inst = (
        a[srt] for a in (pk, p_found, p_goal, p_margin, p_margin_d, old_inst))

    # Goal policies: situated policies whose Gf box holds the goal (few), exactly tested.
    near = np.nonzero(ctx.sit_allowed
                      & np.all((ctx.gf_world[:, :, 0] <= goal) & (goal <= ctx.gf_world[:, :, 1]),
                               axis=1))[0]
    g_ok, g_margin = np.zeros(near.size, bool), np.zeros(near.size)
    redo_g = np.ones(near.size, bool)
    if inc and near.size:
        # `goal_policy_margin` tests the goal and probes up to 0.5 along each axis against
        # the ascent bounds of the policy's segment: an old policy keeps its result (a
        # goal policy with its margin, or none) if no changed block can bind those bounds
        # at a probe (`_goal_binds`). Its Gf box, hence whether it is near, is unchanged.
        redo_g = (new_to_old[near] < 0) | _goal_binds(ctx, near, goal, 0.5, changed)
        old_goal = dict(zip(previous.plan.situated[previous.plan.is_goal].tolist(),
                            previous.plan.margin[previous.plan.is_goal].tolist()))
        for i in np.nonzero(~redo_g)[0]:
            o = int(new_to_old[near[i]])
            if o in old_goal:
                g_ok[i], g_margin[i] = True, old_goal[o]
    reuse_goal = inc and not redo_g.any()
    if redo_g.any():
        idx = near[redo_g]
        ok, marg = _padded(
            lambda ti, si: _goal_jit(jnp.asarray(goal), ti, si, ctx.jtable, templates,
                                     ctx.jterrain, hopper),
            idx.size, 1024, ctx.t_of[idx], ctx.s_of[idx], small=inc)
        g_ok[redo_g], g_margin[redo_g] = ok, marg
    goal_sit, goal_margin = near[g_ok], g_margin[g_ok]
    lap("goal_policies")

    inst = np.nonzero(p_found)[0]
    n_goal = goal_sit.size
    sit = np.concatenate([goal_sit, pk[inst] // n_sit]).astype(np.int64)
    tgt = np.concatenate([np.full(n_goal, -1), pk[inst] % n_sit]).astype(np.int64)
    all_goals = np.concatenate([np.broadcast_to(goal, (n_goal, 3)), p_goal[inst]])
    all_margin = np.concatenate([goal_margin, p_margin[inst]])
    dg = np.concatenate([goal_margin, p_margin_d[inst]])
    is_goal = np.arange(sit.size) < n_goal
    from_old = np.concatenate([np.full(n_goal, -1, np.int64), old_inst[inst]])

    # Prepares rows: remap the old row of a policy with an unchanged goal whose descent
    # meets no changed block (`touched`).
    n_inst = sit.size
    redo = np.ones(n_inst, bool)
    rows_p, cols_p = [], []
    if inc:
        cand = np.nonzero(from_old >= 0)[0]
        cand = cand[~ctx.touched(all_goals[cand], landing)]
        old_p = previous.plan.prepares[from_old[cand]].tocoo()
        mapped = old_sit_to_new[old_p.col]
        bad = np.zeros(cand.size, bool)
        np.logical_or.at(bad, old_p.row, mapped < 0)
        ok_rows = ~bad[old_p.row]
        rows_p.append(cand[old_p.row[ok_rows]])
        cols_p.append(mapped[ok_rows])
        redo[cand[~bad]] = False
    todo_p = np.nonzero(redo)[0]
    allowed_j = ctx.jallowed
    if todo_p.size:
        ids, inside = _padded(
            lambda g: _rows_jit(g, allowed_j, ctx.jtable, templates, ctx.jterrain, hopper),
            todo_p.size, _ROW_CHUNK, all_goals[todo_p], small=inc)
        r, c = np.nonzero(inside)
        rows_p.append(todo_p[r])
        cols_p.append(ids[r, c])
    rows_p = np.concatenate(rows_p) if rows_p else np.zeros(0, np.int64)
    cols_p = np.concatenate(cols_p) if cols_p else np.zeros(0, np.int64)
    p = sp.csr_matrix((np.ones(rows_p.size, bool), (rows_p, cols_p)), shape=(n_inst, n_sit))
    p.sum_duplicates()
    lap("prepares")

    # Each goal must lie in the domain it was chosen for; drop any that do not.
    keep = is_goal | np.asarray(p[np.arange(n_inst), np.maximum(tgt, 0)]).ravel()
    n_dropped = int((~keep).sum())
    inst_index = np.full(n_inst, -1, np.int64)
    inst_index[keep] = np.arange(int(keep.sum()))
    sel = np.nonzero(keep)[0]
    sit, tgt, all_goals, all_margin, dg, is_goal, from_old = (
        a[sel] for a in (sit, tgt, all_goals, all_margin, dg, is_goal, from_old))
    p = p[sel]
    pair_inst = np.full(pk.size, -1, np.int64)
    pair_inst[inst] = inst_index[n_goal:]
    de = np.asarray(ctx.segs.edge_distance)
    safety = SAFETY_WE * de[ctx.s_of[sit]] ** 3 + SAFETY_WG * dg

    # Robustness: the share of the 27 probes around the goal that an allowed domain holds.
    # A probe of a policy with an unchanged goal keeps its old result if its descent meets
    # no change (`touched`).
    offsets = _offsets(ctx.probe)
    n_probe = offsets.shape[0]
    held = np.ones((sit.size, n_probe), bool)
    redo = np.ones((sit.size, n_probe), bool)
    redo[is_goal] = False
    if inc and previous.probe_held is not None:
        cand = np.nonzero(from_old >= 0)[0]
        held[cand] = previous.probe_held[from_old[cand]]
        redo[cand] = False
        # The box test (the hull of all 27 probes' paths) first: cheap, and most kept goals
        # are far from any change; then each probe of the goals it cannot clear.
        near_c = cand[ctx.touched(all_goals[cand], landing, ctx.probe)]
        pts = (all_goals[near_c, None, :] + offsets[None]).reshape(-1, 3)
        redo[near_c] = ctx.touched(pts, landing).reshape(near_c.size, n_probe)
    todo_r = np.nonzero(redo.any(axis=1))[0]
    pol, prb = np.nonzero(redo)
    if pol.size:
        pts = all_goals[pol] + offsets[prb]
        (h,) = _padded(
            lambda q: _held_jit(q, allowed_j, ctx.jtable, templates, ctx.jterrain, hopper),
            pol.size, _PROBE_CHUNK, pts, small=inc)
        held[pol, prb] = h
    robustness = held.sum(axis=1) / n_probe
    robustness[is_goal] = 1.0
    lap("safety_sampling")
    order = deploy(p, sit, safety, is_goal, robustness, pickbest)
    lap("deploy")
    stats = {
        "n_segments": int(ctx.n_seg),
        "n_situated": int(n_sit),
        "n_allowed_situated": int(ctx.sit_allowed.sum()),
        "n_candidate_pairs": int(n_pairs),
        "n_screened_pairs": int(pk.size),
        "n_instantiated": int(sit.size),
        "n_goal_policies": int(is_goal.sum()),
        "n_deployed": int(order.size),
        "n_edges": count_edges(p, sit),
        "n_dropped": n_dropped,
        "incremental": inc,
        "recomputed_pairs": int(n_pairs),
        "screened_pairs_computed": int(todo.size),
        "instantiated_pairs_computed": int(sc.size),
        "recomputed_prepares_rows": int(todo_p.size),
        "recomputed_robustness": int(todo_r.size),
        "recomputed_probes": int(pol.size),
        "reused_goal_policies": bool(reuse_goal),
        "new_situated": int((new_to_old < 0).sum()) if inc else int(n_sit),
        "changed_blocks": [] if changed is None else changed.tolist(),
        "seconds": round(time.perf_counter() - t_start, 4),
        "stage_seconds": stages,
        "cpu_seconds": round(time.process_time() - c_start, 4),
        "stage_cpu_seconds": cpu_stages,
    }
    plan = Plan(ctx.terrain, templates, hopper, goal, sit, tgt, all_goals, safety, all_margin,
                is_goal, robustness, p.tocsr(), order, stats)
    return CoursePlan(cmap, plan, pk, p_found, p_goal, p_margin, p_margin_d, pair_inst, stats,
                      held)


def _goal_binds(ctx: _Context, near: np.ndarray, goal: np.ndarray, reach: float,
                blocks: np.ndarray) -> np.ndarray:
    """Whether a block can bind `ascent_y_bounds` at the goal or a probe of it.

    `goal_policy_margin` probes `goal +- reach` along each axis and needs `lo < y < hi`.
    A higher block right of the segment gives `hi = s + ydot t_up - max(ydot, 0) t_H >= s
    - max(-ydot, 0) t_up`; it can only matter if that is at most the largest probe `y`.
    Mirrored on the left.
    """
    g, rho0 = ctx.hopper.g, ctx.hopper.rho0
    py, base = ctx.py[near], ctx.h[near] + rho0
    t_up = np.sqrt(2.0 * np.maximum(goal[1] + reach - base, 0.0) / g)
    up, down = max(goal[2] + reach, 0.0), max(reach - goal[2], 0.0)
    out = np.zeros(near.size, bool)
    for s, e, height in blocks:
        higher = height - base > -_TOL
        right = s >= py
        out |= higher & np.where(right, s - down * t_up <= goal[0] + reach + _PAD,
                                 e + up * t_up >= goal[0] - reach - _PAD)
    return out


def _situated_map(old: CourseMap, old_segs, ctx: _Context) -> np.ndarray:
    """Old situated id -> new situated id (-1 where its segment is gone).

    A segment is kept when the new map has a segment with the same centre, height and
    block kind, even if its block was re-cut (`course_map` puts floor segments on the
    lattice grid, so a block that changes at its free end keeps them). Whatever a re-cut block
    changes is covered by the dependency tests, which see both versions of every changed
    block. `old_segs`: the old map's `_segments`.
    """
    old_kind = np.asarray(old.kind)[np.asarray(old_segs.block)]
    new_kind = np.asarray(ctx.cmap.kind)[np.asarray(ctx.segs.block)]

    def keys(centre, kind):
        c = np.round(np.asarray(centre, float), 9)
        return list(zip(c[:, 0].tolist(), c[:, 1].tolist(), kind.tolist()))

    index = {k: i for i, k in enumerate(keys(ctx.segs.centre, new_kind))}
    new_seg = np.array([index.get(k, -1) for k in keys(old_segs.centre, old_kind)],
                       dtype=np.int64).reshape(-1)
    nt = ctx.nt
    old_sit = np.arange(new_seg.size * nt)
    seg = new_seg[old_sit // nt]
    return np.where(seg >= 0, seg * nt + old_sit % nt, -1)
