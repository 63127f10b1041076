"""SLIP stance, stride and position-aware deadbeat with SciPy (twin of `jaxhop.slip`).

- Stance (eq 10) in polar coordinates about the foot, COM at `foot + rho (-sin th, cos th)`,
  integrated by `scipy.integrate.solve_ivp` (DOP853) with terminal events: the bottom
  (`rho'` up-crossing 0), liftoff (`rho - rho0` up-crossing 0: `direction=+1`, otherwise it
  would fire at touchdown, where `rho = rho0`) and the fall (COM at the foot's level or the
  leg below `COLLAPSED * rho0`, down-crossing). The same result codes as the JAX path:
  no event within `PHASE_T_MAX` or a fall is `COLLISION`, a failed solve `SOLVER`.
- Stride on a terrain: touchdown of the offset foot (`_model.touchdown_one` with the
  touchdown-angle offset), stance on the block touched, clearance in
  stance and on the way up, ballistic ascent; the JAX stride's failure semantics.
- Deadbeat (eqs 12-16): `kd` from the energy balance (eq 12) with `rho_b` from the
  integrated compression; `(th_td, kc)` jointly from the same three starts as the JAX
  `"gradient"` solver (the best `th_td` of a 9-point grid for each of three normalised
  `kc`), the best end wins; then the same clipping and `ok` flag. Default: the JAX
  solver's damped Gauss-Newton step for step, a forward-difference Jacobian in place of
  forward mode, so both stop at the same point on goals out of reach. `method="lm"`:
  `scipy.optimize.least_squares` (MINPACK Levenberg-Marquardt, iterates clipped to the
  bounds), as good on reachable goals, elsewhere on the others (`"trf"` needed over 40
  strides per start on curved valleys, `"lm"` about 15).

One sample per call, plain floats; no jax import.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from ._model import (
    COLLISION,
    INF,
    OK,
    SOLVER,
    Hopper,
    Terrain,
    crossings_one,
    finite_one,
    position_one,
    touchdown_one,
)

# Mirrors of jaxhop._models.slip.stride / jaxhop._models.slip.kernels constants.
RTOL = 1e-10
ATOL = 1e-10
SEARCH_TOL = 1e-8  # rtol = atol of the searches' trial strides
PHASE_T_MAX = 5.0
COLLAPSED = 0.25
KAPPA_LO, KAPPA_HI = 10.0, 60.0
RATIO_LO, RATIO_HI = 0.5, 2.0
TH_LO, TH_HI = -math.pi / 3, math.pi / 3
W_POS, W_VEL = 1.0, 1.0
# Budget of one start in trial strides, Jacobian evaluations included (the JAX solver: 16
# Gauss-Newton iterations, each one stride with two forward-mode tangents).
MAX_NFEV = 48
# Forward-difference step of the Gauss-Newton Jacobian in (th_td, s) and the tolerance of
# its strides: noise ~ JAC_TOL / DIFF_STEP = 1e-5 relative, truncation ~ DIFF_STEP.
DIFF_STEP = 1e-6
JAC_TOL = 1e-11
MAX_STEP = 0.2
# Bisection steps of the inner problem that seed Gauss-Newton (`START_BISECTIONS` in JAX).
START_BISECTIONS = 14
FAIL_SPEED = 1e3
# least_squares ("lm"): relative finite-difference step on the search-tolerance strides.
LM_DIFF_STEP = 1e-6
# The fastest of DOP853, RK45 and LSODA at rtol = atol = 1e-10 here (1.4, 4.1, 2.7 ms per
# stride, measured on 100 random strides).
METHOD = "DOP853"


def _field(k, m, g, rho0):
    km = k / m

    def f(t, x):
        rho, th, rhod, thd = x
        return np.array([rhod, thd,
                         rho * thd * thd - km * (rho - rho0) - g * math.cos(th),
                         (-2.0 * rhod * thd + g * math.sin(th)) / rho])
    return f


def _event(fn, direction):
    fn.terminal = True
    fn.direction = direction
    return fn


def _phase(x0, k, hopper: Hopper, liftoff: bool, rtol, atol):
    """Integrate eq 10 from `x0` until the bottom (`liftoff=False`) or liftoff, or a fall.

    Returns:
        `(x_end, code)` as `jaxhop._models.slip.stride._phase`.
    """
    rho0 = hopper.rho0
    if liftoff:
        cond = _event(lambda t, x: x[0] - rho0, 1)
    else:
        cond = _event(lambda t, x: x[2], 1)
    fallen = _event(lambda t, x: min(x[0] * math.cos(x[1]), x[0] - COLLAPSED * rho0), -1)
    sol = solve_ivp(_field(k, hopper.m, hopper.g, rho0), (0.0, PHASE_T_MAX), x0,
                    method=METHOD, rtol=rtol, atol=atol, events=(cond, fallen))
    if sol.status == -1:
        return sol.y[:, -1], SOLVER
    if sol.status == 1:
        fired = len(sol.t_events[0]) > 0
        x_end = sol.y_events[0][0] if fired else sol.y_events[1][0]
        code = OK if fired else COLLISION
    else:
        x_end, code = sol.y[:, -1], COLLISION  # no event within PHASE_T_MAX
    if not np.all(np.isfinite(x_end)):
        code = SOLVER
    return x_end, code


def _polar_state(th, v):
    s, c = math.sin(th), math.cos(th)
    return v[0] * -s + v[1] * c, v[0] * -c + v[1] * -s


def _cartesian(x):
    rho, th, rhod, thd = x
    s, c = math.sin(th), math.cos(th)
    return (np.array([rho * -s, rho * c]),
            np.array([rhod * -s + rho * thd * -c, rhod * c + rho * thd * -s]))


def compress(th_td, v_td, kc, hopper: Hopper, rtol=RTOL, atol=ATOL):
    """Compression to the bottom: `(x_b, code)`; an unloaded leg is `COLLISION`."""
    rhod, vth = _polar_state(th_td, v_td)
    loaded = rhod < 0
    # As the JAX path: an unloaded leg runs the same dummy solve (its x_b feeds eq 12).
    x0 = [hopper.rho0, th_td, rhod if loaded else -1.0, vth / hopper.rho0 if loaded else 0.0]
    x_b, code = _phase(x0, kc, hopper, False, rtol, atol)
    return x_b, (code if loaded else COLLISION)


def decompress(x_b, kd, hopper: Hopper, rtol=RTOL, atol=ATOL):
    """Decompression from the bottom to liftoff: `(x_lo, code)`."""
    return _phase(x_b, kd, hopper, True, rtol, atol)


def stance(th_td, v_td, kc, kd, hopper: Hopper, rtol=RTOL, atol=ATOL):
    """Both stance phases: `(code, p_lo, v_lo, rho_b, z_min)`, relative to the foot."""
    x_b, code_c = compress(th_td, v_td, kc, hopper, rtol, atol)
    if code_c != OK:
        return code_c, np.full(2, np.nan), np.full(2, np.nan), x_b[0], np.nan
    x_lo, code_d = decompress(x_b, kd, hopper, rtol, atol)
    p_lo, v_lo = _cartesian(x_lo)
    z_min = min(hopper.rho0 * math.cos(th_td), x_b[0] * math.cos(x_b[1]), p_lo[1])
    return code_d, p_lo, v_lo, x_b[0], z_min


def ascent(p_lo, v_lo, hopper: Hopper, wind=0.0):
    t_up = max(v_lo[1], 0.0) / hopper.g
    return np.array([p_lo[0] + v_lo[0] * t_up + 0.5 * wind * t_up**2,
                     p_lo[1] + 0.5 * v_lo[1] * t_up,
                     v_lo[0] + wind * t_up])


def flat_touchdown(apex, th_td, h, hopper: Hopper):
    """`(y_foot, v_td, reached)` of the descent to flat ground at `h`."""
    y, z, ydot = apex
    drop = z - h - hopper.rho0 * math.cos(th_td)
    t_d = math.sqrt(2.0 * drop / hopper.g) if drop > 0 else 0.0
    return (y + ydot * t_d + hopper.rho0 * math.sin(th_td), (ydot, -hopper.g * t_d),
            drop >= 0)


def slip_apex_map(apex, u, h, hopper: Hopper, rtol=RTOL, atol=ATOL):
    """SLIP apex return map over flat ground at `h`: `(next_apex, code)`."""
    th, kc, kd = (float(a) for a in u)
    y_foot, v_td, reached = flat_touchdown([float(a) for a in apex], th, h, hopper)
    code, p_lo, v_lo, _, _ = stance(th, v_td, kc, kd, hopper, rtol, atol)
    if not reached:
        code = COLLISION
    if code != OK:
        return np.full(3, np.nan), code
    nxt = ascent(p_lo + np.array([y_foot, h]), v_lo, hopper)
    return nxt, (OK if v_lo[1] > 0 else COLLISION)


# --- stride on a terrain ----------------------------------------------------------------------


def _rise_clear(p_lo, v_lo, terrain: Terrain, hopper: Hopper, wind):
    t_up = max(v_lo[1], 0.0) / hopper.g
    for s, e, hb in terrain.as_lists():
        for w in (s, e):
            for t in crossings_one(p_lo[0], v_lo[0], wind, w):
                if t <= t_up and position_one(p_lo[1], v_lo[1], -hopper.g, finite_one(t)) < hb:
                    return False
    return True


def slip_stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0, rtol=RTOL, atol=ATOL):
    """One SLIP stride on the terrain: `(next_apex, code, foothold)` (mirrors `slip_stride`).

    `next_apex` is NaN where the stance did not complete.
    """
    th, kc, kd = (float(a) for a in u)
    offset = (hopper.rho0 * math.sin(th), -hopper.rho0 * math.cos(th))
    code, block, _, y_foot, v_td = touchdown_one(apex, terrain, hopper, wind, offset)
    h = terrain.as_lists()[block][2]
    foot = (y_foot, h)
    if code != OK:
        return np.full(3, np.nan), code, foot
    code, p_lo, v_lo, _, z_min = stance(th, v_td, kc, kd, hopper, rtol, atol)
    if code != OK:
        return np.full(3, np.nan), code, foot
    p_lo = p_lo + np.array([y_foot, h])
    y_td = y_foot - hopper.rho0 * math.sin(th)
    lo, hi = min(y_td, p_lo[0]), max(y_td, p_lo[0])
    swept = any(hb > h + z_min and s < hi and e > lo for s, e, hb in terrain.as_lists())
    clear = not swept and _rise_clear(p_lo, v_lo, terrain, hopper, wind) and v_lo[1] > 0
    return ascent(p_lo, v_lo, hopper, wind), (OK if clear else COLLISION), foot


# --- deadbeat (eqs 12-16) ---------------------------------------------------------------------


def kc_limits(hopper: Hopper):
    scale = hopper.m * hopper.g / hopper.rho0
    return KAPPA_LO * scale, KAPPA_HI * scale


def energy_kd(apex, goal, kc, rho_b, hopper: Hopper):
    """Decompression stiffness that gives the goal's energy (eq 12)."""
    m, g = hopper.m, hopper.g
    gain = m * (goal[2] ** 2 - apex[2] ** 2) + 2.0 * m * g * (goal[1] - apex[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return kc + gain / np.float64(rho_b - hopper.rho0) ** 2


def _descent(apex, th, h, hopper: Hopper, terrain):
    """`(y_foot, v_td, h, reached)`: flat ground at `h`, or with `terrain` the block the foot
    meets (as `_trial` in JAX: a failed touchdown keeps the flat descent and fails)."""
    y_foot, v_td, reached = flat_touchdown(apex, th, h, hopper)
    if terrain is not None:
        offset = (hopper.rho0 * math.sin(th), -hopper.rho0 * math.cos(th))
        code, block, _, y_t, v_t = touchdown_one(apex, terrain, hopper, 0.0, offset)
        reached = code == OK
        if reached:
            y_foot, v_td, h = y_t, v_t, terrain.as_lists()[block][2]
    return y_foot, v_td, h, reached


def trial(apex, goal, h, th, kc, hopper: Hopper, tol=SEARCH_TOL, terrain=None):
    """Stride with `kd` from eq 12 at rtol = atol = `tol`: `(next_apex, code, kd)` (as
    `_trial`); over flat ground at `h`, or with `terrain` on the block the foot lands on."""
    y_foot, v_td, h, reached = _descent(apex, th, h, hopper, terrain)
    x_b, code_c = compress(th, v_td, kc, hopper, tol, tol)
    kd = float(energy_kd(apex, goal, kc, x_b[0], hopper))
    kd_ok = kd > 0
    if code_c != OK:
        return np.full(3, np.nan), max(code_c, 1), kd
    x_lo, code_d = decompress(x_b, kd if kd_ok else kc, hopper, tol, tol)
    p_lo, v_lo = _cartesian(x_lo)
    code = code_d if (reached and kd_ok and v_lo[1] > 0) else max(code_d, 1)
    return ascent(p_lo + np.array([y_foot, h]), v_lo, hopper), code, kd


def trial_speed(apex, goal, h, th, kc, hopper: Hopper, terrain=None, tol=SEARCH_TOL):
    """The liftoff speed the inner search sees (`_trial`'s `speed`): `ydot_lo` when both
    stance phases complete, else `+-FAIL_SPEED` by the side the leg ended on."""
    _, v_td, _, _ = _descent(apex, th, h, hopper, terrain)
    x_b, code_c = compress(th, v_td, kc, hopper, tol, tol)
    if code_c != OK:
        return FAIL_SPEED if x_b[1] < 0 else -FAIL_SPEED
    kd = float(energy_kd(apex, goal, kc, x_b[0], hopper))
    x_lo, code_d = decompress(x_b, kd if kd > 0 else kc, hopper, tol, tol)
    if code_d == OK and kd > 0:
        return _cartesian(x_lo)[1][0]
    return FAIL_SPEED if x_lo[1] < 0 else -FAIL_SPEED


def clip_p(p):
    return min(max(float(p[0]), TH_LO), TH_HI), min(max(float(p[1]), 0.0), 1.0)


def _residual(p, apex, goal, h, hopper: Hopper, sqrt_w, terrain=None, tol=SEARCH_TOL):
    """Weighted apex error of a trial stride at `p = (th_td, s)`, clipped to the bounds as
    the JAX solver clips its iterates; `1e3` where the trial fails."""
    if not np.all(np.isfinite(p)):
        return sqrt_w * 1e3
    th, s = clip_p(p)
    kc_lo, kc_hi = kc_limits(hopper)
    nxt, code, _ = trial(apex, goal, h, th, kc_lo + s * (kc_hi - kc_lo), hopper, tol, terrain)
    return sqrt_w * (nxt - goal) if code == OK else sqrt_w * 1e3


def _bisect_th(apex, goal, h, kc, hopper: Hopper, terrain, tol=SEARCH_TOL):
    """`START_BISECTIONS` bisection steps of the inner problem on `[TH_LO, TH_HI]`."""
    lo, hi = TH_LO, TH_HI
    for _ in range(START_BISECTIONS):
        mid = 0.5 * (lo + hi)
        if trial_speed(apex, goal, h, mid, kc, hopper, terrain, tol) > goal[2]:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def initial_guesses(apex, goal, h, hopper: Hopper, terrain=None, tol=SEARCH_TOL):
    """The JAX solver's starts: for each `s` of 3, the best `th_td` of 9 on `[-0.5, 0.5]`,
    or the inner problem's short bisection where that costs less."""
    ths = np.linspace(-0.5, 0.5, 9)
    weights = np.array([W_POS, W_POS, W_VEL])
    kc_lo, kc_hi = kc_limits(hopper)

    def cost(th, s):
        return float(np.sum(weights * _residual((th, s), apex, goal, h, hopper, np.ones(3),
                                                terrain, tol) ** 2))

    starts = []
    for s in (0.05, 0.35, 0.7):
        costs = [cost(th, s) for th in ths]
        start = (ths[int(np.argmin(costs))], s)
        if START_BISECTIONS:
            th_b = _bisect_th(apex, goal, h, kc_lo + s * (kc_hi - kc_lo), hopper, terrain, tol)
            if cost(th_b, s) < min(costs):
                start = (th_b, s)
        starts.append(start)
    return np.asarray(starts)


def _jacobian(p, apex, goal, h, hopper: Hopper, sqrt_w, terrain=None):
    """Forward differences of the weighted residual at `p` (steps `DIFF_STEP`), on trial
    strides integrated to `JAC_TOL`: the JAX solver differentiates its 1e-8 solve exactly
    (forward mode); here integration noise / step must stay far below the derivative."""
    kc_lo, kc_hi = kc_limits(hopper)

    def res(th, s):
        nxt, code, _ = trial(apex, goal, h, th, kc_lo + s * (kc_hi - kc_lo), hopper,
                             JAC_TOL, terrain)
        return sqrt_w * (nxt - goal) if code == OK else sqrt_w * 1e3

    base = res(p[0], p[1])
    return np.stack([(res(p[0] + DIFF_STEP, p[1]) - base) / DIFF_STEP,
                     (res(p[0], p[1] + DIFF_STEP) - base) / DIFF_STEP], axis=1)


def gauss_newton(p0, apex, goal, h, hopper: Hopper, sqrt_w, max_iter=16, cost_tol=1e-16,
                  terrain=None, min_trust=0.0, stall=0.0, tol=SEARCH_TOL):
    """`_deadbeat_gradient`'s damped Gauss-Newton, step for step: the step
    `(J'J + 1e-12 tr(J'J) I)^-1 J'r` times the trust scale, clipped to `MAX_STEP` per
    coordinate and the iterate to the bounds; a trial that does not lower C2 is rejected and
    quarters the trust scale, an accepted one doubles it (up to 1). A singular normal
    matrix (a failed stride's zero Jacobian) gives no step; at a bound of `s` with the
    gradient pointing out of the box the step is along `th_td` alone. Stops as the JAX
    solver's: after `max_iter` trials, at a C2 below `cost_tol`, a trust scale below
    `min_trust`, or an accepted trial that gains less than the fraction `stall` of C2.
    Trial strides at `tol` (rtol = atol), the Jacobian's at `JAC_TOL`."""
    def step(p, r, jac, trust):
        normal = jac.T @ jac + 1e-12 * np.trace(jac.T @ jac) * np.eye(2)
        grad = jac.T @ r
        try:
            direction = np.linalg.solve(normal, grad)
        except np.linalg.LinAlgError:  # a failed stride: zero Jacobian, no step
            direction = np.zeros(2)
        if (p[1] <= 0.0 and grad[1] > 0.0) or (p[1] >= 1.0 and grad[1] < 0.0):  # s pinned
            with np.errstate(divide="ignore", invalid="ignore"):
                direction = np.array([grad[0] / normal[0, 0], 0.0])
        if not np.all(np.isfinite(direction)):
            direction = np.zeros(2)
        q = p - np.clip(trust * direction, -MAX_STEP, MAX_STEP)
        return np.array([min(max(q[0], TH_LO), TH_HI), min(max(q[1], 0.0), 1.0)])

    best = np.asarray(p0, float)
    r_b = _residual(best, apex, goal, h, hopper, sqrt_w, terrain, tol)
    jac_b = _jacobian(best, apex, goal, h, hopper, sqrt_w, terrain)
    cost_b = float(r_b @ r_b)
    trust = 1.0
    trial_p = step(best, r_b, jac_b, trust)
    flat = False
    for _ in range(max_iter):
        if not (cost_b > cost_tol and trust >= min_trust and not flat):
            break
        r = _residual(trial_p, apex, goal, h, hopper, sqrt_w, terrain, tol)
        if float(r @ r) < cost_b:
            flat = cost_b - float(r @ r) < stall * cost_b
            best, r_b, cost_b = trial_p, r, float(r @ r)
            jac_b = _jacobian(best, apex, goal, h, hopper, sqrt_w, terrain)
            trust = min(2.0 * trust, 1.0)
        else:
            trust = 0.25 * trust
        trial_p = step(best, r_b, jac_b, trust)
    return best, cost_b


def multi_start(apex, goal, h, hopper: Hopper, sqrt_w, method="gauss-newton", terrain=None):
    """The multi-start solver: the best end `(p, C2)` of the starts of `initial_guesses`."""
    best, best_cost = None, INF
    for p0 in initial_guesses(apex, goal, h, hopper, terrain):
        if method == "lm":
            sol = least_squares(_residual, p0, method="lm", jac="2-point",
                                diff_step=LM_DIFF_STEP, ftol=1e-15, xtol=1e-15, gtol=1e-15,
                                max_nfev=MAX_NFEV, args=(apex, goal, h, hopper, sqrt_w, terrain))
            end, cost = clip_p(sol.x), 2.0 * sol.cost
        elif method == "gauss-newton":
            end, cost = gauss_newton(p0, apex, goal, h, hopper, sqrt_w, terrain=terrain)
        else:
            raise ValueError(f"method must be 'gauss-newton' or 'lm', got {method!r}")
        if cost < best_cost:  # the first of equal costs wins, as jnp.argmin
            best, best_cost = end, cost
    if best is None:  # every start ended at a non-finite cost: argmin of NaNs is the first
        best = initial_guesses(apex, goal, h, hopper, terrain)[0]
    return best, best_cost
