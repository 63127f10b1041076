"""What a change of a course map can reach: the dependency tests of an incremental update.

An update keeps every result that no changed block can affect (docs/parkour_reactive.md
derives each test). `changed_blocks` lists the changed blocks, `situated_map` which situated
policies keep their segment, `landing_changes` where a touchdown can be looked up
differently; `Reach` tests pairs (`pair_binds`), rows and columns (`affected`) and descents
(`touched`) against them, `goal_binds` the goal policies; `Update` gathers them for
one update.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._core.terrain import Terrain, segments
from .._planning.regions import slip_shift_limits
from ._map import CourseMap

_PAD = 1e-6
_TOL = 1e-9


def rounded_segments(terrain: Terrain, seg_length: float):
    """`segments` with centres rounded to 1e-12 m.

    `course_map` puts segments on an absolute grid, but `segments` computes a centre from
    its block's start, so the same segment in a re-cut block differs in the last bits. An
    update reuses results computed with the old centre; rounding makes both the same
    number, so an update stays bit for bit equal to a full rebuild.
    """
    segs = segments(terrain, seg_length)
    return dataclasses.replace(segs, centre=jnp.round(segs.centre, 12))


def shift_bounds(templates, v_box):
    """`(dy_lo, dy_hi)` per template: bounds of the horizontal-shift interval of `Gf`
    (`slip_shift_limits`) over the template's goal velocities `v_box[t] = (v0, v1)`.

    BHop: the template's own `[dy_lo, dy_hi]`. SLIP-adjusted templates (eq 35): the limits
    vary with the goal velocity `ydot`. Each is monotone (nondecreasing) in `ydot` between
    breakpoints: `ydot = 0`, where the reversal and direction rules switch on or off, and
    the velocities where `h`'s argument crosses `co` (its constants switch there). So the
    smallest `dy_lo` and largest `dy_hi` over the box are taken at its ends and on both
    sides of each breakpoint inside it.
    """
    arr = templates.as_array()
    if templates.slip is None:
        return arr[:, 4], arr[:, 5]
    _, speed = templates.slip.scales()
    co = templates.slip.co
    lo, hi = np.empty(templates.n), np.empty(templates.n)
    for t in range(templates.n):
        v0, v1 = float(v_box[t, 0]), float(v_box[t, 1])
        # `h(0.5 (v_hi + ydot))` and `h(-0.5 (v_lo + ydot))` switch constants at `u = co`.
        breaks = np.array([0.0, 2.0 * co * speed - arr[t, 1], -2.0 * co * speed - arr[t, 0]])
        eps = 1e-12 * max(1.0, abs(v0), abs(v1))
        v = np.concatenate([[v0, v1], breaks - eps, breaks, breaks + eps])
        v = v[(v >= v0) & (v <= v1)]
        a, b = (np.broadcast_to(np.asarray(x, float), v.shape)
                for x in slip_shift_limits(jnp.asarray(v), templates.row(t)))
        lo[t], hi[t] = a.min(), b.max()
    return lo, hi


def foot_lead_time(templates) -> float:
    """`k >= 0` with `foot_lead(ydot) = k ydot` (eq 37 is linear in `ydot`; 0 for BHop): the
    foot of a SLIP-adjusted template lands where a BHop foot `k` seconds later in its fall
    would be, so `touched` shifts its fall times by `k`."""
    return 0.0 if templates.slip is None else float(templates.slip.lead(1.0))


class Reach:
    """The dependency tests of a course layout (mixed into `_build._Context`).

    Uses the layout's `hopper`, `py`, `h` (segment centre), `l` (half a segment), `dy_lo`,
    `dy_hi` (bounds of the template's shift limits, `shift_bounds`), `lead_time`
    (`foot_lead_time`), `gf_world`, `d_world`, `n_sit` and `floor` (the lowest height a
    falling foot can reach).
    """

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

        The foot falls from `(y + k ydot, z - rho0)` with speed `ydot` (`k`: `lead_time`, the
        foot lead of eq 37 over the speed, 0 for BHop); it is below a block's top `H` from
        `t_H = sqrt(2 (z - rho0 - H) / g)` on, and by `t_end` (the fall to the lowest block,
        or to the hole depth where the map has gaps) `touchdown` has found its event: its
        `y` lies between `y + ydot (t_H + k)` and `y + ydot (t_end + k)`.
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
        k = self.lead_time
        # The whole fall (`t_H` = 0) first: its `y` range holds every block's, and most
        # descents meet no changed block at all.
        wide_lo, wide_hi = y_lo + _least(v_lo, v_hi, k, t_end + k), y_hi + _most(
            v_lo, v_hi, k, t_end + k)
        out = np.zeros(goals.shape[0], bool)
        for s, e, height in blocks:
            i = np.nonzero((wide_lo <= e + _PAD) & (wide_hi >= s - _PAD))[0]
            t_h = np.minimum(np.sqrt(2.0 * np.maximum(z_lo[i] - rho0 - height, 0.0) / g),
                             t_end[i])
            args = (v_lo[i], v_hi[i], t_h + k, t_end[i] + k)
            out[i] |= ((y_lo[i] + _least(*args) <= e + _PAD)
                       & (y_hi[i] + _most(*args) >= s - _PAD))
        return out


def _least(v_lo, v_hi, t0, t1):
    """The smallest of `v t` over `v` in `(v_lo, v_hi)` and `t` in `(t0, t1)`."""
    return np.minimum(np.minimum(v_lo * t0, v_lo * t1), np.minimum(v_hi * t0, v_hi * t1))


def _most(v_lo, v_hi, t0, t1):
    """The largest of `v t` over `v` in `(v_lo, v_hi)` and `t` in `(t0, t1)`."""
    return np.maximum(np.maximum(v_lo * t0, v_lo * t1), np.maximum(v_hi * t0, v_hi * t1))



def goal_binds(ctx, near: np.ndarray, goal: np.ndarray, reach: float,
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


def changed_blocks(old: CourseMap, new: CourseMap):
    """Blocks not in both maps.

    Returns `(k, 3)` rows `(start, end, plan height)` of every block that is in one map
    only (both versions of a changed block), plus the zero-width padding blocks at the
    map's end (`pad_terrain`) where the last block changed.
    """
    so, sn = old.signature(), new.signature()
    old_set, new_set = set(so), set(sn)
    diff = [sig for sig in so if sig not in new_set] + [sig for sig in sn if sig not in old_set]
    rows = [sig[:3] for sig in diff]
    if so[-1] != sn[-1]:
        rows += [(so[-1][1], so[-1][1], so[-1][2]), (sn[-1][1], sn[-1][1], sn[-1][2])]
    return np.array(rows, float).reshape(-1, 3)


def landing_changes(old: CourseMap, old_segs, ctx, blocks: np.ndarray):
    """The parts of the changed `blocks` where a touchdown can be looked up differently.

    `candidate_situated` depends on the map only through the touchdown (the first block
    the falling foot meets) and the allowed segments of the landing block within one
    segment of the foot. Where a block was only re-cut (same height, same kind, and the
    same grid segment covering each point; `course_map` keeps floor segments on the
    lattice grid), neither changes. So the result can differ only within one segment of a point
    where the plan height, the kind or the covering segment differs between the maps.
    `old`, `old_segs`: the old map and its `rounded_segments`; `ctx`: the new map's context.

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


def situated_map(old: CourseMap, old_segs, ctx) -> np.ndarray:
    """Old situated id -> new situated id (-1 where its segment is gone).

    A segment is kept when the new map has a segment with the same centre, height and
    block kind, even if its block was re-cut (`course_map` puts floor segments on the
    lattice grid, so a block that changes at its free end keeps them). Whatever a re-cut block
    changes is covered by the dependency tests, which see both versions of every changed
    block. `old_segs`: the old map's `rounded_segments`.
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


@dataclasses.dataclass
class Update:
    """What an update reuses from `previous` and what changed (`_reach`)."""

    previous: object  # the `CoursePlan` updated
    changed: np.ndarray
    landing: np.ndarray
    old_sit_to_new: np.ndarray
    new_to_old: np.ndarray

    @classmethod
    def of(cls, previous, ctx, goal) -> Update | None:
        """The update from `previous`, or None for a full build (no previous plan, or
        other ends, lowest height, goal or template count)."""
        if previous is None:
            return None
        old_terrain, terrain = previous.plan.terrain, ctx.terrain
        old_starts, old_ends = np.asarray(old_terrain.starts), np.asarray(old_terrain.ends)
        same_ends = (old_starts[0] == np.asarray(terrain.starts)[0]
                     and old_ends[-1] == np.asarray(terrain.ends)[-1])
        same_min = float(np.min(np.asarray(old_terrain.heights))) == ctx.h_min
        same_goal = np.array_equal(previous.plan.goal, goal)
        if not (same_ends and same_min and same_goal
                and previous.plan.templates.n == ctx.templates.n):
            return None
        changed = changed_blocks(previous.cmap, ctx.cmap)
        old_segs = rounded_segments(old_terrain, previous.plan.templates.seg_length)
        landing = landing_changes(previous.cmap, old_segs, ctx, changed)
        old_sit_to_new = situated_map(previous.cmap, old_segs, ctx)
        if not (ctx.contiguous and np.all(old_starts[1:] == old_ends[:-1])):
            ctx.floor = ctx.h_min - ctx.hopper.rho0  # gaps: the foot may fall to the hole depth
        new_to_old = np.full(ctx.n_sit, -1, np.int64)
        kept = old_sit_to_new >= 0
        new_to_old[old_sit_to_new[kept]] = np.nonzero(kept)[0]
        return cls(previous, changed, landing, old_sit_to_new, new_to_old)

    def old(self, name: str, pos):
        """`previous.<name>[pos]`."""
        return getattr(self.previous, name)[pos]
