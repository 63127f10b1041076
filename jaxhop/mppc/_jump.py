"""Minimum-time feasible jump between two contact points, for one pair, in JAX.

For a takeoff contact `(x0, z0)`, a landing contact `(x1, z1)` and a takeoff angle
`theta`, eqs 6-9 fix the flight: with `T = tan(theta)`, `X = x1 - x0 + rf cos theta_f`
and `Z = z1 - z0 + rf sin theta_f`, `g t^2 / 2 = X T - Z` and
`v = (X - rt cos theta) / (t cos theta)`, and the hip passes `x = x_h` at height
`z0 + T (x_h - x0) - rho^2 (X T - Z)` with `rho = (x_h - x0 - rt cos theta) /
(X - rt cos theta)`, the fraction of its horizontal travel (foot and knee are the hip
plus constant flight-configuration offsets). The flight time grows with `theta`, so the
minimum-time jump is the one with the smallest feasible angle. The constraints split
into those a higher arc helps (face clearances, `v >= v_min` above the angle of least
speed, `t >= t_min`, the hip moving forward, no body point starting inside a block) and
those it hurts (`theta <= theta_max`, `t <= t_max`, `v <= v_max`). The search starts at
the smallest angle meeting the obstacle-free lower bounds (`v >= v_min` by bisection in
`tan(theta)`, `N_SPEED` halvings), then takes `N_ITER` Newton steps, each raising the
angle to the largest of the linearised thresholds of the violated clearances. The result
is verified exactly: a pair that cannot be certified is reported infeasible, never the
other way round. Against a dense angle scan the flight time is exact to ~1e-4 s for 98 %
of pairs, and a rare Newton overshoot costs about 0.01 s at most
(`tests/test_mppc_plan.py`).

Wind (`wind=a`, a constant horizontal acceleration in flight; `None`: still air, the
code above exactly): the vertical motion is unchanged and the horizontal one gains
`a tau^2 / 2`, so `t^2 = 2 (X T - Z) / (g + a T)`, the wind moves the hip by
`b = a t^2 / 2` over the flight, `v = (X - rt cos theta - b) / (t cos theta)`, and the
hip passes `x = x_h` at the fraction `sigma` of the flight time that solves
`b sigma^2 + (W - b) sigma = x_h - x_hip0` (`W = X - rt cos theta`), at height
`z0 + rt sin theta + T (W - b) sigma - (X T - Z - b T) sigma^2`. The Newton steps take
the slope of that height in `T` by forward-mode differentiation. The hip must move
forward during the whole flight (`W - b > 0` and `W + b > 0`).
"""

import math

import jax
import jax.numpy as jnp

from ._robot import Robot

N_ITER = 4
N_SPEED = 12
Z_SLACK = 1e-8  # clearances are targeted this far above their bound


def _hip_height_at(x0, z0, tan, c, rt, xp, zp, xh):
    # Hip height where the hip passes x = xh (module docstring).
    rho = (xh - x0 - rt * c) / (xp - rt * c)
    return z0 + tan * (xh - x0) - rho**2 * (xp * tan - zp)


def _queries(robot: Robot, front, back, height, margin_v, room=None):
    # Four clearance queries per block, in hip coordinates: (x where the hip passes, hip
    # height needed). Foot over the front and knee over the back keep the margin (eq 14);
    # foot over the back and knee over the front must only not enter the block. The last
    # group (knee over the front) is implied by the others and a legal touchdown (the foot
    # path is concave), so the search skips it; the final verification keeps it.
    # With `room` (blocks `front, back` already widened by it): the foot keeps the margin
    # over the whole band `[front - room, front + room]` and the knee over `[back - room,
    # back + room]` (two queries each: the paths are concave), so that a flight shifted
    # by up to `room` still keeps it.
    fx, fz = robot.foot_from_hip
    kx, kz = robot.knee_from_hip
    if room is None:
        xh = jnp.concatenate([front - fx, back - fx, back - kx, front - kx])
        zh = jnp.concatenate(
            [height + margin_v - fz, height - fz, height + margin_v - kz, height - kz]
        )
        return xh, zh
    top = height + margin_v
    xh = jnp.concatenate([front - fx, front + 2 * room - fx, back - fx, back - kx,
                          back - 2 * room - kx, front - kx])
    zh = jnp.concatenate([top - fz, top - fz, height - fz, top - kz, top - kz, height - kz])
    return xh, zh


def _start_inside(robot, x0, z0, c, s, front, back, height):
    # Does the foot or knee start its flight inside a block?
    out = jnp.zeros(front.shape, bool)
    for ox, oz in (robot.foot_from_hip, robot.knee_from_hip):
        bx = x0 + robot.r_takeoff * c + ox
        bz = z0 + robot.r_takeoff * s + oz
        out = out | ((bx > front) & (bx < back) & (bz < height))
    return out


def min_time_jump(robot: Robot, start, end, blocks, margin_v, wind=None, room=None):
    """The minimum-flight-time feasible jump from one contact point to another.

    Constraints: eq 5 bounds on `v`, `theta`, `t`; ballistic flight (eqs 6-9) with the
    eqs 1-4 offsets; foot over every block front and knee over every block back it
    passes at least `margin_v` above the top; neither foot nor knee inside a block at
    any time of the flight. Landing legality (surface height, edge margins, restricted
    areas, knee at touchdown) is a property of the landing point, checked by the caller.

    **Arguments:**
    - `robot`: the leg.
    - `start = (x0, z0)`: takeoff contact point; `end = (x1, z1)`: landing contact point
      (scalars).
    - `blocks = (front, back, height)`: the blocks to respect (padding: far ahead).
    - `margin_v`: vertical clearance margin.
    - `wind`: horizontal acceleration during the flight (m/s^2, scalar); `None` (the
      default) for still air. The jump lands on `(x1, z1)` when flown with this wind.
    - `room`: horizontal room (m, scalar; `None`: none): every block is widened by it on
      both sides, and the foot keeps `margin_v` above the top over `[front - room,
      front + room]`, the knee over `[back - room, back + room]`, so that the same
      flight shifted by up to `room` either way is still feasible.

    **Returns:** `(ok, t, v, theta)`: feasibility and the minimum-time jump.
    """
    (x0, z0), (x1, z1), (front, back, height) = start, end, blocks
    ok, t, v, tan = min_time_jump_tan(robot, x0, z0, x1, z1, front, back, height, margin_v,
                                      wind, room)
    return ok, t, v, jnp.arctan(tan)


def min_time_jump_tan(robot: Robot, x0, z0, x1, z1, front, back, height, margin_v,
                      wind=None, room=None):
    # As `min_time_jump`, with tan(theta) in place of theta (arctan is slow on the CPU, and
    # a plan needs it for a handful of jumps only).
    fx, fz = robot.foot_from_hip
    xp = x1 - fx - x0
    zp = z1 - fz - z0
    if room is not None:
        front, back = front - room, back + room
    xh, zh = _queries(robot, front, back, height, margin_v, room)
    obstacles = (front, back, height)
    tan = _first_angle(robot, xp, zp, wind)
    escape = _escape_angles(robot, x0, z0, obstacles)
    for _ in range(N_ITER):
        tan = _raise(robot, x0, z0, xp, zp, xh, zh, obstacles, escape, tan, wind)
    return _verify(robot, x0, z0, xp, zp, xh, zh, obstacles, tan, wind)


def _first_angle(robot, xp, zp, wind=None):
    # Smallest tan(theta) meeting the obstacle-free lower bounds: t >= t_min, the hip
    # moving forward, and v >= v_min (bisection: above the angle of least speed, v grows).
    # With wind, t >= t_min reads T (X - a t_min^2 / 2) >= g t_min^2 / 2 + Z.
    rt, g = robot.r_takeoff, robot.g
    reach = xp if wind is None else xp - wind * robot.t_min**2 / 2
    tan = jnp.maximum(math.tan(robot.theta_min), (g * robot.t_min**2 / 2 + zp) / reach)
    ratio = jnp.clip(rt / jnp.maximum(xp, 1e-12), 1.0, 1e6)
    tan = jnp.maximum(tan, jnp.sqrt(ratio**2 - 1.0) * (1 + 1e-9))
    slow = _flight(robot, xp, zp, tan, wind)[3] < robot.v_min
    # Bisect in tan(theta) itself: transcendental functions are slow on the CPU.
    a, b = tan, jnp.full_like(tan, math.tan(robot.theta_max))
    for _ in range(N_SPEED):
        mid = 0.5 * (a + b)
        fast = _flight(robot, xp, zp, mid, wind)[3] >= robot.v_min
        a, b = jnp.where(fast, a, mid), jnp.where(fast, mid, b)
    return jnp.where(slow, b, tan)


def _escape_angles(robot, x0, z0, obstacles):
    # For each body point (foot, knee) and block: the smallest tan(theta) that takes the
    # point's flight start out of the block, either back behind its front (smaller
    # cos theta) or above its top (larger sin theta).
    rt = robot.r_takeoff
    front, back, height = obstacles
    out = []
    for ox, oz in (robot.foot_from_hip, robot.knee_from_hip):
        c_req = (front - x0 - ox) / rt
        t_c = jnp.where(c_req > 0, jnp.sqrt(1.0 / jnp.clip(c_req, 1e-12, 1.0) ** 2 - 1.0),
                        jnp.inf)
        s_req = jnp.clip((height - z0 - oz) / rt, 0.0, 1.0 - 1e-12)
        t_s = jnp.where((height - z0 - oz) / rt < 1.0, s_req / jnp.sqrt(1.0 - s_req**2),
                        jnp.inf)
        out.append(jnp.minimum(t_c, t_s) * (1 + 1e-12))
    return out


def _raise(robot, x0, z0, xp, zp, xh, zh, obstacles, escape, tan, wind=None):
    # One Newton step towards the smallest angle that clears every query (the hip height
    # where it passes a face, as a function of T) and lifts every body point out of the
    # blocks it would start in. Only ever raises the angle.
    if wind is not None:
        return _raise_wind(robot, x0, z0, xp, zp, xh, zh, obstacles, escape, tan, wind)
    rt = robot.r_takeoff
    c = 1.0 / jnp.sqrt(1.0 + tan**2)
    hip_x0 = x0 + rt * c
    inv_dx = 1.0 / (xp - rt * c)
    lift = xp * tan - zp
    dfac = 2 * rt * tan * c**3 * inv_dx**2 * lift
    new = tan
    for q in range(xh.shape[0] - obstacles[0].shape[0]):  # all but knee over the front
        rho = (xh[q] - hip_x0) * inv_dx
        cross = (xh[q] > hip_x0) & (xh[q] < x0 + xp)
        gap = zh[q] + Z_SLACK - (z0 + tan * (xh[q] - x0) - rho**2 * lift)
        slope = (xh[q] - x0) - rho**2 * xp - rho * (xp - (xh[q] - x0)) * dfac
        step = jnp.where(slope > 0, gap / jnp.where(slope > 0, slope, 1.0), jnp.inf)
        new = jnp.where(cross & (gap > 0), jnp.maximum(new, tan + step), new)
    return _escape(robot, x0, z0, obstacles, escape, tan, new)


def _raise_wind(robot, x0, z0, xp, zp, xh, zh, obstacles, escape, tan, wind):
    # `_raise` in wind: the same step, with the height's slope in T by forward mode.
    n = xh.shape[0] - obstacles[0].shape[0]

    def heights(T):
        cross, z_at = _face_heights_wind(robot, x0, z0, xp, zp, xh[:n], T, wind)
        return z_at, cross

    z_at, slope, cross = jax.jvp(heights, (tan,), (jnp.ones_like(tan),), has_aux=True)
    gap = zh[:n] + Z_SLACK - z_at
    step = jnp.where(slope > 0, gap / jnp.where(slope > 0, slope, 1.0), jnp.inf)
    new = jnp.maximum(tan, jnp.max(jnp.where(cross & (gap > 0), tan + step, tan)))
    return _escape(robot, x0, z0, obstacles, escape, tan, new)


def _face_heights_wind(robot, x0, z0, xp, zp, xh, tan, wind):
    # Where the hip passes x = xh in wind (module docstring): (crosses, hip height there).
    rt = robot.r_takeoff
    c = 1.0 / jnp.sqrt(1.0 + tan**2)
    lift = xp * tan - zp
    b = wind * lift / (robot.g + wind * tan)
    w = xp - rt * c
    d = xh - (x0 + rt * c)
    root = jnp.sqrt(jnp.maximum((w - b) ** 2 + 4 * b * d, 0.0))
    den = (w - b) + root
    sigma = 2 * d / jnp.where(den > 0, den, 1.0)
    z_at = z0 + rt * tan * c + tan * (w - b) * sigma - (lift - b * tan) * sigma**2
    cross = (d > 0) & (xh < x0 + xp)
    return cross, z_at


def _escape(robot, x0, z0, obstacles, escape, tan, new):
    # Lift every body point out of the blocks it would start its flight in.
    rt = robot.r_takeoff
    c = 1.0 / jnp.sqrt(1.0 + tan**2)
    s = tan * c
    front, back, height = obstacles
    for (ox, oz), bound in zip((robot.foot_from_hip, robot.knee_from_hip), escape):
        bx = x0 + rt * c + ox
        bz = z0 + rt * s + oz
        for k in range(front.shape[0]):
            inside = (bx > front[k]) & (bx < back[k]) & (bz < height[k])
            new = jnp.where(inside, jnp.maximum(new, bound[k]), new)
    return jnp.where(jnp.isfinite(new), new, math.tan(robot.theta_max) * 2)


def _flight(robot, xp, zp, tan, wind=None):
    c = 1.0 / jnp.sqrt(1.0 + tan**2)
    if wind is None:
        t2 = 2 * (xp * tan - zp) / robot.g
        t = jnp.sqrt(jnp.maximum(t2, 1e-300))
        v = (xp - robot.r_takeoff * c) / (t * c)
        return c, t2, t, v
    t2 = 2 * (xp * tan - zp) / (robot.g + wind * tan)
    t = jnp.sqrt(jnp.maximum(t2, 1e-300))
    v = (xp - robot.r_takeoff * c - wind * t2 / 2) / (t * c)
    return c, t2, t, v


def _lower_kind(robot, x0, z0, xp, zp, xh, zh, obstacles, tan, slack=Z_SLACK, wind=None):
    # The constraints that a higher arc (larger theta) helps. Written as an unrolled loop
    # over the (few) queries so that, batched, everything fuses into one elementwise pass.
    rt = robot.r_takeoff
    c, t2, t, v = _flight(robot, xp, zp, tan, wind)
    ok = (
        (xp - rt * c > 0)
        & (t2 > 0)
        & (t >= robot.t_min * (1 - 1e-12))
        & (v >= robot.v_min * (1 - 1e-9))
    )
    if wind is not None:
        b = wind * t2 / 2  # the wind's share of the hip's travel: forward all the way
        cross, z_at = _face_heights_wind(robot, x0, z0, xp, zp, xh, tan, wind)
        ok = (ok & (xp - rt * c - b > 0) & (xp - rt * c + b > 0)
              & (robot.g + wind * tan > 0)
              & jnp.all(~cross | (z_at >= zh + slack)))
        return ok & _no_start_inside(robot, x0, c, tan * c, z0, obstacles)
    hip_x0 = x0 + rt * c
    lift = xp * tan - zp
    dx = xp - rt * c
    for q in range(xh.shape[0]):
        rho = (xh[q] - hip_x0) / dx
        cross = (xh[q] > hip_x0) & (xh[q] < x0 + xp)
        z_at = z0 + tan * (xh[q] - x0) - rho**2 * lift
        ok = ok & (~cross | (z_at >= zh[q] + slack))
    return ok & _no_start_inside(robot, x0, c, tan * c, z0, obstacles)


def _no_start_inside(robot, x0, c, s, z0, obstacles):
    # Neither foot nor knee starts its flight inside a block.
    rt = robot.r_takeoff
    front, back, height = obstacles
    ok = True
    for ox, oz in (robot.foot_from_hip, robot.knee_from_hip):
        bx = x0 + rt * c + ox
        bz = z0 + rt * s + oz
        for k in range(front.shape[0]):
            ok = ok & ~((bx > front[k]) & (bx < back[k]) & (bz < height[k]))
    return ok


def _verify(robot, x0, z0, xp, zp, xh, zh, obstacles, tan, wind=None):
    c, t2, t, v = _flight(robot, xp, zp, tan, wind)
    ok = (
        (xp > 0)
        & _lower_kind(robot, x0, z0, xp, zp, xh, zh, obstacles, tan, slack=0.0, wind=wind)
        & (tan <= math.tan(robot.theta_max) * (1 + 1e-12))
        & (t <= robot.t_max)
        & (v <= robot.v_max * (1 + 1e-9))
    )
    return ok, t, v, tan
