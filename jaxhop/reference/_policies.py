"""Situated and instantiated policies: domain lookup, goal choice on the 16 x 16 grid,
goal policies and safety sampling (section III-C, eqs 8, 30-31, 34).

The collision-free clauses (descent to the segment, rise to the goal) are bounds on `y` at
fixed `(ydot, z)`, as in `jaxhop._planning.policies`; only blocks that can bind are evaluated.
"""

from __future__ import annotations

import math

import numpy as np

from ._model import (
    INF,
    OK,
    Hopper,
    Segments,
    Templates,
    Terrain,
    safe_sqrt,
    touchdown,
    touchdown_one,
)
from ._regions import TemplateRegions


class Situation:
    """A terrain cut into segments, with the lookup arrays of the JAX `SituatedTable` and
    the per-template regions."""

    def __init__(self, terrain: Terrain, segs: Segments, templates: Templates, hopper: Hopper):
        self.terrain, self.segs, self.templates, self.hopper = terrain, segs, templates, hopper
        self.regions = [TemplateRegions(templates, i, hopper) for i in range(templates.n)]
        n_blocks = terrain.n_blocks
        self.block_count = np.bincount(segs.block, minlength=n_blocks)
        self.block_first = np.concatenate([[0], np.cumsum(self.block_count)[:-1]])
        self.block_left = terrain.starts.copy()
        for b in range(n_blocks):
            if self.block_count[b]:
                first = segs.centre[self.block_first[b], 0]
                self.block_left[b] = first - 0.5 * templates.seg_length
        self.tcols = {name: templates.col(name) for name in ("v_lo", "v_hi", "e_lo", "e_hi")}

    @property
    def n_situated(self) -> int:
        return self.segs.n * self.templates.n

    def candidate_situated(self, apexes):
        """Situated policies near the nominal touchdown of each apex, and which contain it.

        Returns:
            `(ids, inside)`, both `(n, 3 * n_templates)`.
        """
        apexes = np.atleast_2d(np.asarray(apexes, float))
        hp, seg_len, nt = self.hopper, self.templates.seg_length, self.templates.n
        code, block, _, y_foot, _ = touchdown(apexes, self.terrain, hp)
        with np.errstate(invalid="ignore"):
            k = np.floor((y_foot - self.block_left[block]) / seg_len)
        k = np.nan_to_num(k, nan=0.0).clip(-2**31, 2**31 - 1).astype(np.int64)
        n_on = self.block_count[block]
        local = np.clip(k[:, None] + np.arange(-1, 2), 0, np.maximum(n_on - 1, 0)[:, None])
        segs = self.block_first[block][:, None] + local
        py, h = self.segs.centre[segs, 0], self.segs.centre[segs, 1]
        on_seg = ((np.abs(y_foot[:, None] - py) <= 0.5 * seg_len + 1e-12)
                  & (n_on > 0)[:, None] & (code == OK)[:, None])
        on_seg &= (np.arange(3) == 0) | (local != np.roll(local, 1, axis=1))
        ids = (segs[:, :, None] * nt + np.arange(nt)).reshape(apexes.shape[0], -1)
        # Template test (eqs 38-41) relative to each of the three segments.
        inside = self._template_inside((apexes[:, 0:1] - py)[:, :, None],
                                       (apexes[:, 1:2] - h - hp.rho0)[:, :, None],
                                       apexes[:, 2, None, None])
        return ids, (inside & on_seg[:, :, None]).reshape(apexes.shape[0], -1)

    def _template_inside(self, y_rel, zr, ydot):
        """Template domain test (eqs 38-41) in coordinates relative to a segment; broadcasts
        against the template columns."""
        hp, c = self.hopper, self.tcols
        energy = 0.5 * hp.m * ydot**2 + hp.m * hp.g * zr
        y_td = y_rel + ydot * safe_sqrt(2.0 * zr / hp.g)
        l = self.templates.half_length
        return ((ydot >= c["v_lo"]) & (ydot <= c["v_hi"]) & (zr > 0) & (energy >= c["e_lo"])
                & (energy <= c["e_hi"]) & (y_td >= -l) & (y_td <= l))

    def candidate_situated_one(self, apex):
        """`candidate_situated` for one apex: `(ids, inside)`, each `(3 * n_templates,)`."""
        hp, seg_len, nt = self.hopper, self.templates.seg_length, self.templates.n
        code, block, _, y_foot, _ = touchdown_one(apex, self.terrain, hp)
        n_on = int(self.block_count[block])
        k = (y_foot - self.block_left[block]) / seg_len
        k = math.floor(k) if math.isfinite(k) else 0
        local = [min(max(k + d, 0), max(n_on - 1, 0)) for d in (-1, 0, 1)]
        segs = [int(self.block_first[block]) + j for j in local]
        on_seg = np.array([abs(y_foot - self.segs.centre[sg, 0]) <= 0.5 * seg_len + 1e-12
                           and n_on > 0 and code == OK and (i == 0 or local[i] != local[i - 1])
                           for i, sg in enumerate(segs)])
        ids = (np.asarray(segs)[:, None] * nt + np.arange(nt)).reshape(-1)
        if not on_seg.any():
            return ids, np.zeros(ids.size, bool)
        py, h = self.segs.centre[segs, 0], self.segs.centre[segs, 1]
        inside = self._template_inside((apex[0] - py)[:, None], (apex[1] - h - hp.rho0)[:, None],
                                       float(apex[2]))
        return ids, (inside & on_seg[:, None]).reshape(-1)

    # --- collision-free y bounds ---

    def descent_y_bounds(self, ydot, z, block):
        """Apex `y` interval whose foot meets no higher block before landing on `block`."""
        ter, hp = self.terrain, self.hopper
        h = ter.heights[block]
        higher = ter.heights > h
        lo = np.full(np.broadcast(ydot, z).shape, -INF)
        hi = np.full(lo.shape, INF)
        left = np.nonzero(higher & (ter.ends <= ter.starts[block]))[0]
        right = np.nonzero(higher & (ter.starts >= ter.ends[block]))[0]
        for b in left:
            t_h = safe_sqrt(2.0 * (z - hp.rho0 - ter.heights[b]) / hp.g)
            lo = np.maximum(lo, np.where(ydot > 0, ter.ends[b] - ydot * t_h, -INF))
        for b in right:
            t_h = safe_sqrt(2.0 * (z - hp.rho0 - ter.heights[b]) / hp.g)
            hi = np.minimum(hi, np.where(ydot < 0, ter.starts[b] - ydot * t_h, INF))
        return np.maximum(lo, ter.starts[0]), np.minimum(hi, ter.ends[-1])

    def ascent_y_bounds(self, ydot, z, block):
        """Goal `y` interval whose rise from `block` meets no block higher than the COM."""
        ter, hp = self.terrain, self.hopper
        z_lo = ter.heights[block] + hp.rho0
        lo = np.full(np.broadcast(ydot, z).shape, -INF)
        hi = np.full(lo.shape, INF)
        rise = ter.heights - z_lo
        right = np.nonzero((rise > 0) & (ter.starts >= ter.ends[block]))[0]
        left = np.nonzero((rise > 0) & (ter.ends <= ter.starts[block]))[0]
        if right.size == 0 and left.size == 0:
            return lo, hi
        t_up = safe_sqrt(2.0 * (z - z_lo) / hp.g)
        zdot = hp.g * t_up
        shift = ydot * t_up
        for b in np.concatenate([right, left]):
            t_h = np.where(ter.heights[b] < z,
                           (zdot - safe_sqrt(zdot**2 - 2.0 * hp.g * rise[b])) / hp.g, t_up)
            if b in right:
                hi = np.minimum(hi, ter.starts[b] + shift - np.maximum(ydot, 0) * t_h)
            else:
                lo = np.maximum(lo, ter.ends[b] + shift - np.minimum(ydot, 0) * t_h)
        return lo, hi


# --- goal choice on a grid (eqs 30-31) --------------------------------------------------------


def _axis_margin(mask, spacing, axis):
    """Distance along `axis` to the nearest cell outside `mask` (boundary halfway between)."""
    n = mask.shape[axis]
    shape = [1] * mask.ndim
    shape[axis] = n
    idx = np.arange(n).reshape(shape)
    prev_out = np.maximum.accumulate(np.where(mask, -1, idx), axis=axis)
    rev = np.flip(np.where(mask, n, idx), axis=axis)
    next_out = np.flip(np.minimum.accumulate(rev, axis=axis), axis=axis)
    return (np.minimum(idx - prev_out, next_out - idx) - 0.5) * spacing


def _pair_grids(sit: Situation, ti, tj, seg_i, seg_j, boxes, grid):
    """The goal grids of pairs of templates `(ti, tj)` on segments `seg_i[p]`, `seg_j[p]`
    (all on the same two blocks), `boxes[p]` their box overlaps: every cell of `Gf(i) ∩
    D(j)` with its margin, shaped `(pairs, n_v, n_z)`, computed cell by cell with the same
    arithmetic as a single pair's grid."""
    n_v, n_z = grid
    hp = sit.hopper
    reg_i, reg_j = sit.regions[ti], sit.regions[tj]
    centre = sit.segs.centre
    py_i, h_i = centre[seg_i, 0][:, None, None], centre[seg_i, 1][:, None]
    py_j, h_j = centre[seg_j, 0][:, None, None], centre[seg_j, 1][:, None]
    b_i, b_j = sit.segs.block[seg_i[0]], sit.segs.block[seg_j[0]]
    rho0 = hp.rho0
    z0, z1 = boxes[:, 0, 0][:, None], boxes[:, 0, 1][:, None]
    v0, v1 = boxes[:, 1, 0][:, None], boxes[:, 1, 1][:, None]
    dv, dz = (v1 - v0) / n_v, (z1 - z0) / n_z
    vs = v0 + (np.arange(n_v) + 0.5) * dv
    zs = z0 + (np.arange(n_z) + 0.5) * dz

    gzl, gzh = (b.reshape(vs.shape) for b in reg_i.goal_height_bounds(vs.reshape(-1)))
    dzl, dzh = reg_j.domain_height_bounds(vs)
    gzl, gzh = gzl + h_i + rho0, gzh + h_i + rho0
    dzl, dzh = dzl + h_j + rho0, dzh + h_j + rho0
    dzl = np.maximum(dzl, h_j + rho0 + 1e-6)  # D(j) needs zr > 0 strictly
    zl, zh = np.maximum(gzl, dzl)[:, :, None], np.minimum(gzh, dzh)[:, :, None]
    V, Z = vs[:, :, None], zs[:, None, :]
    in_z = (Z >= zl) & (Z <= zh)

    h_i, h_j = h_i[:, :, None], h_j[:, :, None]
    g_lo, g_hi = reg_i.goal_position_bounds(V, Z - h_i - rho0)
    g_lo, g_hi = g_lo + py_i, g_hi + py_i
    shift_j = V * safe_sqrt(2.0 * (Z - h_j - rho0) / hp.g)
    l = sit.templates.half_length
    d_lo, d_hi = py_j - shift_j - l, py_j - shift_j + l
    c_lo, c_hi = sit.descent_y_bounds(V, Z, b_j)
    a_lo, a_hi = sit.ascent_y_bounds(V, Z, b_i)
    dom_lo, dom_hi = np.maximum(d_lo, c_lo), np.minimum(d_hi, c_hi)
    y_lo = np.maximum(np.maximum(g_lo, a_lo), dom_lo)
    y_hi = np.minimum(np.minimum(g_hi, a_hi), dom_hi)

    mask = in_z & (y_hi > y_lo)
    dz3, dv3 = dz[:, :, None], dv[:, :, None]
    margin = np.minimum(np.minimum(0.5 * (y_hi - y_lo), np.minimum(Z - zl, zh - Z)),
                        np.minimum(_axis_margin(mask, dz3, 2), _axis_margin(mask, dv3, 1)))
    margin = np.where(mask, np.round(margin, 9), -INF)  # ties: first cell wins (as in JAX)
    return {"vs": vs, "zs": zs, "dv": dv, "dz": dz, "dzl": dzl, "dzh": dzh, "mask": mask,
            "margin": margin, "y_lo": y_lo, "y_hi": y_hi, "dom_lo": dom_lo, "dom_hi": dom_hi,
            "v_ok": (vs >= reg_j.t["v_lo"]) & (vs <= reg_j.t["v_hi"])}


def _grid_goals(g):
    """Best cell of each pair's grid (`_pair_grids`): `(found, goals, margin, margin_d)`,
    `margin_d` the goal's margin inside `D(j)` alone (eq 34)."""
    n_pairs, n_v, n_z = g["margin"].shape
    p = np.arange(n_pairs)
    found = g["mask"].any(axis=(1, 2))
    best = np.argmax(g["margin"].reshape(n_pairs, -1), axis=1)
    a, b = best // n_z, best % n_z
    vs, zs, dzl, dzh = g["vs"], g["zs"], g["dzl"], g["dzh"]
    dom_lo, dom_hi = g["dom_lo"], g["dom_hi"]
    y_g = 0.5 * (g["y_lo"][p, a, b] + g["y_hi"][p, a, b])
    z_b, dzl_a, dzh_a = zs[p, b], dzl[p, a], dzh[p, a]
    # The goal's row (fixed ydot, every z) and column (fixed z, every ydot) in D(j).
    row = ((zs >= dzl_a[:, None]) & (zs <= dzh_a[:, None])
           & (dom_hi[p, a] > dom_lo[p, a]) & g["v_ok"][p, a][:, None])
    col = ((z_b[:, None] >= dzl) & (z_b[:, None] <= dzh) & (dom_hi[p, :, b] > dom_lo[p, :, b])
           & g["v_ok"])
    line = np.minimum(_axis_margin(row, g["dz"], 1)[p, b], _axis_margin(col, g["dv"], 1)[p, a])
    margin_d = np.minimum(np.minimum(y_g - dom_lo[p, a, b], dom_hi[p, a, b] - y_g),
                          np.minimum(np.minimum(z_b - dzl_a, dzh_a - z_b), line))
    goals = np.stack([y_g, z_b, vs[p, a]], axis=1)
    return found, goals, g["margin"][p, a, b], margin_d


def pair_goal(sit: Situation, ti, seg_i, tj, seg_j, box, grid=(16, 16), margins=False):
    """Best goal in `Gf(i) ∩ D(j)` for one candidate pair (mirrors `_policies.pair_goal`).

    Arguments:
        box: `(2, 2)` overlap of the pair's boxes, rows `(z, ydot)`, columns `(lo, hi)`.
        margins: return the grid instead, `(margin, vs, zs)` (`-inf` outside the
            intersection), to check which cells tie for the best margin.

    Returns:
        `(found, goal, margin, margin_d)`.
    """
    g = _pair_grids(sit, ti, tj, np.array([seg_i]), np.array([seg_j]),
                    np.asarray(box, float)[None], grid)
    if margins:
        return g["margin"][0], g["vs"][0], g["zs"][0]
    found, goals, margin, margin_d = _grid_goals(g)
    if not found[0]:
        return False, None, -INF, -INF
    return True, goals[0], float(margin[0]), float(margin_d[0])


def pair_goals(sit: Situation, rows, cols, boxes, grid=(16, 16), batch=2048):
    """`pair_goal` of every candidate pair `(rows[p], cols[p])` (situated ids), `boxes[p]`
    their box overlaps: the pairs of each template pair on each pair of blocks are one
    array computation, at most `batch` pairs at a time.

    Returns:
        `(found, goals, margin, margin_d)` per pair (`goals` zero where none is found).
    """
    nt, nb = sit.templates.n, sit.terrain.n_blocks
    n = rows.size
    found = np.zeros(n, bool)
    goals = np.zeros((n, 3))
    margin = np.zeros(n)
    margin_d = np.zeros(n)
    ti, si, tj, sj = rows % nt, rows // nt, cols % nt, cols // nt
    group = ((ti * nt + tj) * nb + sit.segs.block[si]) * nb + sit.segs.block[sj]
    order = np.argsort(group, kind="stable")
    cuts = np.flatnonzero(np.diff(group[order])) + 1
    for members in np.split(order, cuts):
        for k in range(0, members.size, batch):
            idx = members[k:k + batch]
            f, g, m, md = _grid_goals(_pair_grids(sit, ti[idx[0]], tj[idx[0]], si[idx], sj[idx],
                                                  boxes[idx], grid))
            found[idx] = f
            goals[idx] = np.where(f[:, None], g, 0.0)
            margin[idx] = np.where(f, m, 0.0)
            margin_d[idx] = np.where(f, md, 0.0)
    return found, goals, margin, margin_d


#: Slack (m) in `y` of the goal itself where it lies on an end of the segment: a goal on a
#: segment boundary belongs to both neighbouring segments (mirrors `_policies.GOAL_Y_TOL`).
GOAL_Y_TOL = 1e-9


def goal_policy_margin(sit: Situation, goal, ti, seg_i, n_steps=50):
    """Whether situated `(ti, seg_i)` reaches the global goal, and the goal's margin to the
    boundary of its (collision-free) Gf along each axis in 1 cm steps."""
    reg, hp = sit.regions[ti], sit.hopper
    py, h = sit.segs.centre[seg_i]
    block = sit.segs.block[seg_i]
    steps = 0.01 * np.arange(1, n_steps + 1)
    signed = np.array([-1.0, 1.0])[None, :, None, None] * steps[None, None, :, None]
    probes = goal + signed * np.eye(3)[:, None, None, :]  # (axis, sign, step, 3)
    pts = np.concatenate([np.asarray(goal, float)[None], probes.reshape(-1, 3)])
    lo, hi = sit.ascent_y_bounds(pts[:, 2], pts[:, 1], block)
    on_end = abs(abs(pts[0, 0] - py) - sit.templates.half_length) <= GOAL_Y_TOL
    y_tol = np.where((np.arange(pts.shape[0]) == 0) & on_end, GOAL_Y_TOL, 0.0)
    ok = (reg.feasible_goal_contains(pts[:, 0] - py, pts[:, 1] - h - hp.rho0, pts[:, 2],
                                     y_tol)
          & (pts[:, 0] > lo) & (pts[:, 0] < hi))
    if not ok[0]:
        return False, -INF
    inside = ok[1:].reshape(3, 2, n_steps)
    first_out = np.argmin(inside, axis=2)
    dist = np.where(np.all(inside, axis=2), steps[-1], steps[first_out] - 0.005)
    return True, float(dist.min())


_OFFSETS = np.stack(np.meshgrid(*[np.arange(-1.0, 2.0)] * 3, indexing="ij"), -1).reshape(-1, 3)
CENTRE_PROBE = 13  # offset (0, 0, 0)


def situate_goals(sit: Situation, goals, half_width):
    """Domain membership of goals and their safety-sampling scores in one pass.

    Returns:
        `(ids, inside, robustness)`: per goal, the candidate situated ids and which contain
        the goal (a row of the prepares matrix P), and the fraction of the 27 probes
        `goal + {-1, 0, 1}^3 * half_width` held by some situated domain.
    """
    goals = np.atleast_2d(np.asarray(goals, float))
    probes = (goals[:, None, :] + _OFFSETS * half_width).reshape(-1, 3)
    ids, inside = sit.candidate_situated(probes)
    n_probes = _OFFSETS.shape[0]
    ids = ids.reshape(goals.shape[0], n_probes, -1)
    inside = inside.reshape(goals.shape[0], n_probes, -1)
    held = inside.any(axis=2)
    # `n * (1 / 27)`, not `n / 27`: the rounding XLA uses for the JAX path's mean.
    robustness = held.sum(axis=1).astype(float) * (1.0 / n_probes)
    return ids[:, CENTRE_PROBE], inside[:, CENTRE_PROBE], robustness


def situate_goal(sit: Situation, goal, half_width):
    """`situate_goals` of one goal: `(ids, inside, robustness)`."""
    ids, inside, robustness = situate_goals(sit, goal, half_width)
    return ids[0], inside[0], float(robustness[0])


def world_boxes(sit: Situation, gf_rel, d_rel):
    """Per situated policy boxes in world coordinates, `(n_situated, 3, 2)` each."""
    nt, n_sit = sit.templates.n, sit.n_situated
    t_of, s_of = np.arange(n_sit) % nt, np.arange(n_sit) // nt
    c = sit.segs.centre
    offset = np.stack([c[s_of, 0], c[s_of, 1] + sit.hopper.rho0, np.zeros(n_sit)], 1)
    return gf_rel[t_of] + offset[:, :, None], d_rel[t_of] + offset[:, :, None]


def candidate_pairs(gf_world, d_world):
    """Pairs `(i, j)` whose boxes of Gf(i) and D(j) overlap, one row `i` at a time."""
    rows, cols = [], []
    for i in range(gf_world.shape[0]):
        g = gf_world[i]
        j = np.nonzero(np.all((g[None, :, 0] <= d_world[:, :, 1])
                              & (d_world[:, :, 0] <= g[None, :, 1]), axis=1))[0]
        rows.append(np.full(j.size, i))
        cols.append(j)
    return np.concatenate(rows), np.concatenate(cols)


def pair_box(gf_world, d_world, i, j):
    """Overlap of the two boxes in `(z, ydot)`: `(2, 2)` (`(n, 2, 2)` for index arrays)."""
    return np.stack([np.maximum(gf_world[i, 1:, 0], d_world[j, 1:, 0]),
                     np.minimum(gf_world[i, 1:, 1], d_world[j, 1:, 1])], axis=-1)
