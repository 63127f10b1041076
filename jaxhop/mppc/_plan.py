"""Receding-horizon MPPC solved exactly over a grid of landing points (docs/mppc.md).

Per replan: landing candidates in the horizon `(x_s, x_t]` (a fixed absolute grid plus
the exact margin and restricted-area boundaries), the minimum-time jump for every pair
of them in one vectorised JAX call, and a min-plus dynamic programme over the number of
jumps that gives the exact minimum-total-time path with `N` jumps for every `N` at once;
optionally a continuous polish of the chosen path (`_polish.py`). A replan can plan for
a known wind (horizontal acceleration in flight) and keep extra horizontal room around
blocks and restricted areas (`room`; docs/mppc.md, "Disturbances").
"""

import math
import weakref
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._core.batching import bucket
from .._core.programs import jit
from ._course import Course, Environment
from ._jump import min_time_jump_tan
from ._polish import polish_path
from ._robot import Robot

N_CAP = 8  # most jumps searched in one horizon (fallbacks only; the rule needs <= 6)
_EPS = 1e-9
_FLAT_MAX = 0.784459  # longest / shortest flat-ground jump of the original code
_FLAT_MIN = 0.305830
TRACES = {"horizon": 0, "table": 0}  # Python-side trace counts, to catch recompilation
BEHIND = 0.15  # the knee starts at most this far behind the takeoff point


@dataclass(frozen=True)
class Settings:
    """Planner settings.

    - `grid`: spacing of the absolute landing grid (m).
    - `lookahead`: the horizon `p` (m).
    - `dead_ends`: when to land only on grid points from which the goal can still be
      reached over the whole course (an exhaustive search per environment, which keeps
      the receding horizon out of dead ends): `"static"` (courses without snapshots:
      the search runs once; a dynamic course changes at nearly every replan and its
      future is unknown anyway), `"always"` or `"never"`.
    - `polish`: move the landing points of the chosen path off the grid by a bounded
      continuous search (`_polish.py`); the grid path is kept unless the polished one is
      feasible and faster.
    - `room_max`, `room_step`: the largest extra horizontal room (m) a replan may be
      asked to keep around blocks and restricted areas, and the step it is rounded up
      to (padded shapes are sized for every step up to `room_max`; 0: no room).
    """

    grid: float = 0.02
    lookahead: float = 2.0
    dead_ends: str = "static"
    polish: bool = False
    room_max: float = 0.0
    room_step: float = 0.0025

    def __post_init__(self):
        if not (0 < self.grid <= 0.1):
            raise ValueError("Settings.grid: must be in (0, 0.1]")
        if self.lookahead <= 0:
            raise ValueError("Settings.lookahead: must be > 0")
        if self.dead_ends not in ("static", "always", "never"):
            raise ValueError("Settings.dead_ends: one of 'static', 'always', 'never'")
        if not (0 <= self.room_max <= 0.2) or not (0 < self.room_step <= 0.05):
            raise ValueError("Settings.room_max: in [0, 0.2]; room_step: in (0, 0.05]")

    def rooms(self) -> np.ndarray:
        """Every room a replan can use: 0 and the steps up to `room_max`."""
        n = math.ceil(self.room_max / self.room_step - 1e-9)
        return np.minimum(np.arange(n + 1) * self.room_step, self.room_max)

    def round_room(self, room: float) -> float:
        """`room` rounded up to the next step, capped at `room_max`."""
        if room <= 0 or self.room_max <= 0:
            return 0.0
        rooms = self.rooms()
        return float(rooms[min(np.searchsorted(rooms, room - 1e-12), len(rooms) - 1)])


def max_reach(robot: Robot, drop: float) -> float:
    """An upper bound on the horizontal length of a jump that descends by `drop`."""
    vx = robot.v_max * math.cos(robot.theta_min)
    vz = robot.v_max * math.sin(robot.theta_max)
    fz = robot.foot_from_hip[1]
    fall = drop + robot.r_takeoff - fz + 0.01
    t = (vz + math.sqrt(vz**2 + 2 * robot.g * fall)) / robot.g
    return robot.r_takeoff + abs(robot.foot_from_hip[0]) + vx * t + 0.02


def landing_ok(robot: Robot, env: Environment, margin_h: float, x, room: float = 0.0):
    """Landing-point legality: margins to edges, restricted areas, knee at touchdown.

    **Arguments:**
    - `robot`, `env`, `margin_h`: the leg, the environment and the horizontal margin.
    - `x`: candidate landing contact points (array).
    - `room`: extra horizontal room: margins `margin_h + room`, restricted areas and
      blocks (for the knee) widened by `room` on both sides.

    **Returns:** boolean array, True where landing at `x` (on the surface) is legal.
    """
    x = np.asarray(x, float)
    z = env.surface(x)
    col = x[:, None]
    mh = margin_h + room
    ok = np.all(np.abs(col - env.front) >= mh - 1e-12, axis=1)
    ok &= np.all(np.abs(col - env.back) >= mh - 1e-12, axis=1)
    ok &= ~np.any((col > env.restricted_lo - room) & (col < env.restricted_hi + room), axis=1)
    kx, kz = robot.knee_from_foot
    knee_x, knee_z = x + kx, z + kz
    inside = (knee_x[:, None] > env.front - room) & (knee_x[:, None] < env.back + room)
    ok &= ~np.any(inside & (knee_z[:, None] < env.height), axis=1)
    return ok


def candidates(env: Environment, course: Course, grid: float, room: float = 0.0) -> np.ndarray:
    """Sorted landing candidates of the whole course: grid, margin and area boundaries
    (with `room`: the boundaries of the widened margins and areas, as in `landing_ok`)."""
    mh = course.margin_h + room
    lo, hi = course.start, course.goal
    pts = [np.arange(math.ceil(lo / grid - 1e-9), math.floor(hi / grid + 1e-9) + 1) * grid]
    pts.append(np.concatenate([env.front - mh, env.front + mh, env.back - mh, env.back + mh]))
    pts.append(np.concatenate([env.restricted_lo - room, env.restricted_hi + room, [lo, hi]]))
    x = np.concatenate(pts)
    x = np.unique(x[(x >= lo - _EPS) & (x <= hi + _EPS)])
    keep = np.concatenate([[True], np.diff(x) > 1e-9])
    return x[keep]


def _band_table(robot, x, z, valid, front, back, height, margin_v, width: int, n_local: int,
                wind=None, room=None):
    # Minimum-time jumps i -> i + 1 + w for w < width: arrays of shape (C, width) of
    # (feasible, t, v, tan theta).
    TRACES["table"] += 1
    n = x.shape[0]
    i = jnp.arange(n)[:, None]
    j = jnp.minimum(i + 1 + jnp.arange(width)[None, :], n - 1)
    pair_ok = valid[i] & valid[j] & (i + 1 + jnp.arange(width)[None, :] < n) & (x[j] > x[i])
    # Each takeoff point only sees the `n_local` blocks from the first one whose back
    # lies less than BEHIND before it (the caller sizes `n_local` to cover a whole jump).
    first = jnp.searchsorted(back if room is None else back + room, x - BEHIND)
    rows = jnp.minimum(first[:, None] + jnp.arange(n_local)[None, :], front.shape[0] - 1)

    def row(x0, z0, x1s, z1s, k):
        def one(x1, z1):
            return min_time_jump_tan(robot, x0, z0, x1, z1, front[k], back[k], height[k],
                                     margin_v, wind, room)

        return jax.vmap(one)(x1s, z1s)

    ok, t, v, th = jax.vmap(row)(x, z, x[j], z[j], rows)
    return ok & pair_ok, t, v, th


_band_table_jit = jit(_band_table, static_argnames=("robot", "width", "n_local"))


@partial(jit, static_argnames=("robot", "width", "n_local"))
def _horizon_solve(robot, x, z, valid, front, back, height, margin_v, width: int,
                   n_local: int, wind=None, room=None):
    # The pair table, then best[n - 1, j]: least total flight time of n jumps from point 0
    # to point j, for n = 1 .. N_CAP (min-plus products along the band).
    TRACES["horizon"] += 1
    ok, t, v, tan = _band_table(robot, x, z, valid, front, back, height, margin_v, width,
                                n_local, wind, room)
    n = x.shape[0]
    # into[j, w]: cost of the jump that lands on j from i = j - 1 - w.
    src = jnp.arange(n)[:, None] - 1 - jnp.arange(width)[None, :]
    cost = jnp.where(ok, t, jnp.inf)
    into = jnp.where(src >= 0, cost[jnp.maximum(src, 0), jnp.arange(width)], jnp.inf)
    src = jnp.maximum(src, 0)
    bests = []
    best = jnp.full(n, jnp.inf).at[0].set(0.0)
    for _ in range(N_CAP):  # unrolled: a handful of small steps fuse better than a scan
        best = jnp.min(best[src] + into, axis=1)
        bests.append(best)
    return cost, v, tan, jnp.stack(bests)


@jit
def _backward_reach(ok, last):
    # Points from which `last` can be reached over the band of feasible jumps `ok`:
    # propagate backwards, one jump per sweep, until nothing changes.
    n, width = ok.shape
    j = jnp.arange(n)[:, None] + 1 + jnp.arange(width)[None, :]
    ok = ok & (j < n)
    j = jnp.minimum(j, n - 1)

    def sweep(carry):
        reach, _ = carry
        new = reach | jnp.any(ok & reach[j], axis=1)
        return new, jnp.any(new != reach)

    reach, _ = jax.lax.while_loop(lambda c: c[1], sweep,
                                  (jnp.zeros(n, bool).at[last].set(True), True))
    return reach


@dataclass
class Jump:
    """One jump: takeoff contact `(xs, zs)`, `v`, `theta` (rad), `t`, landing `(x1, z1)`."""

    xs: float
    zs: float
    v: float
    theta: float
    t: float
    x1: float
    z1: float

    def to_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in ("xs", "zs", "v", "theta", "t", "x1", "z1")}


@dataclass
class Plan:
    """Result of one replan: the planned jumps (first one is executed), `None` if none."""

    jumps: list
    n_jumps: int
    target: float
    fallback: bool
    nodes: list  # contact points of the plan, from the takeoff to the horizon end


def landing_point(robot: Robot, jump_xs, jump_zs, v, theta, t, wind: float = 0.0):
    """Eqs 8-9 with the offsets of eqs 1-2: the landing contact point of a jump (flown in
    a horizontal acceleration `wind`: `x1` gains `wind t^2 / 2`)."""
    fx, fz = robot.foot_from_hip
    x1 = jump_xs + robot.r_takeoff * math.cos(theta) + fx + v * math.cos(theta) * t
    if wind:
        x1 += 0.5 * wind * t**2
    z1 = (jump_zs + robot.r_takeoff * math.sin(theta) + fz + v * math.sin(theta) * t
          - 0.5 * robot.g * t**2)
    return x1, z1


class EnvData:
    """Per-environment data: candidates, heights, legality and goal reachability, for one
    extra room (`Settings.round_room`; the goal stays legal whatever the room)."""

    def __init__(self, planner, course: Course, env: Environment, room: float = 0.0):
        robot, s = planner.robot, planner.settings
        self.env, self.room, self.goal = env, room, course.goal
        # A planner sized for room always passes it (0 included): one compiled solver.
        self.room_arg = room if s.room_max > 0 else None
        self.x = candidates(env, course, s.grid, room)
        self.z = env.surface(self.x)
        self.legal = self.legal_at(robot, course.margin_h, self.x)
        self.reach = np.ones(self.x.shape, bool)
        if s.dead_ends == "always" or (s.dead_ends == "static" and not course.snapshots):
            self.reach = planner.goal_reachable(course, env, self.x, self.z, self.legal,
                                                self.room_arg)

    def legal_at(self, robot, margin_h, x):
        """`landing_ok` with this data's room; the goal is legal if it is without room."""
        x = np.asarray(x, float)
        ok = landing_ok(robot, self.env, margin_h, x, self.room)
        if self.room:
            goal = np.abs(x - self.goal) < _EPS
            ok |= goal & landing_ok(robot, self.env, margin_h, x)
        return ok

    def solver_args(self, wind=None) -> dict:
        """Keyword arguments of the pair solvers for `wind` and this data's room (none for
        still air and no room: the solvers' defaults)."""
        out = {} if wind is None else {"wind": wind}
        if self.room_arg is not None:
            out["room"] = self.room_arg
        return out


class MPPC:
    """Receding-horizon minimum-flight-time parkour planner (exact over a landing grid).

    **Arguments:**
    - `robot`: the leg (default: the paper's, `Robot()`).
    - `settings`: grid spacing, lookahead, dead-end avoidance (`Settings`).
    """

    def __init__(self, robot: Robot | None = None, settings: Settings | None = None):
        self.robot = robot or Robot()
        self.settings = settings or Settings()
        self._size_cache = weakref.WeakKeyDictionary()  # per Course object

    # --- shapes -----------------------------------------------------------------------
    def _sizes(self, course: Course):
        # Padded sizes for the whole run (all snapshots), so that no replan recompiles:
        # window length, band width (jumps per takeoff point), blocks, blocks per jump.
        # With room (`Settings.room_max`): over every room a replan can use.
        if course in self._size_cache:
            return self._size_cache[course]
        s = self.settings
        envs = [course.environment] + [e for _, e in course.snapshots]
        hmax = max([0.0] + [float(e.height.max()) for e in envs if len(e.height)])
        reach = max_reach(self.robot, hmax)
        window, band, k, local = 1, 1, 1, 1
        for e, room in ((e, r) for e in envs for r in s.rooms()):
            x = candidates(e, course, s.grid, room)
            window = max(window, int(np.max(np.searchsorted(x, x + s.lookahead + _EPS,
                                                            side="right") - np.arange(len(x)))))
            band = max(band, int(np.max(np.searchsorted(x, x + reach, side="right")
                                        - np.arange(len(x)))))
            k = max(k, len(e.front))
            front, back = e.front - room, e.back + room
            for b in back:
                local = max(local, int(np.sum((back >= b) & (front < b + BEHIND + reach))))
        sizes = (bucket(window + 2, 16), bucket(band + 1, 8), bucket(k, 4), local)
        self._size_cache[course] = sizes
        return sizes

    @staticmethod
    def _pad_obstacles(front, back, height, size: int):
        pad = size - len(front)
        far = 1e3  # padding blocks lie far ahead, so the sorted order holds
        return (np.concatenate([front, np.full(pad, far)]),
                np.concatenate([back, np.full(pad, far)]),
                np.concatenate([height, np.zeros(pad)]))

    # --- exhaustive search over the whole course ---------------------------------------
    def goal_reachable(self, course, env, x, z, legal, room: float | None = None) -> np.ndarray:
        """Points of the course's landing grid from which the goal can be reached.

        An exhaustive search (no horizon) over all jumps between grid points (blocks
        widened by `room`, as in `min_time_jump`); the start and the goal count as points.
        Returns a boolean array over `x`.
        """
        _, band, ksize, local = self._sizes(course)
        n = bucket(len(x), 64)
        valid = legal.copy()
        valid[0] |= abs(x[0] - course.start) < _EPS
        xp = np.concatenate([x, x[-1] + 10 + np.arange(n - len(x))])
        zp = np.concatenate([z, np.zeros(n - len(x))])
        vp = np.concatenate([valid, np.zeros(n - len(x), bool)])
        obs = self._pad_obstacles(env.front, env.back, env.height, ksize)
        extra = {} if room is None else {"room": room}
        ok = _band_table_jit(self.robot, xp, zp, vp, *obs, course.margin_v, band, local,
                             **extra)[0]
        if not legal[-1]:
            return np.zeros(len(x), bool)
        return np.asarray(_backward_reach(ok, len(x) - 1))[: len(x)]

    # --- one replan ---------------------------------------------------------------------
    def replan(self, course: Course, data: EnvData, x_s: float, z_s: float,
               wind: float | None = None) -> Plan | None:
        """Plan the horizon from contact point `(x_s, z_s)` on the environment of `data`.

        The horizon ends at `x_t = min(x_s + p, goal)` or, where `x_t` is not a legal
        landing point, at the last legal candidate before it. `N` runs from
        `ceil(d / 0.784459)` to `max(floor(d / 0.305830), 1)` and the smallest `N` with a
        solution wins (the original's rule), with its minimum total flight time. If none
        has one, the planner falls back to any `N <= N_CAP` and, failing that, to the
        farthest reachable point of the horizon (`Plan.fallback`). Returns `None` if no
        jump is possible at all. `data.room` widens margins, restricted areas and blocks;
        `wind` (m/s^2, `None`: still air) is the horizontal acceleration the jumps are
        planned for: each lands on its planned point when flown in it.
        """
        s = self.settings
        size, band, ksize, local = self._sizes(course)
        x_t = min(x_s + s.lookahead, course.goal)
        sel = (data.x > x_s + _EPS) & (data.x <= x_t + _EPS) & data.legal & data.reach
        cand_x = data.x[sel]
        cand_z = data.z[sel]
        # x_t itself ends the horizon when it is a legal landing point (it is on the grid
        # only when x_s is); otherwise the last legal candidate before it does.
        if (not len(cand_x) or cand_x[-1] < x_t - _EPS) and data.legal_at(
                self.robot, course.margin_h, [x_t])[0]:
            cand_x = np.append(cand_x, x_t)
            cand_z = np.append(cand_z, data.env.surface(x_t))
        if len(cand_x) == 0:
            return None
        target = len(cand_x)  # index of the horizon end in the window (start is 0)
        m = len(cand_x) + 1
        if m > size:
            raise RuntimeError("landing window larger than its padded size")
        x = np.concatenate([[x_s], cand_x, x_t + 10 + np.arange(size - m)])
        z = np.concatenate([[z_s], cand_z, np.zeros(size - m)])
        valid = np.arange(size) < m
        env = data.env
        near = (env.back > x_s - 0.3) & (env.front < x_t + 0.1)
        obs = self._pad_obstacles(env.front[near], env.back[near], env.height[near], ksize)
        extra = data.solver_args(wind)
        t_arr, v_arr, tan_arr, best = (
            np.asarray(a) for a in _horizon_solve(self.robot, x, z, valid, *obs,
                                                  course.margin_v, band, local, **extra)
        )
        d = x[target] - x_s
        n_min = max(math.ceil(d / _FLAT_MAX - 1e-12), 1)
        n_max = max(math.floor(d / _FLAT_MIN + 1e-12), 1)
        fallback = False
        chosen = next((n for n in range(n_min, n_max + 1)
                       if n <= N_CAP and np.isfinite(best[n - 1, target])), None)
        if chosen is None:
            fallback = True
            chosen = next((n for n in range(1, N_CAP + 1)
                           if np.isfinite(best[n - 1, target])), None)
        if chosen is None:
            finite = np.isfinite(best[:, 1:m])
            if not finite.any():
                return None
            target = 1 + int(np.nonzero(finite.any(axis=0))[0].max())
            chosen = 1 + int(np.nonzero(np.isfinite(best[:, target]))[0].min())
        nodes = _backtrack(best, t_arr, target, chosen)
        w = np.subtract(nodes[1:], nodes[:-1]) - 1
        px, pz = x[nodes], z[nodes]
        pt, pv, ptan = t_arr[nodes[:-1], w], v_arr[nodes[:-1], w], tan_arr[nodes[:-1], w]
        if s.polish:
            out = polish_path(self.robot, course, data, px, pz, obs, extra, s.grid, N_CAP + 1)
            if out is not None and float(np.sum(out[2])) < float(np.sum(pt)):
                px, pz, pt, pv, ptan = out
        jumps = []
        for k in range(len(pt)):
            th, v, t = math.atan(ptan[k]), float(pv[k]), float(pt[k])
            x1, z1 = landing_point(self.robot, px[k], pz[k], v, th, t, wind or 0.0)
            jumps.append(Jump(float(px[k]), float(pz[k]), v, th, t, x1, z1))
        return Plan(jumps, chosen, float(x[target]), fallback, [float(a) for a in px])


def _backtrack(best, cost, target, n_jumps):
    # Nodes of a least-time path of n_jumps jumps from node 0 to target; cost[i, w] is the
    # jump i -> i + 1 + w.
    nodes = [target]
    for n in range(n_jumps - 1, 0, -1):
        j = nodes[-1]
        i = np.arange(max(j - cost.shape[1], 0), j)
        total = best[n - 1, i] + cost[i, j - 1 - i]
        nodes.append(int(i[np.argmin(total)]))
    nodes.append(0)
    return nodes[::-1]
