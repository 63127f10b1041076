"""Domain and feasible-goal regions of a BHop stride policy template (section V, App. A-B).

Coordinates are relative to the template's segment: `y_rel = y - py`, `zr = z - h - rho0`
(apex height above the virtual ground). All functions take one template (scalar leaves, see
`Templates.row`) and one state; vmap them for batches.

The feasible goal `Gf` (eq 6) separates into a velocity/height part and a position part:
- position: for every touchdown `y_td in [-l, l]` some `dy in [dy_lo, dy_hi]` must reach the
  liftoff point, so `y_rel - ydot* t_up in [l + dy_lo, -l + dy_hi]` (eqs 49-50);
- velocity/height: the liftoff velocity `v* = (ydot*, sqrt(2 g zr*))` must be reachable with
  admissible `(th, k)` from every touchdown velocity `v` of the domain. Given `v` and `v*`,
  `(th, k)` are unique (`stance_controls`), and with `0 < k_lo <= 1 <= k_hi` the binding `v`
  are the extreme points of the domain's touchdown-velocity set: its corners and the ends of
  its energy arcs (see docs/decisions.md for the argument). `goal_velocity_ok` tests those;
  `goal_height_bounds` turns the same conditions into the height interval at each `ydot*`
  (the corrected eqs 45-48).
"""

import jax
import jax.numpy as jnp

from .._core.params import Hopper
from .._models.bhop import safe_sqrt, stance_controls
from .templates import Templates, eq37_lead


def foot_lead(ydot, tmpl: Templates):
    """How far ahead of the COM's touchdown point the planned foot lands (m).

    0 for BHop; `Y` of eq 37 for templates adjusted for the SLIP model (`Templates.slip`),
    from its traced coefficients in the run-time controller's templates (`Templates.lead`).
    """
    if tmpl.lead is not None:
        return eq37_lead(ydot, tmpl.lead)
    return 0.0 * ydot if tmpl.slip is None else tmpl.slip.lead(ydot)


def slip_shift_limits(ydot, tmpl: Templates):
    """The horizontal-shift interval `dy` of `Gf` at goal velocity `ydot`.

    BHop: the template's `[dy_lo, dy_hi]`. SLIP (eq 35): `[h(ydot_avg), -h(-ydot_avg)]` in
    its place, `ydot_avg` the mean of the domain's and the goal's velocities; `h` is
    increasing, so the limits that hold from every domain velocity are `h` at the domain's
    `v_hi` and `-h(-.)` at its `v_lo`.
    """
    if tmpl.slip is None:
        return tmpl.dy_lo, tmpl.dy_hi
    lo = tmpl.slip.h(0.5 * (tmpl.v_hi + ydot))
    hi = -tmpl.slip.h(-0.5 * (tmpl.v_lo + ydot))
    if tmpl.slip.reversal:
        # The leg force points away from the foot: a stance that turns forward motion into
        # backward motion lifts off behind its foot, and vice versa (docs/decisions.md).
        hi = jnp.where((ydot < 0) & (tmpl.v_hi > 0), jnp.minimum(hi, 0.0), hi)
        lo = jnp.where((ydot > 0) & (tmpl.v_lo < 0), jnp.maximum(lo, 0.0), lo)
    if tmpl.slip.keep_direction:
        # A stance that starts and ends moving forward moves forward all along, so it lifts
        # off ahead of the COM's touchdown point, the foot lead `Y` behind the planned foot;
        # mirrored for backward strides (docs/decisions.md, "Direction rule").
        slack = 2.0 * tmpl.half_length * tmpl.slip.direction_slack
        lo = jnp.where((ydot >= 0) & (tmpl.v_lo >= 0),
                       jnp.maximum(lo, -tmpl.slip.lead(tmpl.v_lo) - slack), lo)
        hi = jnp.where((ydot <= 0) & (tmpl.v_hi <= 0),
                       jnp.minimum(hi, -tmpl.slip.lead(tmpl.v_hi) + slack), hi)
    return lo, hi


def template_domain_contains(z_rel, tmpl: Templates, hopper: Hopper):
    """`Z in D(Phi)` of eqs 38-41 (no collision clause), relative coordinates.

    For SLIP-adjusted templates the `y` range is shifted by `-Y` (eqs 36-37).
    """
    y_rel, zr, ydot = z_rel
    energy = 0.5 * hopper.m * ydot**2 + hopper.m * hopper.g * zr
    y_td = y_rel + ydot * safe_sqrt(2.0 * zr / hopper.g) + foot_lead(ydot, tmpl)
    l = tmpl.half_length
    return ((ydot >= tmpl.v_lo) & (ydot <= tmpl.v_hi) & (zr > 0) & (energy >= tmpl.e_lo)
            & (energy <= tmpl.e_hi) & (y_td >= -l) & (y_td <= l))


def domain_height_bounds(ydot, tmpl: Templates, hopper: Hopper):
    """Height interval `Rz` (eq 39) at velocity `ydot`, intersected with `zr > 0`."""
    mg = hopper.m * hopper.g
    lo = jnp.maximum((tmpl.e_lo - 0.5 * hopper.m * ydot**2) / mg, 0.0)
    hi = (tmpl.e_hi - 0.5 * hopper.m * ydot**2) / mg
    inside = (ydot >= tmpl.v_lo) & (ydot <= tmpl.v_hi)
    return jnp.where(inside, lo, jnp.inf), jnp.where(inside, hi, -jnp.inf)


def domain_velocity_extremes(tmpl: Templates, hopper: Hopper):
    """Candidate extreme touchdown velocities of the domain, shape `(10, 2)`, and a mask.

    The domain's touchdown velocities `v = (ydot, -sqrt(2 g zr))` fill the part of the annulus
    `2 e_lo / m <= |v|^2 <= 2 e_hi / m` with `ydot in RV` and `zdot <= 0` (closure of
    `zr > 0`). Candidates: the four corners on `ydot = v_lo, v_hi`; the four ends of the arcs
    on `zdot = 0`; the two points where a touchdown-angle limit line is tangent to the outer
    arc (only for limits of the "wrong" sign, `th_lo > 0` or `th_hi < 0`).
    """
    r_lo = jnp.sqrt(2.0 * tmpl.e_lo / hopper.m)
    r_hi = jnp.sqrt(2.0 * tmpl.e_hi / hopper.m)
    a = jnp.array([1.0, 1.0, 1.0, 1.0, 1.0, -1.0, 1.0, -1.0, 0.0, 0.0])
    a = a * jnp.stack([tmpl.v_lo, tmpl.v_hi, tmpl.v_lo, tmpl.v_hi, r_lo, r_lo, r_hi, r_hi,
                       0.0, 0.0])
    r2 = jnp.stack([r_hi, r_hi, r_lo, r_lo, r_lo, r_lo, r_hi, r_hi, r_hi, r_hi]) ** 2
    b = -safe_sqrt(r2 - a**2)
    corners = jnp.stack([a, b], axis=1)
    t_lo, t_hi = jnp.tan(tmpl.th_lo), jnp.tan(tmpl.th_hi)
    tangent_lo = -r_hi * jnp.stack([1.0, t_lo]) / jnp.sqrt(1.0 + t_lo**2)
    tangent_hi = r_hi * jnp.stack([1.0, t_hi]) / jnp.sqrt(1.0 + t_hi**2)
    corners = corners.at[8].set(tangent_lo).at[9].set(tangent_hi)
    norm2 = jnp.sum(corners**2, axis=1)
    eps = 1e-9
    mask = ((corners[:, 0] >= tmpl.v_lo - eps) & (corners[:, 0] <= tmpl.v_hi + eps)
            & (corners[:, 1] <= eps) & (norm2 >= r_lo**2 - eps) & (norm2 <= r_hi**2 + eps)
            & (r2 >= a**2 - eps))
    mask = mask.at[8].set(mask[8] & (tmpl.th_lo > 0)).at[9].set(mask[9] & (tmpl.th_hi < 0))
    return corners, mask


def goal_velocity_ok(v_star, tmpl: Templates, hopper: Hopper):
    """Whether liftoff velocity `v_star` is reachable from every domain touchdown velocity."""
    corners, mask = domain_velocity_extremes(tmpl, hopper)
    th, k = jax.vmap(stance_controls, in_axes=(0, None))(corners, v_star)
    ok = (th >= tmpl.th_lo) & (th <= tmpl.th_hi) & (k >= tmpl.k_lo) & (k <= tmpl.k_hi)
    return jnp.all(ok | ~mask) & jnp.any(mask) & (v_star[1] > 0)


def goal_position_bounds(ydot, zr, tmpl: Templates, hopper: Hopper):
    """`y_rel` interval of `Gf` at `(ydot, zr)` (eqs 49-50; eq 35 for SLIP templates)."""
    shift = ydot * safe_sqrt(2.0 * zr / hopper.g)
    l = tmpl.half_length
    dy_lo, dy_hi = slip_shift_limits(ydot, tmpl)
    return shift + l + dy_lo, shift - l + dy_hi


def feasible_goal_contains(z_rel, tmpl: Templates, hopper: Hopper, y_tol=0.0):
    """`Z' in Gf(Phi)` by the closed form, relative coordinates.

    `y_tol` widens the `y` interval on both sides (m): a goal on the boundary between two
    segments lies on the edge of both their `Gf`s, where rounding in `y - py` could put it
    just outside each (docs/decisions.md, "Goals on segment boundaries").
    """
    y_rel, zr, ydot = z_rel
    v_star = jnp.stack([ydot, safe_sqrt(2.0 * hopper.g * zr)])
    lo, hi = goal_position_bounds(ydot, zr, tmpl, hopper)
    return (goal_velocity_ok(v_star, tmpl, hopper) & (y_rel >= lo - y_tol)
            & (y_rel <= hi + y_tol) & (zr > 0))


def _liftoff_speed_bounds(c, v, tmpl: Templates):
    """Interval of vertical liftoff speed `d` with admissible `(th, k)` from `v` at `ydot* = c`.

    From `k(v, v*) in [k_lo, k_hi]`: with `q_k(d) = |v*|^2 + (k - 1) v.v* - k |v|^2`, the
    conditions are `q_klo(d) >= 0` (a lower bound, the larger root) and `q_khi(d) <= 0`
    (between the roots). From `th in [th_lo, th_hi]`: `-(c - a) / (d - b)` within
    `[tan th_lo, tan th_hi]`, linear in `d`.
    """
    a, b = v
    v2 = a**2 + b**2

    def roots(k):
        p = (k - 1.0) * b
        q = c**2 + (k - 1.0) * a * c - k * v2
        disc = p**2 - 4.0 * q
        r = safe_sqrt(disc)
        return (-p - r) / 2.0, (-p + r) / 2.0, disc >= 0

    _, lo_k, has_lo = roots(tmpl.k_lo)
    hi_lo, hi_hi, has_hi = roots(tmpl.k_hi)
    lo = jnp.where(has_lo, lo_k, 0.0)
    lo = jnp.maximum(lo, jnp.where(has_hi, hi_lo, jnp.inf))
    hi = jnp.where(has_hi, hi_hi, -jnp.inf)
    t_lo, t_hi = jnp.tan(tmpl.th_lo), jnp.tan(tmpl.th_hi)
    # th >= th_lo  <=>  a - c >= t_lo (d - b);  th <= th_hi  <=>  a - c <= t_hi (d - b).
    big = 1e12
    finite_lo = jnp.abs(t_lo) < big
    finite_hi = jnp.abs(t_hi) < big
    bound_lo = b + (a - c) / jnp.where(finite_lo & (t_lo != 0), t_lo, 1.0)
    bound_hi = b + (a - c) / jnp.where(finite_hi & (t_hi != 0), t_hi, 1.0)
    lo = jnp.where(finite_lo & (t_lo < 0), jnp.maximum(lo, bound_lo), lo)
    hi = jnp.where(finite_lo & (t_lo > 0), jnp.minimum(hi, bound_lo), hi)
    hi = jnp.where(finite_lo & (t_lo == 0) & (a < c), -jnp.inf, hi)
    lo = jnp.where(finite_hi & (t_hi > 0), jnp.maximum(lo, bound_hi), lo)
    hi = jnp.where(finite_hi & (t_hi < 0), jnp.minimum(hi, bound_hi), hi)
    hi = jnp.where(finite_hi & (t_hi == 0) & (a > c), -jnp.inf, hi)
    return lo, hi


def goal_height_bounds(ydot, tmpl: Templates, hopper: Hopper):
    """Height interval `[zr_lo, zr_hi]` of `Gf` at apex velocity `ydot` (corrected eqs 45-48).

    The lower bound is the largest, over the domain's extreme touchdown velocities, of the
    smallest reachable liftoff speed; the upper bound the smallest of the largest. Heights
    are `zdot_lo^2 / (2 g)`. An empty interval is returned as `lo > hi`.
    """
    corners, mask = domain_velocity_extremes(tmpl, hopper)
    lo, hi = jax.vmap(_liftoff_speed_bounds, in_axes=(None, 0, None))(ydot, corners, tmpl)
    d_lo = jnp.maximum(jnp.max(jnp.where(mask, lo, 0.0)), 0.0)
    d_hi = jnp.min(jnp.where(mask, hi, jnp.inf))
    empty = (d_hi <= d_lo) | ~jnp.any(mask)
    two_g = 2.0 * hopper.g
    return jnp.where(empty, jnp.inf, d_lo**2 / two_g), jnp.where(empty, -jnp.inf,
                                                                  d_hi**2 / two_g)


def goal_height_bounds_printed(ydot, tmpl: Templates, hopper: Hopper):
    """Eqs 45-48 exactly as printed, for comparison only (they are not used by the planner).

    Eq 46 gives the vertical liftoff speed at touchdown velocity `(ydot_td, zdot_td)` with the
    touchdown angle of eq 45; eq 47 takes `min` over the two domain velocity bounds at the
    highest energy, eq 48 `max` at the lowest, and both divide a speed by `2g`. The printed
    text leaves `k` open: we use `k_lo` for the lower and `k_hi` for the upper bound.
    """
    def zdot_lo(energy, v_td, k):
        zdot_td = -safe_sqrt(2.0 * energy / hopper.m - v_td**2)
        disc = (1 + k) ** 2 * zdot_td**2 - 4.0 * (ydot + k * v_td) * (ydot - v_td)
        x = ((1 + k) * zdot_td + safe_sqrt(disc)) / (2.0 * (ydot + k * v_td))
        return (0.5 * (1 + k) * (2 * x / (1 + x**2) * v_td - (1 - x**2) / (1 + x**2) * zdot_td)
                + 0.5 * (1 - k) * zdot_td)

    z_lo = jnp.minimum(zdot_lo(tmpl.e_hi, tmpl.v_lo, tmpl.k_lo),
                       zdot_lo(tmpl.e_hi, tmpl.v_hi, tmpl.k_lo)) / (2.0 * hopper.g)
    z_hi = jnp.maximum(zdot_lo(tmpl.e_lo, tmpl.v_lo, tmpl.k_hi),
                       zdot_lo(tmpl.e_lo, tmpl.v_hi, tmpl.k_hi)) / (2.0 * hopper.g)
    return z_lo, z_hi


def goal_velocity_range_printed(tmpl: Templates, hopper: Hopper):
    """Eqs 43-44 as printed: the velocity range of `Gf`."""
    s = jnp.sqrt(2.0 * tmpl.e_lo / hopper.m)
    lo = -0.5 * (1 + tmpl.k_hi) * s + 0.5 * (1 - tmpl.k_hi) * tmpl.v_lo
    hi = 0.5 * (1 + tmpl.k_hi) * s + 0.5 * (1 - tmpl.k_hi) * tmpl.v_hi
    return lo, hi


def domain_samples(tmpl: Templates, hopper: Hopper, n: int = 24):
    """A dense sample of `D(Phi)` (relative coordinates), boundaries included.

    Returns `(n * n * 3, 3)` states and a validity mask: `ydot` on a grid over `RV`, `zr` on
    a grid over the admissible heights at that `ydot` (down to the `zr = 0` closure), touchdown
    at `-l, 0, l`.
    """
    ydot = jnp.linspace(tmpl.v_lo, tmpl.v_hi, n)
    zlo, zhi = domain_height_bounds(ydot, tmpl, hopper)
    frac = jnp.linspace(0.0, 1.0, n)
    zr = zlo[:, None] + frac[None, :] * (zhi - zlo)[:, None]
    valid = jnp.broadcast_to((zhi >= zlo)[:, None], zr.shape)
    y_td = jnp.array([-1.0, 0.0, 1.0]) * tmpl.half_length
    yd = jnp.broadcast_to(ydot[:, None, None], (n, n, 3))
    zz = jnp.broadcast_to(zr[:, :, None], (n, n, 3))
    yy = y_td[None, None, :] - yd * safe_sqrt(2.0 * jnp.maximum(zz, 0.0) / hopper.g)
    states = jnp.stack([yy, zz, yd], axis=-1).reshape(-1, 3)
    return states, jnp.broadcast_to(valid[:, :, None], (n, n, 3)).reshape(-1)


def feasible_goal_contains_brute(z_rel, tmpl: Templates, hopper: Hopper, n: int = 24,
                                 with_extremes: bool = False):
    """`Z' in Gf(Phi)` by the definition (eq 6): reachable from every sampled domain state.

    Each sampled domain state is inverted with the BHop deadbeat (eqs 25-29) and its controls
    are checked against the template's limits. With `with_extremes`, the domain's extreme
    touchdown velocities (`domain_velocity_extremes`) join the sample.
    """
    from .._models.bhop import deadbeat_bhop

    states, valid = domain_samples(tmpl, hopper, n)
    if with_extremes:
        v, mask = domain_velocity_extremes(tmpl, hopper)
        zr = v[:, 1] ** 2 / (2.0 * hopper.g)
        t_d = jnp.abs(v[:, 1]) / hopper.g
        l = tmpl.half_length
        extra = jnp.concatenate([jnp.stack([y - v[:, 0] * t_d, zr, v[:, 0]], 1)
                                 for y in (-l, 0.0, l)])
        states = jnp.concatenate([states, extra])
        valid = jnp.concatenate([valid, mask, mask, mask])
    # h = -rho0 makes world heights equal heights above the virtual ground.
    u = jax.vmap(deadbeat_bhop, in_axes=(0, None, None, None))(states, z_rel, -hopper.rho0,
                                                                hopper)
    lo = jnp.stack([tmpl.dy_lo, tmpl.th_lo, tmpl.k_lo])
    hi = jnp.stack([tmpl.dy_hi, tmpl.th_hi, tmpl.k_hi])
    ok = jnp.all((u >= lo - 1e-12) & (u <= hi + 1e-12), axis=1)
    return jnp.all(ok | ~valid) & jnp.any(valid) & (z_rel[1] > 0)
