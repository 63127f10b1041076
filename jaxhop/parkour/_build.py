"""Reactive plans on a course map, built in full or updated incrementally (issue 8).

`build_course_plan` runs the stages of `jaxhop.build_plan` (situate, candidate pairs,
screen, instantiate, goal policies, prepares, safety sampling, deploy) with one change:
policies are situated only on the map's allowed blocks (restricted floor and margin
bands carry segments, so that `Plan.table()` stays consistent, but none of their situated
policies is ever instantiated, prepared or deployed). It keeps what an update needs: every
screened pair's result, the prepares rows and the robustness scores.

`update_course_plan` takes such a plan and a new course map (a snapshot) and recomputes
only what the change can affect. A *changed interval* is the extent of every block that is
not in both maps with the same `(start, end, plan height, true height, kind)`. Then:

* a pair `(i, j)` is recomputed iff its *dependency range* meets a changed interval: the
  `y` overlap of the boxes of `Gf(i)` and `D(j)`, widened to the two segments (plus the
  largest `|dy|` on `i`'s side). The collision clauses of a cell can only be bound by a
  block that meets this range (docs/parkour_reactive.md has the argument); all other
  pairs keep their screened result, goal, margins (segments of unchanged blocks keep their
  place, so their ids are remapped);
* a prepares row `P[a, :]` is recomputed iff the goal's nominal descent (the `y` range the
  foot and COM sweep down to the lowest block, plus three segments) meets a changed
  interval; otherwise the old row is remapped;
* a robustness score is recomputed iff the same range for the whole probe box does;
* goal policies are recomputed (there are few), and deployment is redone (cheap).

A change of the map's ends or of its lowest height (which the hole test uses) falls back
to a full build. Instantiated policies are kept in a canonical order (goal policies by
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
#: Safety-sampling probe half-widths of `jaxhop.build_plan` (m, m, m/s) for the 1 m hopper;
#: Froude-scaled for other hoppers.
PROBE = 0.2
_PAD = 1e-6
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


def _robust(goals, allowed, table, templates, terrain, hopper, half_width):
    offsets = jnp.stack(jnp.meshgrid(*[jnp.arange(-1.0, 2.0)] * 3, indexing="ij"), -1)
    offsets = offsets.reshape(-1, 3) * half_width

    def one(goal):
        def held(p):
            ids, inside = candidate_situated(p, table, templates, terrain, hopper)
            return jnp.any(inside & allowed[ids])

        return jnp.mean(jax.vmap(held)(goal + offsets).astype(float))

    return jax.vmap(one)(goals)


def _goal_policies(goal, ti, si, table, templates, terrain, hopper):
    return jax.vmap(goal_policy_margin, (None, 0, 0, None, None, None, None))(
        goal, ti, si, table, templates, terrain, hopper)


_screen_jit = jax.jit(_screen, static_argnames=("grid",))
_pairs_jit = jax.jit(_pairs, static_argnames=("grid",))
_rows_jit = jax.jit(_rows)
_robust_jit = jax.jit(_robust)
_goal_jit = jax.jit(_goal_policies)


def _padded(fn, n, chunk, *arrays, small=False):
    """Run `fn(*chunk_of_arrays)` over `n` items in fixed-size chunks.

    Two chunk sizes only (others would recompile, seconds, in an update): `chunk`, and
    `chunk // 8` for small batches and for updates (`small`), where padding the last
    large chunk would waste up to a full chunk of work.
    """
    outs = None
    chunk = chunk // 8 if (small or n <= chunk // 8) else chunk
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        idx = np.arange(start, start + chunk).clip(max=n - 1)
        res = fn(*[jnp.asarray(a[idx]) for a in arrays])
        res = res if isinstance(res, tuple) else (res,)
        res = [np.asarray(r)[: stop - start] for r in res]
        if outs is None:
            outs = [[] for _ in res]
        for o, r in zip(outs, res):
            o.append(r)
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


class _Context:
    """Everything about a course map that the stages share."""

    def __init__(self, cmap: CourseMap, templates: Templates, hopper: Hopper):
        self.cmap, self.templates, self.hopper = cmap, templates, hopper
        terrain = cmap.plan
        self.terrain = terrain
        self.segs = segments(terrain, templates.seg_length)
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
        self.dy_max = float(np.max(np.abs(templates.as_array()[:, 4:6])))
        scale = template_scales(hopper)
        self.probe = np.array([PROBE * scale["length"]] * 2 + [PROBE * scale["velocity"]])
        self.h_min = float(np.min(np.asarray(terrain.heights)))
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

    def affected(self, intervals):
        """Rows (Gf side) and columns (domain side) whose ranges meet a changed interval."""
        l = 0.5 * self.templates.seg_length
        r_lo = np.minimum(self.gf_world[:, 0, 0], self.py - l - self.dy_max)
        r_hi = np.maximum(self.gf_world[:, 0, 1], self.py + l + self.dy_max)
        c_lo = np.minimum(self.d_world[:, 0, 0], self.py - l)
        c_hi = np.maximum(self.d_world[:, 0, 1], self.py + l)
        return _meets(r_lo, r_hi, intervals), _meets(c_lo, c_hi, intervals)

    def pair_range(self, rows, cols):
        """Dependency range `[lo, hi]` of each pair (see the module docstring)."""
        l = 0.5 * self.templates.seg_length
        ov_lo = np.maximum(self.gf_world[rows, 0, 0], self.d_world[cols, 0, 0])
        ov_hi = np.minimum(self.gf_world[rows, 0, 1], self.d_world[cols, 0, 1])
        pi, pj = self.py[rows], self.py[cols]
        lo = np.minimum.reduce([ov_lo, pi - l - self.dy_max, pj - l])
        hi = np.maximum.reduce([ov_hi, pi + l + self.dy_max, pj + l])
        return lo, hi

    def descent_range(self, goals, half_width=None):
        """`y` range swept by the foot and COM from apexes `goals` (boxes) to the ground."""
        hw = np.zeros(3) if half_width is None else half_width
        y, z, v = goals[:, 0], goals[:, 1] + hw[1], goals[:, 2]
        t = np.sqrt(np.maximum(2.0 * (z - self.hopper.rho0 - self.h_min) / self.hopper.g, 0.0))
        # The foot lands within one segment of the segments `candidate_situated` looks at.
        pad = 2.0 * self.templates.seg_length + hw[0]
        return (y + np.minimum((v - hw[2]) * t, 0.0) - pad,
                y + np.maximum((v + hw[2]) * t, 0.0) + pad)


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


def _meets(lo, hi, intervals) -> np.ndarray:
    out = np.zeros(np.shape(lo), bool)
    for a, b in intervals:
        out |= (lo <= b + _PAD) & (hi >= a - _PAD)
    return out


def _changed(old: CourseMap, new: CourseMap):
    """Changed intervals between two maps, and the old -> new segment-block map."""
    so, sn = old.signature(), new.signature()
    new_index = {sig: k for k, sig in enumerate(sn)}
    old_set = set(so)
    intervals = [(s, e) for (s, e, *_) in so if (s, e, *_) not in new_index]
    intervals += [(s, e) for (s, e, *_) in sn if (s, e, *_) not in old_set]
    block_map = np.array([new_index.get(sig, -1) for sig in so], dtype=np.int64)
    return intervals, block_map


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
    t_start = time.perf_counter()
    stages, mark = {}, [t_start]

    def lap(name):
        now = time.perf_counter()
        stages[name] = round(now - mark[0], 4)
        mark[0] = now

    ctx = _Context(cmap, templates, hopper)
    goal = np.asarray(cmap.goal, float)
    n_sit = ctx.n_sit
    intervals, old_sit_to_new = None, None
    if previous is not None:
        old_ctx_terrain = previous.plan.terrain
        same_ends = (np.asarray(old_ctx_terrain.starts)[0] == np.asarray(ctx.terrain.starts)[0]
                     and np.asarray(old_ctx_terrain.ends)[-1] == np.asarray(ctx.terrain.ends)[-1])
        same_min = float(np.min(np.asarray(old_ctx_terrain.heights))) == ctx.h_min
        same_goal = np.array_equal(previous.plan.goal, goal)
        if same_ends and same_min and same_goal and previous.plan.templates.n == templates.n:
            intervals, block_map = _changed(previous.cmap, cmap)
            old_sit_to_new = _situated_map(previous, ctx, block_map)
        else:
            previous = None

    inc = previous is not None
    if previous is None:
        rows, cols = ctx.candidate_pairs()
        reuse_keys = np.zeros(0, np.int64)
        reuse_pos = np.zeros(0, np.int64)
    else:
        # Rows whose Gf box (or stance) and columns whose domain box (or segment) reach a
        # changed interval: every pair whose dependency range meets one has such a row or
        # column (the two boxes of a candidate pair overlap). Those are recomputed; every
        # other candidate pair is an old one with both policies kept.
        row_aff, col_aff = ctx.affected(intervals)
        new_to_old = np.full(n_sit, -1, np.int64)
        kept = old_sit_to_new >= 0
        new_to_old[old_sit_to_new[kept]] = np.nonzero(kept)[0]
        row_aff |= new_to_old < 0
        col_aff |= new_to_old < 0
        rows, cols = ctx.candidate_pairs(row_aff, col_aff)
        n_old = previous.plan.n_situated
        o_r, o_c = previous.pair_key // n_old, previous.pair_key % n_old
        n_r, n_c = old_sit_to_new[o_r], old_sit_to_new[o_c]
        ok = (n_r >= 0) & (n_c >= 0)
        ok[ok] = ~row_aff[n_r[ok]] & ~col_aff[n_c[ok]]
        reuse_pos = np.nonzero(ok)[0]
        reuse_keys = n_r[reuse_pos] * n_sit + n_c[reuse_pos]
        # Of the enumerated pairs, recompute only those whose own dependency range meets a
        # changed interval; look the others up among the old screened pairs.
        lo, hi = ctx.pair_range(rows, cols)
        need = _meets(lo, hi, intervals) | (new_to_old[rows] < 0) | (new_to_old[cols] < 0)
        look = np.nonzero(~need)[0]
        old_keys = new_to_old[rows[look]] * n_old + new_to_old[cols[look]]
        pos = np.searchsorted(previous.pair_key, old_keys)
        pos = pos.clip(max=max(previous.pair_key.size - 1, 0))
        hit = (previous.pair_key.size > 0) & (previous.pair_key[pos] == old_keys)
        reuse_keys = np.concatenate([reuse_keys, rows[look[hit]].astype(np.int64) * n_sit
                                     + cols[look[hit]]])
        reuse_pos = np.concatenate([reuse_pos, pos[hit]])
        rows, cols = rows[need], cols[need]
    n_pairs = rows.size
    keys = rows.astype(np.int64) * n_sit + cols
    lap("candidate_pairs")
    todo = np.ones(n_pairs, bool)
    comp_idx = np.nonzero(todo)[0]
    boxes = np.stack([np.maximum(ctx.gf_world[rows[comp_idx], 1:, 0],
                                 ctx.d_world[cols[comp_idx], 1:, 0]),
                      np.minimum(ctx.gf_world[rows[comp_idx], 1:, 1],
                                 ctx.d_world[cols[comp_idx], 1:, 1])], axis=2)
    args = (ctx.t_of[rows[comp_idx]], ctx.s_of[rows[comp_idx]], ctx.t_of[cols[comp_idx]],
            ctx.s_of[cols[comp_idx]], boxes)
    if comp_idx.size:
        (screen,) = _padded(lambda *a: _screen_jit(*a, ctx.jtable, templates, hopper, grid),
                            comp_idx.size, 4 * _PAIR_CHUNK, *args, small=inc)
    else:
        screen = np.zeros(0, bool)
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
    pk = np.concatenate([reuse_keys, keys[comp_idx[sc]]])
    p_found = np.concatenate([previous.pair_found[reuse_pos] if previous else np.zeros(0, bool),
                              found])
    p_goal = np.concatenate([previous.pair_goal[reuse_pos] if previous else np.zeros((0, 3)),
                             goals])
    p_margin = np.concatenate([previous.pair_margin[reuse_pos] if previous else np.zeros(0),
                               margin])
    p_margin_d = np.concatenate([previous.pair_margin_d[reuse_pos] if previous
                                 else np.zeros(0), margin_d])
    old_inst = np.concatenate([previous.pair_inst[reuse_pos] if previous
                               else np.zeros(0, np.int64), np.full(sc.size, -1, np.int64)])
    srt = np.argsort(pk, kind="stable")
    pk, p_found, p_goal, p_margin, p_margin_d, old_inst = (
        a[srt] for a in (pk, p_found, p_goal, p_margin, p_margin_d, old_inst))

    # Goal policies: situated policies whose Gf box holds the goal (few), exactly tested.
    near = np.nonzero(ctx.sit_allowed
                      & np.all((ctx.gf_world[:, :, 0] <= goal) & (goal <= ctx.gf_world[:, :, 1]),
                               axis=1))[0]
    reuse_goal = False
    if previous is not None and near.size:
        # Unchanged if every candidate is an unaffected old policy and the goal's probes
        # (`goal_policy_margin`: up to 0.5 m along each axis) meet no changed interval.
        y = goal[0]
        reuse_goal = bool(np.all(new_to_old[near] >= 0) and not np.any(row_aff[near])
                          and not _meets(np.array([y - 0.51]), np.array([y + 0.51]),
                                         intervals)[0])
    if reuse_goal:
        old_sit = previous.plan.situated[previous.plan.is_goal]
        mapped = old_sit_to_new[old_sit]
        srt = np.argsort(mapped)
        goal_sit = mapped[srt]
        goal_margin = previous.plan.margin[previous.plan.is_goal][srt]
        reuse_goal = bool(np.all(goal_sit >= 0))
    if reuse_goal:
        pass
    elif near.size:
        g_ok, g_margin = _padded(
            lambda ti, si: _goal_jit(jnp.asarray(goal), ti, si, ctx.jtable, templates,
                                     ctx.jterrain, hopper),
            near.size, 1024, ctx.t_of[near], ctx.s_of[near])
        goal_sit, goal_margin = near[g_ok], g_margin[g_ok]
    else:
        goal_sit, goal_margin = np.zeros(0, np.int64), np.zeros(0)
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

    # Prepares rows: remap the old rows of reused policies whose descent is unchanged.
    n_inst = sit.size
    redo = np.ones(n_inst, bool)
    rows_p, cols_p = [], []
    if previous is not None:
        cand = np.nonzero(from_old >= 0)[0]
        lo, hi = ctx.descent_range(all_goals[cand])
        cand = cand[~_meets(lo, hi, intervals)]
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

    robustness = np.ones(sit.size)
    redo = np.ones(sit.size, bool)
    if previous is not None:
        cand = np.nonzero(from_old >= 0)[0]
        lo, hi = ctx.descent_range(all_goals[cand], ctx.probe)
        cand = cand[~_meets(lo, hi, intervals)]
        robustness[cand] = previous.plan.robustness[from_old[cand]]
        redo[cand] = False
    redo &= ~is_goal
    todo_r = np.nonzero(redo)[0]
    if todo_r.size:
        (rob,) = _padded(
            lambda g: _robust_jit(g, allowed_j, ctx.jtable, templates, ctx.jterrain, hopper,
                                  jnp.asarray(ctx.probe)),
            todo_r.size, _ROW_CHUNK, all_goals[todo_r], small=inc)
        robustness[todo_r] = rob
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
        "incremental": previous is not None,
        "recomputed_pairs": int(comp_idx.size),
        "recomputed_prepares_rows": int(todo_p.size),
        "recomputed_robustness": int(todo_r.size),
        "reused_goal_policies": reuse_goal,
        "changed_intervals": [] if intervals is None else [list(map(float, x))
                                                            for x in intervals],
        "seconds": round(time.perf_counter() - t_start, 4),
        "stage_seconds": stages,
    }
    plan = Plan(ctx.terrain, templates, hopper, goal, sit, tgt, all_goals, safety, all_margin,
                is_goal, robustness, p.tocsr(), order, stats)
    return CoursePlan(cmap, plan, pk, p_found, p_goal, p_margin, p_margin_d, pair_inst, stats)


def _situated_map(previous: CoursePlan, ctx: _Context, block_map: np.ndarray) -> np.ndarray:
    """Old situated id -> new situated id (-1 where its block changed)."""
    old_segs = segments(previous.plan.terrain, previous.plan.templates.seg_length)
    old_block = np.asarray(old_segs.block)
    nb_old = previous.plan.terrain.n_blocks
    first_old = np.concatenate([[0], np.cumsum(np.bincount(old_block, minlength=nb_old))[:-1]])
    new_block = np.asarray(ctx.segs.block)
    first_new = np.concatenate([[0], np.cumsum(np.bincount(new_block,
                                                           minlength=ctx.terrain.n_blocks))[:-1]])
    nb = block_map[old_block]
    local = np.arange(old_block.size) - first_old[old_block]
    new_seg = np.where(nb >= 0, first_new[np.maximum(nb, 0)] + local, -1)
    nt = ctx.nt
    old_sit = np.arange(old_block.size * nt)
    seg = new_seg[old_sit // nt]
    return np.where(seg >= 0, seg * nt + old_sit % nt, -1)
