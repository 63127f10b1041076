"""The kernels of the SLIP deadbeat solvers (section IV-A2, eqs 12-16): the trial stride,
the costs, the control limits, and the gradient solver that the table start polishes with.

For a target apex `goal` over a flat foothold at `h`, find `u = (th_td, kc, kd)`:

- `kd` from the energy balance (eq 12), with the bottom compression `rho_b` taken from the
  integrated compression phase for the current `(th_td, kc)`: the stride then ends with the
  goal's energy exactly, so matching `ydot` also matches `z`.
- Inner problem (eqs 13-14) over `th_td` for fixed `kc`: the root of
  `ydot_lo(th_td) = ydot*` (the minimiser of C1's velocity term). The liftoff velocity
  decreases with the touchdown angle (Fig. 5) on most of the bracket, but not on all of it
  (it rises first next to a leg far behind a fast body, and wiggles on strides that
  reverse the velocity), so the equation can have several roots.
- Outer problem (eqs 15-16) over `kc`: a coarse scan, then golden-section minimisation of
  C2 next to the best scan point.

Two solvers (`deadbeat.deadbeat_slip` picks one):

- `"bracket"` (`bracket.py`): nested bracketing searches. Inner: a 17-point
  grid over `th_td`, optimistix bisection (explicit `flip`) in up to three of the speed
  error's sign changes, the root with the least C2. Outer: golden section over a
  normalised `s in [0, 1]` next to the best point of a 7-point scan.
- `"gradient"` (the default): both problems jointly over `(th_td, kc)` (`kd` from eq 12)
  by damped Gauss-Newton steps applied with optax, the Jacobian by forward-mode
  differentiation through diffrax, from three points of a coarse grid: 10-30x faster per
  target than `"bracket"` and more accurate (docs/slip.md); `deadbeat_gradient` here, its
  start from the apex table in `table.py`.

One sample per call; vmap for batches.
"""

import jax
import jax.numpy as jnp
import optax

from ..._core.batching import bounded_while, run_once
from ..._core.params import Hopper
from ..bhop import safe_sqrt
from ..flight import OK, touchdown
from .stride import (
    KD_RATIO,
    Tolerances,
    ascent,
    cartesian,
    compress,
    decompress,
    flat_touchdown,
    lowest_com,
    slip_stride,
    stride_clear,
)

# Control limits (eq 14; `docs/slip.md`, "Deadbeat") and the touchdown-angle search interval.
KAPPA_LO, KAPPA_HI = 10.0, 60.0  # kc rho0 / (m g)
RATIO_LO, RATIO_HI = KD_RATIO  # kd / kc
TH_LO, TH_HI = -jnp.pi / 3, jnp.pi / 3
# Searches run at looser tolerances than the simulated stride (1e-10): against it, on 2 000
# random strides of the reference hopper, SEARCH_TOL moves an apex by at most 2e-8 m (m/s)
# and DECISION_TOL by at most 6.5e-5: a controller's decision, whose prediction is accepted
# within 5 cm of its goal, polishes on the cheaper strides (docs/slip.md, "Deadbeat"). On an
# accelerator a decision runs fixed-shape strides instead (`FIXED_DECISION_TOL`, 10 steps
# per stance phase, at most 3.0e-6 there), in searches of fixed shape (`fixed_loops`: no
# data-dependent loop in the decision; docs/slip.md, "Fixed-shape trial strides").
SEARCH_TOL = Tolerances(rtol=1e-8, atol=1e-8)
DECISION_TOL = Tolerances(rtol=1e-5, atol=1e-5)
FIXED_DECISION_TOL = Tolerances(steps=10, fixed_loops=True)


def decision_tol(platform: str | None = None) -> Tolerances:
    """A decision's trial strides on `platform` (default: JAX's default backend): adaptive
    (`DECISION_TOL`) on a CPU, where a stride's few adaptive steps cost less than the fixed
    ones, fixed-shape strides and searches (`FIXED_DECISION_TOL`) elsewhere, where every
    turn of a data-dependent loop waits for the host (docs/slip.md, "Fixed-shape trial
    strides")."""
    platform = jax.default_backend() if platform is None else platform
    return DECISION_TOL if platform == "cpu" else FIXED_DECISION_TOL


# The speed the inner search sees where a trial stance fails (see `trial_stride`).
FAIL_SPEED = 1e3
# Weights of C2 (eq 16): position (m) and velocity (m/s) errors weigh the same.
W_POS, W_VEL = 1.0, 1.0
# Largest Gauss-Newton step per coordinate of (th_td in rad, s = normalised kc).
MAX_STEP = 0.2
# Bisection steps of the inner problem that seed the gradient solver (0: grid starts only).
START_BISECTIONS = 14


def kc_limits(hopper: Hopper):
    scale = hopper.m * hopper.g / hopper.rho0
    return KAPPA_LO * scale, KAPPA_HI * scale


def energy_kd(apex, goal, kc, rho_b, hopper: Hopper, ydot_td=None, ydot_lo=None):
    """Decompression stiffness that gives the goal's energy (eq 12).

    With a horizontal flight acceleration `a` (wind), flight does work on the body: the
    energy arrives at touchdown with the horizontal velocity `ydot_td = ydot + a t_d`, and
    a rise of `t_up` reaches the goal's `(z, ydot)` from liftoff only with the liftoff
    energy `m g z* + m ydot_lo^2 / 2` with `ydot_lo = ydot* - a t_up`. `ydot_td` and
    `ydot_lo` replace the apex and goal velocities (`None`: no wind, eq 12 as it is).
    """
    m, g = hopper.m, hopper.g
    ydot = apex[2] if ydot_td is None else ydot_td
    ydot_goal = goal[2] if ydot_lo is None else ydot_lo
    gain = m * (ydot_goal ** 2 - ydot ** 2) + 2.0 * m * g * (goal[1] - apex[1])
    return kc + gain / (rho_b - hopper.rho0) ** 2


def mirrored_rise_time(goal, h, th, hopper: Hopper):
    """The rise time to the goal's height from the liftoff of a stance mirrored about the
    vertical (liftoff at `h + rho0 cos th_td`): the first guess of `t_up` where the wind's
    work in the rise is balanced before the stance has run."""
    return safe_sqrt(2.0 * (goal[1] - (h + hopper.rho0 * jnp.cos(th))) / hopper.g)


def _wind_kd(apex, goal, h, th, kc, x_b, v_td, hopper: Hopper, tol: Tolerances, wind):
    """Eq 12's `kd` with a wind `a` in flight (`energy_kd`): the rise time `t_up` is first
    that of a mirrored stance (liftoff at `h + rho0 cos th_td`), then that of the liftoff
    this first `kd` gives, which leaves an energy error of second order in the change of
    the liftoff between the two. Without wind both are the same: the second decompression
    runs only where `wind != 0` (`run_once`; under `vmap`, not in a windless batch)."""
    t_up = mirrored_rise_time(goal, h, th, hopper)
    kd = energy_kd(apex, goal, kc, x_b[0], hopper, v_td[0], goal[2] - wind * t_up)

    def second(zero):
        x_lo, _ = decompress(x_b + zero, jnp.where(kd > 0, kd, kc), hopper, tol)
        _, v_lo = cartesian(x_lo)
        t_lo = jnp.maximum(v_lo[1], 0.0) / hopper.g
        return energy_kd(apex, goal, kc, x_b[0], hopper, v_td[0], goal[2] - wind * t_lo)

    return run_once(wind != 0.0, second, kd, tol.fixed_loops)


def trial_stride(apex, goal, h, th, kc, hopper: Hopper, tol: Tolerances, terrain=None, wind=None,
           clearance=False):
    """Stride over flat ground with `kd` from eq 12.

    With `wind` (a horizontal flight acceleration; `None`: none), both flight phases fly
    with it and `kd` comes from `_wind_kd`.

    With `terrain`, the foot lands where it meets the terrain (`flight.touchdown`), on the
    height of that block instead of `h`: a stride planned for a foothold near a block's edge
    whose foot lands on the neighbouring block is computed on the block it lands on. A
    touchdown that fails (a wall, a hole) counts as a failed stride.

    Returns:
        `(next_apex, code, kd, speed)`. `speed` is what the inner search sees: the liftoff
        horizontal velocity when both stance phases completed (continuous in `th_td` even
        where the liftoff does not rise), else `-+FAIL_SPEED` by the side the body fell to
        (a leg far behind the body acts like "too fast"), which keeps it monotone. With
        `clearance` (and `terrain`) a fifth value: whether the stride also clears the
        terrain as `slip_stride` checks it (`jaxhop._models.slip.stride.stride_clear`).
    """
    y_foot, v_td, reached = flat_touchdown(apex, th, h, hopper, wind)
    if terrain is not None:
        offset = hopper.rho0 * jnp.stack([jnp.sin(th), -jnp.cos(th)])
        t_code, block, _, y_t, v_t = touchdown(apex, offset, terrain, hopper,
                                               *([] if wind is None else [wind]))
        landed = t_code == OK
        y_foot = jnp.where(landed, y_t, y_foot)
        v_td = jnp.where(landed, v_t, v_td)
        h = jnp.where(landed, terrain.heights[block], h)
        reached = landed
    x_b, code_c = compress(th, v_td, kc, hopper, tol)
    if wind is None:
        kd = energy_kd(apex, goal, kc, x_b[0], hopper)
    else:
        kd = _wind_kd(apex, goal, h, th, kc, x_b, v_td, hopper, tol, wind)
    # A non-positive kd cannot push off: the trial runs with kc and counts as failed.
    kd_ok = kd > 0
    x_lo, code_d = decompress(x_b, jnp.where(kd_ok, kd, kc), hopper, tol)
    p_lo, v_lo = cartesian(x_lo)
    stance_ok = (code_c == OK) & (code_d == OK) & kd_ok
    code = jnp.where(code_c != OK, code_c, code_d)
    code = jnp.where(reached & kd_ok & (v_lo[1] > 0), code, jnp.maximum(code, 1))
    th_end = jnp.where(code_c != OK, x_b[1], x_lo[1])
    speed = jnp.where(stance_ok, v_lo[0], jnp.where(th_end < 0, FAIL_SPEED, -FAIL_SPEED))
    foot = jnp.stack([y_foot, h])
    a = 0.0 if wind is None else wind
    nxt = ascent(p_lo + foot, v_lo, hopper, a)
    if not clearance:
        return nxt, code, kd, speed
    clear = stride_clear(th, foot, lowest_com(th, x_b, p_lo, hopper), p_lo + foot, v_lo,
                         terrain, hopper, a)
    return nxt, code, kd, speed, clear


def goal_cost(nxt, code, goal):
    err = nxt - goal
    cost = W_POS * (err[0] ** 2 + err[1] ** 2) + W_VEL * err[2] ** 2
    return jnp.where(code == OK, cost, 1e6)


def _residual(p, apex, goal, h, hopper, tol, terrain=None, wind=None):
    # A non-finite point runs a benign stride and counts as failed: a stance started from
    # NaN would run diffrax to MAX_STEPS, and under vmap stall every other lane.
    finite = jnp.all(jnp.isfinite(p))
    th, s = jnp.where(finite, p, 0.0)
    kc_lo, kc_hi = kc_limits(hopper)
    nxt, code, *_ = trial_stride(apex, goal, h, th, kc_lo + s * (kc_hi - kc_lo), hopper, tol,
                           terrain, wind)
    return jnp.where((code == OK) & finite, nxt - goal, 1e3)


def initial_guesses(apex, goal, h, hopper, tol, terrain=None, wind=None):
    """Starts of the gradient solver: the best `th_td` of a coarse grid for each of a few `s`.

    One start per `s` row, because C2 can have two valleys in `kc` (strides that reverse the
    velocity); a single best grid point sometimes sits in the wrong one.
    """
    ths, ss = jnp.meshgrid(jnp.linspace(-0.5, 0.5, 9), jnp.array([0.05, 0.35, 0.7]))
    weights = jnp.array([W_POS, W_POS, W_VEL])

    def cost(p):
        return jnp.sum(weights * _residual(p, apex, goal, h, hopper, tol, terrain, wind) ** 2)

    costs = jax.vmap(jax.vmap(cost))(jnp.stack([ths, ss], axis=-1))
    best = jnp.argmin(costs, axis=1)
    grid = jnp.stack([ths[0, best], ss[:, 0]], axis=1)
    if START_BISECTIONS == 0:
        return grid
    # The speed is very steep in th_td at low speeds (C2's valley can be far narrower than
    # the grid step): a short inner bisection (eqs 13-14) per row gives a second start.
    kc_lo, kc_hi = kc_limits(hopper)

    def bisect(s):
        kc = kc_lo + s * (kc_hi - kc_lo)

        # A last pass prices the final midpoint: one stride site serves both (one to compile).
        def body(i, b):
            lo, hi, _ = b
            mid = 0.5 * (lo + hi)
            nxt, code, _, speed = trial_stride(apex, goal, h, mid, kc, hopper, tol, terrain, wind)
            move, fast = i < START_BISECTIONS, speed > goal[2]
            c = jnp.sum(weights * jnp.where(code == OK, nxt - goal, 1e3) ** 2)
            return jnp.where(move & fast, mid, lo), jnp.where(move & ~fast, mid, hi), c

        init = (jnp.asarray(TH_LO, float), jnp.asarray(TH_HI, float), jnp.asarray(jnp.inf))
        lo, hi, c = jax.lax.fori_loop(0, START_BISECTIONS + 1, body, init)
        return 0.5 * (lo + hi), c

    th_inner, c_inner = jax.vmap(bisect)(ss[:, 0])
    inner = jnp.stack([th_inner, ss[:, 0]], axis=1)
    better = c_inner < jnp.min(costs, axis=1)
    return jnp.where(better[:, None], inner, grid)


def deadbeat_gradient(apex, goal, h, hopper, tol, max_iter=16, cost_tol=1e-16,
                       terrain=None, wind=None, starts=None, min_trust=0.0, stall=0.0,
                       max_turns=None):
    """Damped Gauss-Newton on C2 over `p = (th_td, s)`, the Jacobian by forward mode through
    diffrax (two tangents); optax applies the steps. A trial that does not lower C2 is
    rejected and quarters the step scale; an accepted one doubles it (up to 1). A start
    stops after `max_iter` steps (may be traced), at a C2 below `cost_tol`, at a step scale
    below `min_trust` (only rejected steps shrink it: the trial strides' noise floor), or
    after an accepted step that gains less than the fraction `stall` of C2 (a target out
    of reach: the valley's floor).

    `starts`: `(n, 2)` starting points (default `initial_guesses`). `max_turns`: a static
    bound of a traced `max_iter`, for `tol.fixed_loops` (a loop of `max_turns + 1` turns).
    Returns `(th_td, kc, c2)` of the best end point.
    """
    tol = tol.forward()
    sqrt_w = jnp.sqrt(jnp.array([W_POS, W_POS, W_VEL]))

    def residual(p):
        r = sqrt_w * _residual(p, apex, goal, h, hopper, tol, terrain, wind)
        return r, r

    opt = optax.chain(optax.clip(MAX_STEP), optax.sgd(1.0))

    def step(p, r, jac, trust, state):
        normal = jac.T @ jac + 1e-12 * jnp.trace(jac.T @ jac) * jnp.eye(2)
        grad = jac.T @ r
        direction = jnp.linalg.solve(normal, grad)
        # s at a bound the gradient points out of: a step along th_td alone (a clipped 2-D
        # step stalls there, where targets out of reach often have their best stride).
        pinned = ((p[1] <= 0.0) & (grad[1] > 0.0)) | ((p[1] >= 1.0) & (grad[1] < 0.0))
        direction = jnp.where(pinned, jnp.stack([grad[0] / normal[0, 0], 0.0]), direction)
        # A failed stride has a constant residual, hence a zero Jacobian and a singular
        # normal matrix: no step (the trial repeats the best point, which is rejected).
        direction = jnp.where(jnp.all(jnp.isfinite(direction)), direction, 0.0)
        updates, state = opt.update(trust * direction, state)
        p = optax.apply_updates(p, updates)
        return jnp.stack([jnp.clip(p[0], TH_LO, TH_HI), jnp.clip(p[1], 0.0, 1.0)]), state

    def cond(carry):
        best, _, _, cost, _, trust, _, i, flat = carry
        return (i < max_iter) & (cost > cost_tol) & (trust >= min_trust) & ~flat

    def body(carry):
        best, r_b, jac_b, cost_b, trial, trust, state, i, _ = carry
        jac, r = jax.jacfwd(residual, has_aux=True)(trial)
        cost = jnp.sum(r**2)
        # Step -1 prices the start (kept; trust 0.5 -> 1): one differentiated stride site.
        first = i < 0
        better = (cost < cost_b) | first
        flat = better & ~first & (cost_b - cost < stall * cost_b)
        best, r_b, jac_b = (jnp.where(better, new, old) for new, old in
                            ((trial, best), (r, r_b), (jac, jac_b)))
        cost_b = jnp.sum(r_b**2)
        trust = jnp.where(better, jnp.minimum(2.0 * trust, 1.0), 0.25 * trust)
        trial, state = step(best, r_b, jac_b, trust, state)
        return best, r_b, jac_b, cost_b, trial, trust, state, i + 1, flat

    def solve(p0):
        carry = (p0, jnp.zeros(3), jnp.zeros((3, 2)), jnp.asarray(jnp.inf), p0,
                 jnp.array(0.5), opt.init(p0), -1, jnp.asarray(False))
        turns = (max_iter if max_turns is None else max_turns) + 1  # step -1 included
        best, _, _, cost, *_ = bounded_while(cond, body, carry, turns, tol.fixed_loops)
        return best, cost

    if starts is None:
        starts = initial_guesses(apex, goal, h, hopper, tol, terrain, wind)
    ends, costs = jax.vmap(solve)(starts)
    k = jnp.argmin(costs)
    kc_lo, kc_hi = kc_limits(hopper)
    return ends[k, 0], kc_lo + ends[k, 1] * (kc_hi - kc_lo), costs[k]


def clipped_controls(apex, goal, h, th, kc, hopper, tol, terrain=None, wind=None, predict=False):
    """`(u, ok)` of `deadbeat_slip` for the solution `(th_td, kc)`: eq 12's `kd` from its
    trial stride, the controls clipped to their limits. With `predict` (and `terrain`),
    also `(pred, code)` of `slip_stride` with `u` at `tol`: the trial stride itself where
    no control was clipped (the same stride, with `slip_stride`'s clearance checks), a
    stride of its own only where one was."""
    out = trial_stride(apex, goal, h, th, kc, hopper, tol, terrain, wind, clearance=predict)
    code, kd = out[1], out[2]
    kc_lo, kc_hi = kc_limits(hopper)
    kc_c = jnp.clip(kc, kc_lo, kc_hi)
    kd_c = jnp.clip(kd, RATIO_LO * kc_c, RATIO_HI * kc_c)
    clipped = (kd_c != kd) | (kc_c != kc) | ~jnp.isfinite(kd)
    ok = (code == OK) & ~clipped
    u = jnp.stack([th, kc_c, jnp.where(jnp.isfinite(kd_c), kd_c, kc_c)])
    if not predict:
        return u, ok

    def stride(zero):
        nxt, code, _ = slip_stride(apex + zero, u, terrain, hopper,
                                   0.0 if wind is None else wind, tol)
        return nxt, code

    trial = (out[0], jnp.where((code == OK) & out[4], OK, jnp.maximum(code, 1)))
    pred, code = run_once(clipped, stride, trial, tol.fixed_loops)
    return u, ok, pred, code
