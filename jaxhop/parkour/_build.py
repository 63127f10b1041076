"""Reactive plans on a course map, built in full or updated incrementally.

`build_course_plan` runs the stages of `jaxhop.build_plan` (`jaxhop._planning.stages`: situate,
candidate pairs, screen, instantiate, goal policies, prepares, safety sampling, deploy)
with one change:
policies are situated only on the map's allowed blocks (restricted floor and margin
bands carry segments, so that `Plan.table()` stays consistent, but none of their situated
policies is ever instantiated, prepared or deployed). It keeps what an update needs: every
screened pair's result, the prepares rows and the robustness scores. A full build is an
update with nothing to reuse.

With `previous`, `build_course_plan` updates such a plan for a new course map (a
snapshot) and recomputes only what the change can affect. The *changed blocks* are every
block that is not in both maps with the same `(start, end, plan height, true height,
kind)`, old and new versions alike. Situated policies on unchanged blocks keep their
segment (their ids are remapped); those on changed blocks are *new*. Then:

* a pair `(i, j)` is recomputed iff `i` or `j` is new, or a changed block can bind one of
  its collision clauses in some cell of its grid (`Reach.ascent_binds` on `i`'s segment,
  `Reach.descent_binds` on `j`'s; closed-form bounds of the clauses of
  `ascent_y_bounds` / `descent_y_bounds`). Only blocks higher than the segment (`h + rho0`
  for the rise) count, on the side the velocity range can reach, within the distance the
  COM (foot) covers while it is below the block's top. All other pairs keep their screened
  result, goal and margins; a recomputed old pair keeps its old screen (it depends on no
  block);
* a prepares row `P[a, :]` is remapped from the old row iff the goal is unchanged and its
  nominal descent meets no changed block (`Reach.touched`: the foot's `y` while it is
  below the block's top, until it reaches the lowest block); a robustness score likewise
  for the whole probe box;
* goal policies are reused iff every candidate is an old policy and no changed block can
  bind the ascent bounds at the goal's probes (`goal_binds`); deployment is redone.

docs/parkour_reactive.md derives each test. A change of the map's ends, of its lowest
height (which the hole test uses) or of the goal falls back to a full build. SLIP-adjusted
templates (eqs 35-37) update the same way: their foot lead moves a domain and its
collision bounds together, and the dependency tests bound the shift limits and the lead
(`shift_bounds`, `foot_lead_time`). Instantiated policies are kept in a canonical order
(goal policies by situated id, then pairs by `(situated, target)`), so an update and a
full build of the same map feed `deploy` the same arrays.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from .._core.batching import bucket, chunked_map, pad_terrain, pad_to
from .._core.params import Hopper
from .._planning import stages as S
from .._planning.deploy import by_robustness, deploy
from .._planning.graph import count_edges
from .._planning.plan import Plan
from .._planning.policies import PairGrid, SituatedTable, candidate_pairs
from .._planning.templates import Templates, template_scales
from ._map import CourseMap
from ._reach import (
    Reach,
    Update,
    foot_lead_time,
    goal_binds,
    rounded_segments,
    shift_bounds,
)

_GRID = PairGrid()


def _padded(fn, n, chunk, *arrays, small=False):
    """`fn(*chunk_of_arrays)` over `n` items in a full build's (`small`: an update's) chunks.

    Returns:
        The outputs concatenated over items, always as a tuple.
    """
    size, tail = S.chunk_sizes(chunk, n, "tail" if small else "fit")
    out = chunked_map(fn, n, size, arrays, tail=tail)
    return out if isinstance(out, tuple) else (out,)


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


class _Context(S.Layout, Reach):
    """A course map's situated policies, with what the stages and the update tests share."""

    chunking = "fit"
    # Snapshots that add a block or two keep the shapes of the side lists (no recompile).
    sides_step = 8

    def __init__(self, cmap: CourseMap, templates: Templates, hopper: Hopper):
        terrain = cmap.plan
        segs = rounded_segments(terrain, templates.seg_length)
        super().__init__(terrain, segs, templates, hopper)
        self.cmap = cmap
        self.sit_allowed = np.asarray(cmap.allowed)[np.asarray(self.segs.block)][self.s_of]
        scale = template_scales(hopper)
        probe = S.PROBE_HALF_WIDTH
        self.probe = np.array([probe * scale["length"]] * 2 + [probe * scale["velocity"]])
        self.h_min = float(np.min(np.asarray(terrain.heights)))
        # For the dependency tests of updates (`Reach`).
        centre = np.asarray(self.segs.centre)
        self.py, self.h = centre[self.s_of, 0], centre[self.s_of, 1]
        self.l = 0.5 * templates.seg_length
        dy_lo, dy_hi = shift_bounds(templates, self.gf_rel[:, 2])
        self.dy_lo, self.dy_hi = dy_lo[self.t_of], dy_hi[self.t_of]
        self.lead_time = foot_lead_time(templates)
        starts, ends = np.asarray(terrain.starts), np.asarray(terrain.ends)
        self.contiguous = bool(np.all(starts[1:] == ends[:-1]))
        self.floor = self.h_min if self.contiguous else self.h_min - hopper.rho0
        self._pad()

    def _pad(self):
        """Padded copies for the jitted stages, so that a snapshot that adds blocks or
        segments reuses the compiled code: zero-width blocks at the map's end, segments
        with no block (neither can be touched down on nor bind a collision clause)."""
        terrain, t = self.terrain, self.table
        nb = bucket(terrain.n_blocks + 1, 32)
        ns = bucket(self.n_seg + 1, 128)
        self.jterrain = pad_terrain(terrain, nb).unnamed()
        self.jtable = SituatedTable(
            pad_to(t.centre, ns, [1e6, 0.0]), pad_to(t.seg_block, ns, terrain.n_blocks - 1),
            pad_to(t.edge_distance, ns, 0.0), pad_to(t.block_first, nb, self.n_seg),
            pad_to(t.block_count, nb, 0), pad_to(t.block_left, nb, np.asarray(terrain.ends)[-1]))
        self.jallowed = pad_to(self.sit_allowed, ns * self.nt, False)

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
        r1, c1 = candidate_pairs(self.gf_world[a_rows], self.d_world[cols_all])
        b_rows = np.nonzero(allowed & ~row_aff)[0]
        a_cols = np.nonzero(allowed & col_aff)[0]
        r2, c2 = candidate_pairs(self.gf_world[b_rows], self.d_world[a_cols])
        rows = np.concatenate([a_rows[r1], b_rows[r2]])
        cols = np.concatenate([cols_all[c1], a_cols[c2]])
        key = rows.astype(np.int64) * self.n_sit + cols
        srt = np.argsort(key, kind="stable")  # two sorted runs: a merge
        return rows[srt], cols[srt]



def build_shape(cmap: CourseMap, templates: Templates, hopper: Hopper) -> tuple[int, int]:
    """`(padded blocks, situated policies)` of a full build on `cmap`: two maps of the same
    shape share the build's compiled programs."""
    ctx = _Context(cmap, templates, hopper)
    return ctx.jterrain.n_blocks, int(ctx.jtable.centre.shape[0])


def _pairs_to_compute(ctx: _Context, up: Update | None):
    """Candidate pairs to compute, and the screened pairs an update keeps.

    Returns:
        `(rows, cols, known, reuse_keys, reuse_pos)`: the pairs to compute, the old
        position of each that was screened before (-1: screen it), and the new keys and old
        positions of the kept screened pairs.
    """
    if up is None:
        rows, cols = ctx.candidate_pairs()
        empty = np.zeros(0, np.int64)
        return rows, cols, np.full(rows.size, -1, np.int64), empty, empty
    # A pair's result depends on the map only through the bounds of the blocks that can
    # bind it (`ascent_binds`, `descent_binds`): it is recomputed iff one of its policies
    # is new or a changed block (either version) can bind it. Rows (columns) that such a
    # block can bind on their whole `Gf` (domain) box are enumerated; every other
    # candidate pair is an old one with both policies kept.
    n_sit, prev = ctx.n_sit, up.previous
    row_aff, col_aff = ctx.affected(up.changed)
    fresh = up.new_to_old < 0
    rows, cols = ctx.candidate_pairs(row_aff | fresh, col_aff | fresh)
    n_old = prev.plan.n_situated
    n_r, n_c = up.old_sit_to_new[prev.pair_key // n_old], up.old_sit_to_new[prev.pair_key % n_old]
    ok = (n_r >= 0) & (n_c >= 0)
    ok[ok] = ~row_aff[n_r[ok]] & ~col_aff[n_c[ok]]
    reuse_pos = np.nonzero(ok)[0]
    reuse_keys = n_r[reuse_pos] * n_sit + n_c[reuse_pos]
    # Of the enumerated pairs with both policies kept, look the old result up (the screen
    # depends on no block: an old pair not screened stays so); recompute those a changed
    # block can bind.
    both = np.nonzero(~fresh[rows] & ~fresh[cols])[0]
    old_keys = up.new_to_old[rows[both]] * n_old + up.new_to_old[cols[both]]
    pos = np.searchsorted(prev.pair_key, old_keys).clip(max=max(prev.pair_key.size - 1, 0))
    hit = (prev.pair_key.size > 0) & (prev.pair_key[pos] == old_keys)
    binds = ctx.pair_binds(rows[both], cols[both], up.changed)
    look = ~binds & hit
    reuse_keys = np.concatenate([reuse_keys, rows[both[look]].astype(np.int64) * n_sit
                                 + cols[both[look]]])
    reuse_pos = np.concatenate([reuse_pos, pos[look]])
    need = fresh[rows] | fresh[cols]
    need[both[binds & hit]] = True
    known = np.full(rows.size, -1, np.int64)
    known[both[binds & hit]] = pos[binds & hit]
    return rows[need], cols[need], known[need], reuse_keys, reuse_pos


@dataclasses.dataclass
class _Screened:
    """Every screened pair in key order: its `pair_goal` result and old instantiated index."""

    key: np.ndarray
    found: np.ndarray
    goal: np.ndarray
    margin: np.ndarray
    margin_d: np.ndarray
    old_inst: np.ndarray
    counts: dict


def _screened_pairs(ctx: _Context, up: Update | None, grid, laps) -> _Screened:
    """Candidate pairs, screen and instantiate what changed; merge with the kept pairs."""
    rows, cols, known, reuse_keys, reuse_pos = _pairs_to_compute(ctx, up)
    keys = rows.astype(np.int64) * ctx.n_sit + cols
    laps("candidate_pairs")
    args = ctx.pair_args(rows, cols)
    screen = known >= 0
    todo = np.nonzero(~screen)[0]
    if todo.size:
        screen[todo] = S.screen(ctx, tuple(a[todo] for a in args), grid)
    laps("screen")
    sc = np.nonzero(screen)[0]
    found, goals, margin, margin_d = S.instantiate(ctx, tuple(a[sc] for a in args), grid)
    laps("instantiate")
    # The old instantiated policy of each recomputed pair whose goal is unchanged: its
    # prepares row and robustness depend on nothing else (and on the blocks, tested later).
    recomputed_old = np.full(sc.size, -1, np.int64)
    if up is not None:
        k = known[sc]
        same = k >= 0
        same[same] = np.all(up.old("pair_goal", k[same]) == goals[same], axis=1) & (
            up.old("pair_found", k[same]) == found[same])
        recomputed_old[same] = up.old("pair_inst", k[same])

    def merged(name, computed, empty):
        return np.concatenate([empty if up is None else up.old(name, reuse_pos), computed])

    parts = (np.concatenate([reuse_keys, keys[sc]]),
             merged("pair_found", found, np.zeros(0, bool)),
             merged("pair_goal", goals, np.zeros((0, 3))),
             merged("pair_margin", margin, np.zeros(0)),
             merged("pair_margin_d", margin_d, np.zeros(0)),
             merged("pair_inst", recomputed_old, np.zeros(0, np.int64)))
    srt = np.argsort(parts[0], kind="stable")
    counts = {"n_pairs": rows.size, "screened": todo.size, "instantiated": sc.size}
    return _Screened(*(a[srt] for a in parts), counts)


def _goal_policies(ctx: _Context, up: Update | None, goal):
    """Goal policies: the allowed situated policies whose `Gf` box holds the goal (few),
    exactly tested; an update keeps an old policy's result if no changed block can bind
    the ascent bounds at a probe of `goal_policy_margin` (`goal_binds`).

    Returns:
        `(situated, margin, reused)`: the goal policies, their margins, and whether every
        result was kept.
    """
    gf = ctx.gf_world
    near = np.nonzero(ctx.sit_allowed & np.all((gf[:, :, 0] <= goal) & (goal <= gf[:, :, 1]),
                                               axis=1))[0]
    g_ok, g_margin = np.zeros(near.size, bool), np.zeros(near.size)
    redo = np.ones(near.size, bool)
    if up is not None and near.size:
        redo = (up.new_to_old[near] < 0) | goal_binds(ctx, near, goal, 0.5, up.changed)
        old = up.previous.plan
        old_goal = dict(zip(old.situated[old.is_goal].tolist(),
                            old.margin[old.is_goal].tolist()))
        for i in np.nonzero(~redo)[0]:
            o = int(up.new_to_old[near[i]])
            if o in old_goal:
                g_ok[i], g_margin[i] = True, old_goal[o]
    if redo.any():
        g_ok[redo], g_margin[redo] = S.goal_policies(ctx, goal, near[redo])
    return near[g_ok], g_margin[g_ok], up is not None and not redo.any()


def _prepares(ctx: _Context, up: Update | None, goals, from_old):
    """`P` (CSR): an update remaps the old row of a policy with an unchanged goal whose
    descent meets no changed block (`touched`). Returns `P` and how many rows were computed."""
    n_inst = goals.shape[0]
    redo = np.ones(n_inst, bool)
    rows, cols = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    if up is not None:
        cand = np.nonzero(from_old >= 0)[0]
        cand = cand[~ctx.touched(goals[cand], up.landing)]
        old_p = up.previous.plan.prepares[from_old[cand]].tocoo()
        mapped = up.old_sit_to_new[old_p.col]
        bad = np.zeros(cand.size, bool)
        np.logical_or.at(bad, old_p.row, mapped < 0)
        ok_rows = ~bad[old_p.row]
        rows.append(cand[old_p.row[ok_rows]])
        cols.append(mapped[ok_rows])
        redo[cand[~bad]] = False
    todo = np.nonzero(redo)[0]
    if todo.size:
        ids, inside = S.prepares_rows(ctx, goals[todo])
        r, c = np.nonzero(inside)
        rows.append(todo[r])
        cols.append(ids[r, c])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    p = sp.csr_matrix((np.ones(rows.size, bool), (rows, cols)), shape=(n_inst, ctx.n_sit))
    p.sum_duplicates()
    return p, todo.size


def _probes_held(ctx: _Context, up: Update | None, goals, is_goal, from_old):
    """Safety sampling: whether an allowed domain holds each of the 27 probes around each
    goal (goal policies: all). A probe of a policy with an unchanged goal keeps its old
    result if its descent meets no change (`touched`).

    Returns:
        `(held, robustness, policies computed, probes computed)`: `robustness` is the
        fraction of probes held (goal policies: 1), kept where no probe was redone.
    """
    offsets = S.probe_offsets(ctx.probe)
    n_probe = offsets.shape[0]
    held = np.ones((goals.shape[0], n_probe), bool)
    robustness = np.ones(goals.shape[0])
    # The policies with probes to compute (ascending) and which of their probes.
    rows = np.nonzero(~is_goal)[0]
    mask = np.ones((rows.size, n_probe), bool)
    if up is not None and up.previous.probe_held is not None:
        cand = np.nonzero(from_old >= 0)[0]
        held[cand] = up.previous.probe_held[from_old[cand]]
        robustness[cand] = up.previous.plan.robustness[from_old[cand]]
        # The box test (the hull of all 27 probes' paths) first: cheap, and most kept goals
        # are far from any change; then each probe of the goals it cannot clear.
        near = cand[ctx.touched(goals[cand], up.landing, ctx.probe)]
        pts = (goals[near, None, :] + offsets[None]).reshape(-1, 3)
        new = np.nonzero((from_old < 0) & ~is_goal)[0]
        rows = np.concatenate([new, near])
        mask = np.concatenate([np.ones((new.size, n_probe), bool),
                               ctx.touched(pts, up.landing).reshape(near.size, n_probe)])
        srt = np.argsort(rows, kind="stable")
        rows, mask = rows[srt], mask[srt]
    r, prb = np.nonzero(mask)
    pol = rows[r]
    if pol.size:
        held[pol, prb] = S.held(ctx, goals[pol] + offsets[prb])
    robustness[rows] = held[rows].sum(axis=1) / n_probe
    return held, robustness, int(mask.any(axis=1).sum()), int(pol.size)


def _update_stats(ctx: _Context, up: Update | None, counts: dict, n_rows: int, n_pol: int,
                  n_probes: int, reused_goal: bool) -> dict:
    """The course keys of `CoursePlan.stats`: what was recomputed, what changed."""
    return {
        "n_allowed_situated": int(ctx.sit_allowed.sum()),
        "incremental": up is not None,
        "recomputed_pairs": int(counts["n_pairs"]),
        "screened_pairs_computed": int(counts["screened"]),
        "instantiated_pairs_computed": int(counts["instantiated"]),
        "recomputed_prepares_rows": int(n_rows),
        "recomputed_robustness": n_pol,
        "recomputed_probes": n_probes,
        "reused_goal_policies": bool(reused_goal),
        "new_situated": int((up.new_to_old < 0).sum()) if up else int(ctx.n_sit),
        "changed_blocks": [] if up is None else up.changed.tolist(),
    }


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
    laps = S.Laps(digits=4, cpu=True)
    ctx = _Context(cmap, templates, hopper)
    goal = np.asarray(cmap.goal, float)
    up = Update.of(previous, ctx, goal)
    ctx.chunking = "fit" if up is None else "tail"
    pairs = _screened_pairs(ctx, up, grid, laps)
    goal_sit, goal_margin, reused_goal = _goal_policies(ctx, up, goal)
    laps("goal_policies")
    inst = np.nonzero(pairs.found)[0]
    n_goal, n_sit = goal_sit.size, ctx.n_sit
    sit, tgt, goals, margin, dg, is_goal = S.instantiated(
        goal, goal_sit, goal_margin, pairs.key[inst] // n_sit, pairs.key[inst] % n_sit,
        pairs.goal[inst], pairs.margin[inst], pairs.margin_d[inst])
    from_old = np.concatenate([np.full(n_goal, -1, np.int64), pairs.old_inst[inst]])
    p, n_rows = _prepares(ctx, up, goals, from_old)
    laps("prepares")
    # Each goal must lie in the domain it was chosen for; drop any that do not.
    keep = S.holds_own_target(p, tgt, is_goal)
    inst_index = np.full(sit.size, -1, np.int64)
    inst_index[keep] = np.arange(int(keep.sum()))
    sel = np.nonzero(keep)[0]
    sit, tgt, goals, margin, dg, is_goal, from_old = (
        a[sel] for a in (sit, tgt, goals, margin, dg, is_goal, from_old))
    p = p[sel]
    pair_inst = np.full(pairs.key.size, -1, np.int64)
    pair_inst[inst] = inst_index[n_goal:]
    safety = S.safety(ctx, sit, dg)
    held, robustness, n_pol, n_probes = _probes_held(ctx, up, goals, is_goal, from_old)
    laps("safety_sampling")
    order = deploy(p, sit, safety, is_goal, robustness, pickbest)
    laps("deploy")
    stats = S.counts(ctx, pairs.counts["n_pairs"], pairs.key.size, sit, is_goal, order,
                     count_edges(p, sit), int((~keep).sum()))
    stats |= _update_stats(ctx, up, pairs.counts, n_rows, n_pol, n_probes, reused_goal)
    stats |= laps.stats()
    plan = Plan(ctx.terrain, templates, hopper, goal, sit, tgt, goals, safety, margin,
                is_goal, robustness, p.tocsr(), order, stats)
    return CoursePlan(cmap, plan, pairs.key, pairs.found, pairs.goal, pairs.margin,
                      pairs.margin_d, pair_inst, stats, held)
