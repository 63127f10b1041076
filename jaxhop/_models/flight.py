"""Flight over the terrain: touchdown, stance clearance and failures (sections IV-B and VI-C).

Pure functions of one state; the terrain's blocks are vectorised inside. Time runs from the
start of each ballistic arc. A point follows `p(t) = p0 + v t + a t^2 / 2` horizontally
(`a`: wind) and `z(t) = z0 + zdot0 t - g t^2 / 2` vertically.
"""

import jax
import jax.numpy as jnp

from .._core.params import Hopper
from .._core.result import FAILURE_NAMES as FAILURE_NAMES
from .._core.result import RESULT_NAMES as RESULT_NAMES
from .._core.result import Result
from .._core.terrain import Terrain
from .bhop import safe_sqrt

# Stride outcomes as used here (a completed stride is `OK`); see `Result`.
OK = SUCCESS = Result.SUCCESS
COLLISION = Result.COLLISION
HOLE = Result.HOLE
OFF_MAP = Result.OFF_MAP
OUTSIDE_DOMAIN = Result.OUTSIDE_DOMAIN
MAX_STEPS = Result.MAX_STEPS
SOLVER = Result.SOLVER
RUNNING = Result.RUNNING

_INF = jnp.inf
#: Slack (m) around the paths in `touchdown`'s window.
REACH_PAD = 1e-9


def flight_crossings(p0, v, a, w):
    """Both times `t >= 0` with `p0 + v t + a t^2 / 2 = w` (`inf` where none)."""
    c = p0 - w
    lin = jnp.abs(a) < 1e-12
    t_lin = jnp.where(v != 0, -c / jnp.where(v != 0, v, 1.0), _INF)
    disc = v**2 - 2.0 * a * c
    root = safe_sqrt(disc)
    # Stable quadratic roots: q = -(v + sign(v) root), t1 = q / a, t2 = 2c / q.
    q = -(v + jnp.where(v >= 0, 1.0, -1.0) * root)
    a_safe = jnp.where(lin, 1.0, a)
    q_safe = jnp.where(q != 0, q, 1.0)
    t1 = jnp.where(q != 0, q / a_safe, -v / a_safe)
    t2 = jnp.where(q != 0, 2.0 * c / q_safe, -v / a_safe)
    real = disc >= 0
    t1 = jnp.where(real & (t1 >= 0), t1, _INF)
    t2 = jnp.where(real & (t2 >= 0), t2, _INF)
    lo, hi = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
    lo = jnp.where(lin, jnp.where(t_lin >= 0, t_lin, _INF), lo)
    hi = jnp.where(lin, _INF, hi)
    return lo, hi


def _time_at_height(z0, zdot0, g, height):
    """Later time at which a falling arc is at `height` (`inf` if it never is)."""
    disc = zdot0**2 + 2.0 * g * (z0 - height)
    return jnp.where(disc >= 0, (zdot0 + safe_sqrt(disc)) / g, _INF)


def flight_position(p0, v, a, t):
    return p0 + v * t + 0.5 * a * t**2


def _wall_hits(y0, vy, a, z0, zdot0, g, terrain: Terrain):
    """Earliest time the point crosses a block's side wall below its top (per block)."""
    def per_wall(w):
        t1, t2 = flight_crossings(y0, vy, a, w)
        z1 = flight_position(z0, zdot0, -g, jnp.where(jnp.isfinite(t1), t1, 0.0))
        z2 = flight_position(z0, zdot0, -g, jnp.where(jnp.isfinite(t2), t2, 0.0))
        below1, below2 = z1 < terrain.heights, z2 < terrain.heights
        return jnp.minimum(jnp.where(below1, t1, _INF), jnp.where(below2, t2, _INF))
    return jnp.minimum(per_wall(terrain.starts), per_wall(terrain.ends))


def _inside(y, z, terrain: Terrain):
    """Whether the point is strictly inside the solid part of a block."""
    return jnp.any((y > terrain.starts) & (y < terrain.ends) & (z < terrain.heights))


def reach_interval(y, fy, ydot, wind, t_end):
    """`(lo, hi)`: the horizontal extent of the COM's (from `y`) and the foot's (from `fy`)
    paths over the times `[0, t_end]` (`t_end`: the fall to the hole depth)."""
    t_vertex = jnp.clip(jnp.where(wind != 0, -ydot / jnp.where(wind != 0, wind, 1.0), 0.0),
                        0.0, t_end)
    drift = jnp.stack([0.0 * ydot, flight_position(0.0, ydot, wind, t_end),
                       flight_position(0.0, ydot, wind, t_vertex)])
    return (jnp.minimum(y, fy) + jnp.min(drift), jnp.maximum(y, fy) + jnp.max(drift))


def blocks_in_reach(lo, hi, terrain: Terrain, width: int):
    """The `width` consecutive blocks from the first one that ends at or after `lo` (moved
    back where fewer than `width` remain), as a terrain, and the index of its first block.

    Blocks are sorted and do not overlap, so every block that meets `[lo, hi]` lies in it
    when at most `width` do."""
    n = terrain.n_blocks
    first = jnp.clip(jnp.searchsorted(terrain.ends, lo, side="left"), 0, n - width)

    def cut(a):
        return jax.lax.dynamic_slice(a, (first,), (width,))

    return Terrain(cut(terrain.starts), cut(terrain.ends), cut(terrain.heights)), first


def touchdown(apex, foot_offset, terrain: Terrain, hopper: Hopper, wind=0.0, window=None):
    """First contact of the descending foot with the terrain.

    The foot rides at `COM + foot_offset` from apex (BHop: `(0, -rho0)`). Touchdown is the
    first time the foot reaches the top of a block while above it; before it, a crossing of a
    side wall below its top by the foot or the COM is a `COLLISION`, a foot more than `rho0`
    below the lowest block top is in a `HOLE`, a foot outside the terrain's y range is
    `OFF_MAP`.

    `window` (static): test only that many consecutive blocks, those around the paths of
    the foot and the COM until the foot falls to the hole depth (`reach_interval`,
    `blocks_in_reach`). Every block that can decide the outcome lies on those paths, so the
    result is the same, bit for bit, whenever at most `window` blocks meet them
    (`jaxhop._planning.policies.landing_window` sizes it).

    Returns:
        `(code, block, t, y_foot, v_td)`: `code` is `OK` on touchdown on block `block` at time
        `t` with the foot at `y_foot` and COM velocity `v_td`.
    """
    y, z, ydot = apex
    g = hopper.g
    fy, fz = y + foot_offset[0], z + foot_offset[1]
    y_min, y_max = terrain.starts[0], terrain.ends[-1]
    t_hole = _time_at_height(fz, 0.0, g, jnp.min(terrain.heights) - hopper.rho0)
    if window is not None:
        lo, hi = reach_interval(y, fy, ydot, wind, t_hole)
        terrain, offset = blocks_in_reach(lo - REACH_PAD, hi + REACH_PAD, terrain, window)
    t_top = _time_at_height(fz, 0.0, g, terrain.heights)
    y_at_top = flight_position(fy, ydot, wind, jnp.where(jnp.isfinite(t_top), t_top, 0.0))
    on_top = jnp.isfinite(t_top) & (y_at_top >= terrain.starts) & (y_at_top <= terrain.ends)
    t_top = jnp.where(on_top, t_top, _INF)
    block = jnp.argmin(t_top)
    t_td = t_top[block]
    if window is not None:
        # The whole terrain's `argmin`: the first block of the earliest top, 0 if none.
        block = jnp.where(jnp.isfinite(t_td), offset + block, 0)

    t_wall = jnp.minimum(jnp.min(_wall_hits(fy, ydot, wind, fz, 0.0, g, terrain)),
                         jnp.min(_wall_hits(y, ydot, wind, z, 0.0, g, terrain)))
    # The COM meeting a block top before the foot does is a body-ground collision.
    t_com = _time_at_height(z, 0.0, g, terrain.heights)
    y_com = flight_position(y, ydot, wind, jnp.where(jnp.isfinite(t_com), t_com, 0.0))
    t_com = jnp.min(jnp.where((y_com > terrain.starts) & (y_com < terrain.ends), t_com, _INF))
    inside = _inside(fy, fz, terrain) | _inside(y, z, terrain)
    t_collide = jnp.where(inside, 0.0, jnp.minimum(t_wall, t_com))

    t_off = jnp.minimum(jnp.min(jnp.stack(flight_crossings(fy, ydot, wind, y_min))),
                        jnp.min(jnp.stack(flight_crossings(fy, ydot, wind, y_max))))
    t_off = jnp.where((fy < y_min) | (fy > y_max), 0.0, t_off)

    times = jnp.stack([t_td, t_collide, t_hole, t_off])
    codes = jnp.array([OK, COLLISION, HOLE, OFF_MAP])
    # Ties go to the earlier entry: touchdown, then collision.
    first = jnp.argmin(times)
    t = times[first]
    t_safe = jnp.where(jnp.isfinite(t), t, 0.0)
    v_td = jnp.stack([ydot + wind * t_safe, -g * t_safe])
    return codes[first], block, t_safe, flight_position(fy, ydot, wind, t_safe), v_td


def liftoff_clear(y_td, y_lo, v_lo, h, terrain: Terrain, hopper: Hopper, wind=0.0):
    """Whether the COM clears the terrain from touchdown to the next apex.

    In stance the COM sweeps horizontally from `y_td` to `y_lo` at height `h + rho0`; it then
    rises ballistically with the leg retracted. Any block whose solid part it enters is a
    collision; a liftoff with `zdot <= 0` cannot leave the ground and is one too.
    """
    z_lo = h + hopper.rho0
    lo, hi = jnp.minimum(y_td, y_lo), jnp.maximum(y_td, y_lo)
    sweep = jnp.any((terrain.heights > z_lo) & (terrain.starts < hi) & (terrain.ends > lo))
    t_up = jnp.maximum(v_lo[1], 0.0) / hopper.g

    def wall_hit(w):
        t1, t2 = flight_crossings(y_lo, v_lo[0], wind, w)
        z1 = flight_position(z_lo, v_lo[1], -hopper.g, jnp.where(jnp.isfinite(t1), t1, 0.0))
        z2 = flight_position(z_lo, v_lo[1], -hopper.g, jnp.where(jnp.isfinite(t2), t2, 0.0))
        return (((t1 <= t_up) & (z1 < terrain.heights))
                | ((t2 <= t_up) & (z2 < terrain.heights)))

    rise = jnp.any(wall_hit(terrain.starts) | wall_hit(terrain.ends))
    return ~(sweep | rise | (v_lo[1] <= 0))
