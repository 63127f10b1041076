"""Continuous polish of a replan's path: its landing points moved off the landing grid.

The DP (`_plan.py`) is exact over the grid; the continuous problem (landing points
anywhere legal) can be slightly faster. With the path's start, end and number of jumps
fixed, each intermediate landing point moves forward within its *legal interval*: the
stretch of the same surface after it, at most one grid step long, with no edge margin,
restricted area or knee-at-touchdown conflict in it (every landing rule forbids an open
interval of `x`, so the legal stretch is an interval). Only forward: a landing point
moved back leaves a longer rest of the course to the next replan, whose smallest-`N`
rule then sometimes takes one jump more (measured: with moves both ways the polished
runs were slower on 55 of 200 random courses). The search is
coordinate-wise (block coordinate descent): the odd landing points move while the even
ones stay, then the reverse, each point to the best of `K` evenly spaced offsets in a
window around it or its current place (so the total never grows); three such sweeps
with the window halved each time (one grid step, a half, a quarter). Every jump is the
same exactly verified minimum-time jump as in the DP (`min_time_jump_tan`); the caller
keeps the grid path unless the polished one is feasible, legal and faster.
"""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._core.programs import jit
from ._jump import min_time_jump_tan

K = 9  # offsets per point and sweep
N_SWEEPS = 3


def legal_end(robot, env, margin_h: float, room: float, x: float, z: float,
              half: float) -> float:
    """The end of the legal stretch after landing point `x` (on the surface `z`), at most
    `half` ahead (and not before `x`).

    Forbidden open intervals: `(e - Mh - room, e + Mh + room)` around every block edge
    `e`, restricted areas widened by `room`, and the landing points that put the knee
    (`knee_from_foot`) inside a block taller than the knee (block widened by `room`);
    a block edge also ends the stretch (another surface).
    """
    m = margin_h + room
    edges = np.concatenate([env.front, env.back])
    kx, kz = robot.knee_from_foot
    tall = env.height > z + kz
    lo_ends = np.concatenate([edges - m, env.restricted_lo - room,
                              env.front[tall] - room - kx, edges])
    right = lo_ends[lo_ends >= x - 1e-12]
    hi = min(x + half, float(right.min())) if right.size else x + half
    return max(hi, x)


def _pair(robot, obs, margin_v, wind, room):
    front, back, height = obs

    def one(x0, z0, x1, z1):
        return min_time_jump_tan(robot, x0, z0, x1, z1, front, back, height, margin_v, wind,
                                 room)

    return jax.vmap(one)


@partial(jit, static_argnames=("robot",))
def _polish(robot, x, z, lo, hi, n, front, back, height, margin_v, half, wind=None,
            room=None):
    # x, z: the path's points padded to N_CAP + 1; n: its number of jumps (traced).
    obs = (front, back, height)
    pair = _pair(robot, obs, margin_v, wind, room)
    p = x.shape[0]
    idx = jnp.arange(p)
    frac = jnp.linspace(-1.0, 1.0, K)

    # One sweep per turn of a loop, so the pair solver is compiled for the two parities
    # only, not for every sweep; each sweep halves the window.
    def sweep(_, carry):
        x, width = carry
        for parity in (1, 0):
            i = idx[1::2] if parity else idx[2::2]
            active = (i >= 1) & (i < n)
            prev, nxt = jnp.maximum(i - 1, 0), jnp.minimum(i + 1, p - 1)
            cand = jnp.clip(x[i][:, None] + width * frac[None, :], lo[i][:, None],
                            hi[i][:, None])
            cand = jnp.concatenate([x[i][:, None], cand], axis=1)  # stay: index 0
            rows, cols = cand.shape
            zi = jnp.broadcast_to(z[i][:, None], cand.shape).ravel()
            ok_a, t_a, _, _ = pair(jnp.repeat(x[prev], cols), jnp.repeat(z[prev], cols),
                                   cand.ravel(), zi)
            ok_b, t_b, _, _ = pair(cand.ravel(), zi, jnp.repeat(x[nxt], cols),
                                   jnp.repeat(z[nxt], cols))
            cost = jnp.where(ok_a & ok_b, t_a + t_b, jnp.inf).reshape(rows, cols)
            best = jnp.argmin(cost, axis=1)
            new = jnp.take_along_axis(cand, best[:, None], axis=1)[:, 0]
            x = x.at[i].set(jnp.where(active, new, x[i]))
        return x, 0.5 * width

    x, _ = jax.lax.fori_loop(0, N_SWEEPS, sweep, (x, jnp.asarray(half, x.dtype)))
    ok, t, v, tan = pair(x[:-1], z[:-1], x[1:], z[1:])
    return x, ok, t, v, tan


def polish_path(robot, course, data, xs, zs, obs, extra: dict, grid: float, size: int):
    """The polished path, or `None` where it is not feasible, legal and faster.

    **Arguments:**
    - `robot`, `course`, `data`: the leg, the course and the replan's `_EnvData`.
    - `xs, zs`: the grid path's contact points (takeoff first, horizon end last).
    - `obs`: the padded blocks the replan used; `extra`: its wind and room arguments of
      the pair solver (`_EnvData.solver_args`).
    - `grid`: the landing grid's spacing (the search window); `size`: padded points.

    **Returns:** `(x, z, t, v, tan)` arrays of the polished path (points and jumps).
    """
    n = len(xs) - 1
    if n < 2:
        return None
    env = data.env
    lo, hi = np.array(xs, float), np.array(xs, float)  # forward only: lo is the grid point
    for k in range(1, n):
        hi[k] = legal_end(robot, env, course.margin_h, data.room, xs[k], zs[k], grid)
    pad = size - len(xs)
    far = xs[-1] + 10 + np.arange(pad)
    xp = np.concatenate([xs, far])
    zp = np.concatenate([zs, np.zeros(pad)])
    lop, hip = np.concatenate([lo, far]), np.concatenate([hi, far])
    args = (xp, zp, lop, hip, n, *obs, course.margin_v, grid)
    out = _polish(robot, *args, **extra)
    x, ok, t, v, tan = (np.asarray(a) for a in out)
    x, z = x[: n + 1], np.asarray(zs, float)
    if not ok[:n].all() or not np.all(np.diff(x) > 0):
        return None
    inner = x[1:n]
    if not (data.legal_at(robot, course.margin_h, inner).all()
            and np.array_equal(env.surface(inner), z[1:n])):
        return None
    return x, z, t[:n], v[:n], tan[:n]
