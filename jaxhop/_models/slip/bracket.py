"""The SLIP deadbeat's `"bracket"` solver (`deadbeat.deadbeat_slip`,
`method="bracket"`): nested bracketing searches over the touchdown angle and the
compression stiffness (section IV-A2, eqs 13-16).

Inner problem (eqs 13-14): a `TH_GRID`-point grid over `th_td`, optimistix bisection
(explicit `flip`) in up to `N_ROOTS` of the speed error's sign changes, the root with the
least C2. Outer problem (eqs 15-16): golden section over a normalised `s in [0, 1]` next
to the best point of a `KC_SCAN`-point scan. One sample per call; vmap for batches.
"""

import jax
import jax.numpy as jnp
import optimistix as optx

from .kernels import FAIL_SPEED, TH_HI, TH_LO, goal_cost, kc_limits, trial_stride
from .stride import flat_touchdown, polar_state

# Inner touchdown-angle grid, sign changes bisected per stiffness, steps per sign change,
# points of the outer stiffness scan.
TH_GRID, N_ROOTS, BISECTION_STEPS, KC_SCAN = 17, 3, 24, 7
# Radial touchdown speed (m/s) above -GRAZE_SPEED: an unloaded leg (`_search_trial`).
GRAZE_SPEED = 1e-3


def _search_trial(apex, goal, h, th, kc, hopper, tol):
    """`trial_stride` as the bracket searches see it: a barely loaded leg counts as failed.

    A leg whose radial speed at touchdown is within `GRAZE_SPEED` of zero compresses by
    ~nothing and lifts off ~1e-13 s after its bottom; its decompression solve then runs to
    `MAX_STEPS` (4096 steps), and under `vmap` one such lane stalls every other lane. A
    bisection next to the unloaded-leg boundary converges right onto it, so the searches
    run a benign `th_td = 0` stride there instead and see the failure value `trial_stride` gives
    an unloaded leg (`+FAIL_SPEED` for a leg behind the body, `-FAIL_SPEED` ahead).
    """
    _, v_td, _ = flat_touchdown(apex, th, h, hopper)
    rhod, _ = polar_state(th, v_td)
    grazing = rhod > -GRAZE_SPEED
    nxt, code, kd, speed = trial_stride(apex, goal, h, jnp.where(grazing, 0.0, th), kc, hopper, tol)
    speed = jnp.where(grazing, jnp.where(th < 0, FAIL_SPEED, -FAIL_SPEED), speed)
    return nxt, jnp.where(grazing, jnp.maximum(code, 1), code), kd, speed


def _inner_th(apex, goal, h, kc, hopper, tol):
    """Touchdown angle whose stride (with eq 12's kd) reaches the goal velocity (eqs 13-14).

    The liftoff speed decreases with `th_td` on most of `[TH_LO, TH_HI]` (Fig. 5), but not
    everywhere: next to a leg far behind a fast body it rises first (a maximum, then the
    decreasing branch), strides that reverse the velocity add wiggles, and the failure
    values jump. So the speed error is sampled on `TH_GRID` points, up to `N_ROOTS` of its
    sign changes are bisected (vmapped), and the root whose stride has the least C2 wins.
    Sign changes between two completed stances come first, then those next to a failed
    one (often only the jump to a failure value), leftmost first. Without any sign change
    the grid point of least |error| is returned.

    Returns:
        `(th_td, c2)`: the touchdown angle and the C2 of its stride.
    """
    def trial(th):
        return _search_trial(apex, goal, h, th, kc, hopper, tol)

    def error(th):
        return trial(th)[3] - goal[2]

    grid = jnp.linspace(TH_LO, TH_HI, TH_GRID)
    err = jax.vmap(error)(grid)
    done = jnp.abs(err + goal[2]) < 0.5 * FAIL_SPEED  # a completed stance, not a failure
    change = (err[:-1] > 0) != (err[1:] > 0)
    score = jnp.where(change, 1 + done[:-1].astype(int) + done[1:].astype(int), 0)
    cells = jnp.argsort(-score, stable=True)[:N_ROOTS]
    found = score[cells] > 0
    # Unused lanes bisect a degenerate bracket at the grid point of least |error|.
    nearest = jnp.argmin(jnp.where(done, jnp.abs(err), jnp.inf))
    lower = jnp.where(found, grid[cells], grid[nearest])
    upper = jnp.where(found, grid[cells + 1], grid[nearest])
    sign = jnp.where(err[cells] > 0, 1.0, -1.0)  # sign * error falls from + to - in a cell

    def bisect(lo, hi, sg):
        # flip=True: `sg * error` is positive at `lo`; explicit, so no evaluations at the
        # ends. Bisection stops when both the bracket (rad) and |error| (m/s) are below
        # atol (after ~21 steps); one next to a jump never gets there and stops at
        # BISECTION_STEPS, where the bracket is a grid cell / 2**24 < 1e-8 rad wide.
        solver = optx.Bisection(rtol=0.0, atol=1e-7, flip=True)
        sol = optx.root_find(lambda th, _: sg * error(th), solver, 0.5 * (lo + hi),
                             options=dict(lower=lo, upper=hi), max_steps=BISECTION_STEPS,
                             throw=False)
        return sol.value

    def c2(th):
        nxt, code, *_ = trial(th)
        return goal_cost(nxt, code, goal)

    roots = jax.vmap(bisect)(lower, upper, sign)
    costs = jax.vmap(c2)(roots)
    costs = jnp.where(found | (jnp.arange(N_ROOTS) == 0), costs, jnp.inf)
    best = jnp.argmin(costs)
    return roots[best], costs[best]


def golden_minimise(fn, lower, upper, rtol=0.0, atol=1e-8, max_steps=80):
    """Golden-section minimum of `fn` on `[lower, upper]`.

    optimistix 0.1.0's `GoldenSearch` puts its first point at `(upper - lower) / (phi + 1)`,
    forgetting `lower`: the search runs over `s in [0, 1]` and maps back.
    """
    def scaled(s, args):
        return fn(lower + s * (upper - lower))

    sol = optx.minimise(scaled, optx.GoldenSearch(rtol=rtol, atol=atol), jnp.array(0.5),
                        options=dict(lower=0.0, upper=1.0), max_steps=max_steps, throw=False)
    return lower + sol.value * (upper - lower)


def deadbeat_bracket(apex, goal, h, hopper, tol, n_scan=KC_SCAN):
    kc_lo, kc_hi = kc_limits(hopper)

    def cost(s):
        return _inner_th(apex, goal, h, kc_lo + s * (kc_hi - kc_lo), hopper, tol)[1]

    # C2 can have two valleys in kc (strides that reverse the velocity): a coarse scan
    # picks the better one, golden section then refines inside its two neighbouring cells.
    scan = jnp.linspace(0.0, 1.0, n_scan)
    best = jnp.argmin(jax.vmap(cost)(scan))
    lower = scan[jnp.maximum(best - 1, 0)]
    upper = scan[jnp.minimum(best + 1, n_scan - 1)]
    s = golden_minimise(cost, lower, upper, atol=1e-6)
    kc = kc_lo + s * (kc_hi - kc_lo)
    return _inner_th(apex, goal, h, kc, hopper, tol)[0], kc
