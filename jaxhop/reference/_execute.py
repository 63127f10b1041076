"""Reactive execution (Fig. 8) and domain-of-attraction sweeps, one run at a time.

`model="slip"` runs the SLIP model (`_slip`) with the controller of `jaxhop._execution.batches`'s
`decide_slip`: the SLIP deadbeat (eqs 12-16) on the `SLIP_CANDIDATES` highest-priority
matching policies, the first whose predicted stride lands within `SLIP_ACCEPT` of its goal
(else the smallest scaled miss), and SLIP strides on the terrain.
"""

from __future__ import annotations

import time

import numpy as np

from ._deadbeat import DeadbeatSearch, deadbeat_slip
from ._model import (
    FAILURE_NAMES,
    MAX_STEPS,
    OK,
    OUTSIDE_DOMAIN,
    RUNNING,
    SOLVER,
    SUCCESS,
    Hopper,
    Terrain,
    bhop_stride,
    deadbeat_bhop,
    touchdown_one,
)
from ._plan import Plan
from ._slip import slip_stride

_BIG = np.iinfo(np.int32).max
# Mirrors of jaxhop._execution.batches's SLIP decision constants.
SLIP_CANDIDATES = 2
SLIP_ACCEPT = np.array([0.05, 0.05, 0.05])
SLIP_STAGE_C2 = 1e-4  # jaxhop._control.decisions.SLIP_STAGE_C2
DECISION_TOL = 1e-5  # rtol = atol of a decision's strides (jaxhop._models.slip.kernels)


def slip_scales(hopper):
    """`SLIP_ACCEPT` and `SLIP_STAGE_C2` Froude-scaled from the reference `Hopper()` to
    `hopper` (`_models._slip_scales`)."""
    ref = Hopper()
    length = hopper.rho0 / ref.rho0
    speed = np.sqrt((hopper.g / ref.g) * length)
    return SLIP_ACCEPT * np.array([length, length, speed]), SLIP_STAGE_C2 * length**2


class Controller:
    """The execution lookup of a plan: the first deployed policy of every situated policy.

    Every instantiated policy of one situated policy has that policy's domain, so only the
    first deployed one can be a first match; `best_pos[s]` is its position in the order.
    """

    def __init__(self, plan: Plan, slip_table=None):
        """`slip_table`: `(values, grid)` of the SLIP table (`jaxhop._models.slip.table`): SLIP
        decisions then take the table-start deadbeat, as the JAX controller with one."""
        self.plan = plan
        self.slip_table = slip_table
        n_sit = plan.situation.n_situated
        self.best_pos = np.full(n_sit, _BIG, np.int64)
        self.best_inst = np.zeros(n_sit, np.int64)
        for pos in range(plan.order.size - 1, -1, -1):
            a = plan.order[pos]
            s = plan.situated[a]
            self.best_pos[s], self.best_inst[s] = pos, a
        t = plan.situation.templates
        self.lo = np.stack([t.col("dy_lo"), t.col("th_lo"), t.col("k_lo")], 1)
        self.hi = np.stack([t.col("dy_hi"), t.col("th_hi"), t.col("k_hi")], 1)

    def first_match(self, apex):
        """`(found, situated, instantiated)` of the first deployed policy containing `apex`."""
        ids, inside = self.plan.situation.candidate_situated_one(np.asarray(apex, float))
        pos = np.where(inside, self.best_pos[ids], _BIG)
        k = int(np.argmin(pos))
        return bool(pos[k] < _BIG), int(ids[k]), int(self.best_inst[ids[k]])

    def first_match_scan(self, apex):
        """The literal first match: scan the whole order (slow; a cross-check)."""
        sit = self.plan.situation
        code, block, _, y_foot, _ = touchdown_one(apex, sit.terrain, sit.hopper)
        if code != OK:
            return False, -1
        nt, l = sit.templates.n, sit.templates.half_length
        on_seg = ((sit.segs.block == block)
                  & (np.abs(y_foot - sit.segs.centre[:, 0]) <= l + 1e-12))
        apex = np.asarray(apex, float)
        contains = np.zeros(sit.n_situated, bool)
        for seg in np.nonzero(on_seg)[0]:
            py, h = sit.segs.centre[seg]
            for t in range(nt):
                reg = sit.regions[t]
                contains[seg * nt + t] = reg.domain_contains(
                    apex[0] - py, apex[1] - h - sit.hopper.rho0, apex[2])
        hit = contains[self.plan.situated[self.plan.order]]
        if not hit.any():
            return False, -1
        return True, int(self.plan.order[np.argmax(hit)])

    def decide(self, apex, model="bhop"):
        """Controls for one measured apex: `(found, u, instantiated)`.

        `model="slip"`: the SLIP deadbeat to the matched goal, within the SLIP limits.
        """
        if model == "slip":
            return self.decide_slip(apex)
        found, s, a = self.first_match(apex)
        return found, self.controls(apex, s, a, model), a

    def decide_slip(self, apex, n_candidates=SLIP_CANDIDATES):
        """SLIP controls for one measured apex (mirrors `jaxhop._control.decisions.decide_slip`).

        The SLIP deadbeat for each of the `n_candidates` highest-priority matching policies,
        its stride predicted over the policy's foothold; the first in deployment order whose
        prediction lies within `SLIP_ACCEPT` of its goal wins, else the smallest miss
        relative to `SLIP_ACCEPT`, else (no completed stride) the first match. A miss that
        lands back in the chosen policy's domain no nearer its goal is a loop: the decision
        is taken again without that policy, where another matches.

        Returns:
            `(found, u, instantiated)`; `u` is None when nothing matches.
        """
        apex = np.asarray(apex, float)
        found, u, inst, s, stuck = self._choose(apex, n_candidates, -1)
        if stuck:
            again = self._choose(apex, n_candidates, s)
            if again[0]:
                return again[:3]
        return found, u, inst

    def _choose(self, apex, n_candidates, exclude):
        """`(found, u, instantiated, situated, stuck)` of `decide_slip` over the matches
        other than situated policy `exclude`."""
        ids, inside = self.plan.situation.candidate_situated_one(apex)
        pos = np.where(inside & (ids != exclude), self.best_pos[ids], _BIG)
        order = np.argsort(pos, kind="stable")[:n_candidates]
        order = order[pos[order] < _BIG]
        if order.size == 0:
            return False, None, -1, -1, False
        sit = self.plan.situation
        sits = [int(ids[k]) for k in order]
        scale, stage_c2 = slip_scales(self.plan.situation.hopper)
        insts = [int(self.best_inst[k]) for k in sits]
        hs = [sit.segs.centre[k // sit.templates.n, 1] for k in sits]

        def one(c, **kw):
            goal = self.plan.goals[insts[c]]
            search = DeadbeatSearch(tol=DECISION_TOL, **kw)
            u, _ = deadbeat_slip(apex, goal, hs[c], sit.hopper, search, sit.terrain)
            pred, code, _ = slip_stride(apex, u, sit.terrain, sit.hopper, 0.0, DECISION_TOL,
                                       DECISION_TOL)
            ok = code == OK and np.all(np.isfinite(pred))
            miss = float(np.max(np.abs(pred - goal) / scale)) if ok else np.inf
            return u, miss, pred

        if self.slip_table is None:
            us, misses, preds = map(list, zip(*(one(c) for c in range(len(order)))))
        else:
            # `jaxhop._control.decisions._first_accepted`: the candidates in order from the table's
            # starts until one is accepted.
            n = len(order)
            us, misses, preds = [np.zeros(3)] * n, [np.inf] * n, [None] * n
            for c in range(len(order)):
                us[c], misses[c], preds[c] = one(c, table=self.slip_table, fallback=False,
                                                 accept=stage_c2)
                if misses[c] <= 1.0:
                    break
        misses = np.asarray(misses)
        good = misses <= 1.0
        pick = int(np.argmax(good)) if good.any() else int(np.argmin(misses))
        if not np.isfinite(misses[pick]):
            pick = 0
        stuck = False
        if not good.any() and np.isfinite(misses[pick]):
            goal = self.plan.goals[insts[pick]]
            away = np.max(np.abs(apex - goal) / scale) <= misses[pick]
            found_next, sit_next, _ = self.first_match(preds[pick])
            stuck = bool(away and found_next and sit_next == sits[pick])
        return True, us[pick], insts[pick], sits[pick], stuck

    def controls(self, apex, s, a, model="bhop"):
        """The deadbeat controls of `decide` for the matched situated / instantiated policy."""
        sit = self.plan.situation
        nt = sit.templates.n
        h = sit.segs.centre[s // nt, 1]
        if model == "slip":
            return deadbeat_slip(apex, self.plan.goals[a], h, sit.hopper, terrain=sit.terrain)[0]
        u = deadbeat_bhop(apex, self.plan.goals[a], h, sit.hopper)
        lo, hi = self.lo[s % nt], self.hi[s % nt]
        u = np.where(np.isfinite(u), u, hi)
        return np.clip(u, lo, hi)


def run_one(ctrl: Controller, apex0, *, true_terrain: Terrain | None = None, wind=0.0,
            noise=None, tolerance=(0.05, 0.05, 0.05), max_steps=60, model="bhop"):
    """One run of the reactive controller (mirrors `jaxhop._execution.batches.run_one`).

    Arguments:
        noise: `(max_steps, 3)` additive measurement noise per apex (already scaled), or None.
        model: `"bhop"` or `"slip"` (strides and deadbeat of that model).

    Returns:
        `(code, steps, apexes)`: result code, strides taken, the visited apexes.
    """
    plan = ctrl.plan
    terrain = plan.terrain if true_terrain is None else true_terrain
    goal = plan.goal
    tol = np.asarray(tolerance, float)
    apex = np.asarray(apex0, float)
    apexes = [apex]
    code, steps = RUNNING, 0
    for k in range(max_steps):
        if np.all(np.abs(apex - goal) <= tol):
            code = SUCCESS
            break
        measured = apex if noise is None else apex + noise[k]
        if model == "slip":
            found, u, _ = ctrl.decide_slip(measured)
        else:
            found, s, a = ctrl.first_match(measured)
            u = ctrl.controls(measured, s, a, model) if found else None
        if not found:
            code = OUTSIDE_DOMAIN
            break
        stride = slip_stride if model == "slip" else bhop_stride
        nxt, s_code, _ = stride(apex, u, terrain, plan.hopper, wind)
        if s_code == OK and not np.all(np.isfinite(nxt)):
            s_code = SOLVER
        steps += 1
        if s_code != OK:
            code = s_code
            break
        apex = nxt
        apexes.append(apex)
    if code == RUNNING:
        code = SUCCESS if np.all(np.abs(apex - goal) <= tol) else MAX_STEPS
    return code, steps, np.asarray(apexes)


def sweep_grid(terrain: Terrain, ydot0=0.5, dy=0.05, dz=0.05, z_range=None):
    """Initial apexes on a `(y, z)` grid (Figs. 16, 17 and 20)."""
    y0, y1 = terrain.y_range
    if z_range is None:
        z_range = (float(terrain.heights.min()) + 1.0, float(terrain.heights.max()) + 2.6)
    ys = np.arange(y0, y1 + 1e-9, dy)
    zs = np.arange(z_range[0], z_range[1] + 1e-9, dz)
    Y, Z = np.meshgrid(ys, zs, indexing="ij")
    return np.stack([Y.ravel(), Z.ravel(), np.full(Y.size, ydot0)], axis=1)


def in_global_domain(ctrl: Controller, apexes) -> np.ndarray:
    return np.array([ctrl.first_match(z)[0] for z in np.atleast_2d(apexes)], bool)


def run_batch(ctrl: Controller, initial, *, noise=None, **kwargs):
    """Every initial apex in turn. `noise`: `(n, max_steps, 3)` or None."""
    initial = np.atleast_2d(initial)
    codes = np.zeros(initial.shape[0], np.int64)
    steps = np.zeros(initial.shape[0], np.int64)
    for i, z0 in enumerate(initial):
        codes[i], steps[i], _ = run_one(ctrl, z0, noise=None if noise is None else noise[i],
                                        **kwargs)
    return {"code": codes, "steps": steps}


def summarize(result: dict, seconds: float) -> dict:
    code, steps = result["code"], result["steps"]
    ok = code == SUCCESS
    return {
        "n_initial_conditions": int(code.size),
        "success_rate": float(ok.mean()) if code.size else 0.0,
        "mean_steps": float(steps[ok].mean()) if ok.any() else 0.0,
        "max_steps": int(steps[ok].max()) if ok.any() else 0,
        "failures": {name: int((code == i + 1).sum()) for i, name in enumerate(FAILURE_NAMES)},
        "seconds": round(seconds, 3),
    }


def sweep(plan: Plan, *, initial=None, ydot0=0.5, dy=0.05, dz=0.05, **kwargs):
    """Domain-of-attraction sweep: `(summary, initial_states, result)`."""
    t0 = time.perf_counter()
    ctrl = Controller(plan)
    if initial is None:
        grid = sweep_grid(plan.terrain, ydot0, dy, dz)
        initial = grid[in_global_domain(ctrl, grid)]
    result = run_batch(ctrl, initial, **kwargs)
    return summarize(result, time.perf_counter() - t0), initial, result
