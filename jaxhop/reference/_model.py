"""Plain NumPy data and models: hopper, terrain, templates, segments, BHop map, flight.

Everything here mirrors `jaxhop._core.params`, `_terrain`, `_templates`, `_bhop` and `_flight`
operation for operation (same formulas, same order of floating-point operations), so the
twin agrees with the JAX path to the last bits wherever the math libraries do. Functions
that act on apex states take a batch `(n, 3)`; the blocks of the terrain are the last axis.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np

SEGMENT_LENGTH = 0.15

OK = SUCCESS = 0
COLLISION = 1
HOLE = 2
OFF_MAP = 3
OUTSIDE_DOMAIN = 4
MAX_STEPS = 5
SOLVER = 6
RUNNING = -1
FAILURE_NAMES = ("collision", "hole", "off_map", "outside_domain", "max_steps", "solver")

TEMPLATE_FIELDS = ("v_lo", "v_hi", "e_lo", "e_hi", "dy_lo", "dy_hi", "th_lo", "th_hi",
                   "k_lo", "k_hi")

INF = np.inf


@dataclasses.dataclass(frozen=True)
class Hopper:
    """Mass, gravity, leg rest length (SI)."""

    m: float = 80.0
    g: float = 9.81
    rho0: float = 1.0


@dataclasses.dataclass(frozen=True, eq=False)
class Terrain:
    """Blocks `(start, end, height)` as three arrays, plus the default goal."""

    starts: np.ndarray
    ends: np.ndarray
    heights: np.ndarray
    goal: tuple | None = None

    @classmethod
    def from_blocks(cls, blocks, goal=None) -> Terrain:
        arr = np.asarray(blocks, float).reshape(-1, 3)
        return cls(arr[:, 0].copy(), arr[:, 1].copy(), arr[:, 2].copy(),
                   None if goal is None else tuple(float(g) for g in goal))

    @property
    def n_blocks(self) -> int:
        return int(self.starts.size)

    def as_lists(self) -> list[tuple[float, float, float]]:
        if not hasattr(self, "_lists"):
            object.__setattr__(self, "_lists", [
                (float(s), float(e), float(h))
                for s, e, h in zip(self.starts, self.ends, self.heights)])
        return self._lists

    @property
    def y_range(self) -> tuple[float, float]:
        return float(self.starts[0]), float(self.ends[-1])


@dataclasses.dataclass(frozen=True, eq=False)
class Templates:
    """Template rows `(v_lo, v_hi, e_lo, e_hi, dy_lo, dy_hi, th_lo, th_hi, k_lo, k_hi)`."""

    rows: np.ndarray
    seg_length: float = SEGMENT_LENGTH

    @property
    def n(self) -> int:
        return int(self.rows.shape[0])

    @property
    def half_length(self) -> float:
        return 0.5 * self.seg_length

    def col(self, name: str) -> np.ndarray:
        return self.rows[:, TEMPLATE_FIELDS.index(name)]

    def row(self, i: int) -> dict:
        return dict(zip(TEMPLATE_FIELDS, (float(x) for x in self.rows[i])))


def paper_templates(seg_length: float = SEGMENT_LENGTH) -> Templates:
    """The 20 templates of eq 33."""
    rows = []
    for (v_lo, v_hi), (e_lo, e_hi) in itertools.product(
            [(-2.5, -1.0), (-1.0, 0.0), (0.0, 1.0), (1.0, 2.5)],
            [(120, 160), (160, 240), (240, 400), (400, 640), (640, 1120)]):
        if v_hi <= 0:
            dy, th = (-0.25, 0.0), (-math.pi / 2, math.pi / 3)
        else:
            dy, th = (0.0, 0.25), (-math.pi / 3, math.pi / 2)
        rows.append((v_lo, v_hi, e_lo, e_hi, *dy, *th, 0.7, 1.4))
    return Templates(np.asarray(rows, float), seg_length)


@dataclasses.dataclass(frozen=True, eq=False)
class Segments:
    """Segment centres `(n, 2)`, their blocks and `de(p)`."""

    centre: np.ndarray
    block: np.ndarray
    edge_distance: np.ndarray

    @property
    def n(self) -> int:
        return int(self.block.size)


def segments(terrain: Terrain, seg_length: float = SEGMENT_LENGTH) -> Segments:
    """`floor(L / 2l)` segments per block, centred in it (section VI-A)."""
    centres, blocks, edges = [], [], []
    for b in range(terrain.n_blocks):
        s, e, h = float(terrain.starts[b]), float(terrain.ends[b]), float(terrain.heights[b])
        n = int(math.floor((e - s) / seg_length + 1e-9))
        left = s + 0.5 * ((e - s) - n * seg_length)
        for k in range(n):
            y = left + (k + 0.5) * seg_length
            centres.append((y, h))
            blocks.append(b)
            edges.append(min(y - s, e - y))
    return Segments(np.reshape(np.asarray(centres, float), (-1, 2)),
                    np.asarray(blocks, np.int64), np.asarray(edges, float))


# --- BHop model (section IV-B) ------------------------------------------------------------


def safe_sqrt(x):
    x = np.asarray(x, float)
    return np.sqrt(np.where(x > 0, x, 0.0))


def stance(y_td, v_td, u):
    """Stance map (eqs 18-21) for one stride: `v_lo = v_td - (1 + k)(v_td . n) n`."""
    dy, th, k = u
    n0, n1 = -math.sin(th), math.cos(th)
    dot = v_td[0] * n0 + v_td[1] * n1
    return y_td + dy, np.array([v_td[0] - (1.0 + k) * dot * n0, v_td[1] - (1.0 + k) * dot * n1])


def ascent(y_lo, v_lo, h, hopper: Hopper, wind=0.0):
    """Ballistic rise to the next apex (eq 24)."""
    t_up = max(v_lo[1], 0.0) / hopper.g
    return np.array([y_lo + v_lo[0] * t_up + 0.5 * wind * t_up**2,
                     h + hopper.rho0 + 0.5 * hopper.g * t_up**2,
                     v_lo[0] + wind * t_up])


def bhop_apex_map(apex, u, h, hopper: Hopper, wind=0.0):
    """Apex return map over a flat foothold at height `h` (eq 22)."""
    y, z, ydot = apex
    t_d = float(safe_sqrt(2.0 * (z - h - hopper.rho0) / hopper.g))
    y_td = y + ydot * t_d + 0.5 * wind * t_d**2
    y_lo, v_lo = stance(y_td, np.array([ydot + wind * t_d, -hopper.g * t_d]), u)
    return ascent(y_lo, v_lo, h, hopper, wind)


def stance_controls(v_td, v_lo):
    """`(th, k)` taking touchdown velocity `v_td` to liftoff velocity `v_lo` (eqs 28-29).

    Broadcasts over leading axes; the last axis is `(ydot, zdot)`.
    """
    dv0 = v_lo[..., 0] - v_td[..., 0]
    dv1 = v_lo[..., 1] - v_td[..., 1]
    th = np.arctan2(-dv0, dv1)
    th = np.where(th > np.pi / 2, th - np.pi, np.where(th < -np.pi / 2, th + np.pi, th))
    denom = -(v_td[..., 0] * dv0 + v_td[..., 1] * dv1)
    ok = denom > 0
    k = np.where(ok, (dv0 * dv0 + dv1 * dv1) / np.where(ok, denom, 1.0) - 1.0, INF)
    return th, k


def deadbeat_bhop(apex, goal, h, hopper: Hopper):
    """Deadbeat controls `(dy, th, k)` from `apex` to `goal` over a foothold at `h` (eqs 25-29).

    Unclipped; windless model.
    """
    y, z, ydot = (float(a) for a in apex)
    t_d = float(safe_sqrt(2.0 * (z - h - hopper.rho0) / hopper.g))
    y_td = y + ydot * t_d + 0.5 * 0.0 * t_d**2
    v_td = np.array([ydot + 0.0 * t_d, -hopper.g * t_d])
    y_g, z_g, ydot_g = (float(a) for a in goal)
    zdot_lo = float(safe_sqrt(2.0 * hopper.g * (z_g - h - hopper.rho0)))
    y_lo = y_g - ydot_g * zdot_lo / hopper.g
    th, k = stance_controls(v_td, np.array([ydot_g, zdot_lo]))
    return np.array([y_lo - y_td, float(th), float(k)])


# --- flight over the terrain (section IV-B) -----------------------------------------------


def _crossings(p0, v, a, w):
    """Both times `t >= 0` with `p0 + v t + a t^2 / 2 = w` (`inf` where none)."""
    c = p0 - w
    with np.errstate(divide="ignore", invalid="ignore"):
        if abs(a) < 1e-12:
            t_lin = np.where(v != 0, -c / np.where(v != 0, v, 1.0), INF)
            return np.where(t_lin >= 0, t_lin, INF), np.full(np.shape(t_lin), INF)
        disc = v**2 - 2.0 * a * c
        root = safe_sqrt(disc)
        q = -(v + np.where(v >= 0, 1.0, -1.0) * root)
        q_safe = np.where(q != 0, q, 1.0)
        t1 = np.where(q != 0, q / a, -v / a)
        t2 = np.where(q != 0, 2.0 * c / q_safe, -v / a)
    real = disc >= 0
    t1 = np.where(real & (t1 >= 0), t1, INF)
    t2 = np.where(real & (t2 >= 0), t2, INF)
    return np.minimum(t1, t2), np.maximum(t1, t2)


def _time_at_height(z0, zdot0, g, height):
    disc = zdot0**2 + 2.0 * g * (z0 - height)
    return np.where(disc >= 0, (zdot0 + safe_sqrt(disc)) / g, INF)


def _pos(p0, v, a, t):
    return p0 + v * t + 0.5 * a * t**2


def _finite_or_zero(t):
    return np.where(np.isfinite(t), t, 0.0)


def _wall_hits(y0, vy, a, z0, zdot0, g, terrain: Terrain):
    """Earliest crossing of any side wall below its top; `(n, 1)` inputs, `(n,)` output."""
    best = INF
    for walls in (terrain.starts, terrain.ends):
        t1, t2 = _crossings(y0, vy, a, walls)
        below1 = _pos(z0, zdot0, -g, _finite_or_zero(t1)) < terrain.heights
        below2 = _pos(z0, zdot0, -g, _finite_or_zero(t2)) < terrain.heights
        hit = np.minimum(np.where(below1, t1, INF), np.where(below2, t2, INF))
        best = np.minimum(best, hit.min(axis=-1))
    return best


def _inside(y, z, terrain: Terrain):
    return np.any((y > terrain.starts) & (y < terrain.ends) & (z < terrain.heights), axis=-1)


def touchdown(apexes, terrain: Terrain, hopper: Hopper, wind=0.0):
    """First contact of the BHop foot (straight below the COM) for a batch of apexes.

    Arguments:
        apexes: `(n, 3)` apex states.

    Returns:
        `(code, block, t, y_foot, v_td)`, arrays of length `n` (`v_td`: `(n, 2)`).
    """
    apexes = np.asarray(apexes, float)
    y, z, ydot = apexes[:, 0:1], apexes[:, 1:2], apexes[:, 2:3]
    g = hopper.g
    fy, fz = y + 0.0, z + -hopper.rho0
    t_top = _time_at_height(fz, 0.0, g, terrain.heights)
    y_at_top = _pos(fy, ydot, wind, _finite_or_zero(t_top))
    on_top = np.isfinite(t_top) & (y_at_top >= terrain.starts) & (y_at_top <= terrain.ends)
    t_top = np.where(on_top, t_top, INF)
    block = np.argmin(t_top, axis=1)
    t_td = t_top[np.arange(block.size), block]

    t_wall = np.minimum(_wall_hits(fy, ydot, wind, fz, 0.0, g, terrain),
                        _wall_hits(y, ydot, wind, z, 0.0, g, terrain))
    t_com = _time_at_height(z, 0.0, g, terrain.heights)
    y_com = _pos(y, ydot, wind, _finite_or_zero(t_com))
    t_com = np.min(np.where((y_com > terrain.starts) & (y_com < terrain.ends), t_com, INF),
                   axis=1)
    inside = _inside(fy, fz, terrain) | _inside(y, z, terrain)
    t_collide = np.where(inside, 0.0, np.minimum(t_wall, t_com))

    y_min, y_max = terrain.starts[0], terrain.ends[-1]
    fy1, ydot1 = fy[:, 0], ydot[:, 0]
    t_off = np.minimum(np.minimum(*_crossings(fy1, ydot1, wind, y_min)),
                       np.minimum(*_crossings(fy1, ydot1, wind, y_max)))
    t_off = np.where((fy1 < y_min) | (fy1 > y_max), 0.0, t_off)
    t_hole = _time_at_height(fz[:, 0], 0.0, g, np.min(terrain.heights) - hopper.rho0)

    times = np.stack([t_td, t_collide, t_hole, t_off])
    first = np.argmin(times, axis=0)  # ties: touchdown, then collision
    t = times[first, np.arange(first.size)]
    t_safe = _finite_or_zero(t)
    code = np.array([OK, COLLISION, HOLE, OFF_MAP])[first]
    v_td = np.stack([ydot1 + wind * t_safe, -g * t_safe], axis=1)
    return code, block, t_safe, _pos(fy1, ydot1, wind, t_safe), v_td


# --- the same, for one apex: plain floats, a loop over the (few) blocks ------------------------


def crossings_one(p0, v, a, w):
    c = p0 - w
    if abs(a) < 1e-12:
        t_lin = -c / v if v != 0 else INF
        return (t_lin if t_lin >= 0 else INF), INF
    disc = v**2 - 2.0 * a * c
    root = math.sqrt(disc) if disc > 0 else 0.0
    q = -(v + (1.0 if v >= 0 else -1.0) * root)
    t1, t2 = (q / a, 2.0 * c / q) if q != 0 else (-v / a, -v / a)
    real = disc >= 0
    t1 = t1 if real and t1 >= 0 else INF
    t2 = t2 if real and t2 >= 0 else INF
    return min(t1, t2), max(t1, t2)


def _time_at_height1(z0, g, height):
    disc = 0.0 + 2.0 * g * (z0 - height)
    return (0.0 + (math.sqrt(disc) if disc > 0 else 0.0)) / g if disc >= 0 else INF


def position_one(p0, v, a, t):
    return p0 + v * t + 0.5 * a * t**2


def finite_one(t):
    return t if t != INF else 0.0


def touchdown_one(apex, terrain: Terrain, hopper: Hopper, wind=0.0, offset=None):
    """`touchdown` for one apex, as scalar code over the blocks (same operations).

    The foot rides at `COM + offset` (default `(0, -rho0)`, BHop's foot below the COM; the
    SLIP twin passes its touchdown-angle offset), as in `jaxhop._models.flight.touchdown`.
    """
    y, z, ydot = (float(a) for a in apex)
    g = hopper.g
    blocks = terrain.as_lists()
    offset = (0.0, -hopper.rho0) if offset is None else offset
    fy, fz = y + offset[0], z + offset[1]
    t_td, block = INF, 0
    t_wall = t_com = INF
    inside = False
    for b, (s, e, h) in enumerate(blocks):
        t = _time_at_height1(fz, g, h)
        if t != INF and s <= position_one(fy, ydot, wind, t) <= e and t < t_td:
            t_td, block = t, b
        for px, pz in ((fy, fz), (y, z)):  # side walls, for the foot and the COM
            inside = inside or (s < px < e and pz < h)
            for w in (s, e):
                for tc in crossings_one(px, ydot, wind, w):
                    if pz + 0.0 * finite_one(tc) + 0.5 * -g * finite_one(tc) ** 2 < h:
                        t_wall = min(t_wall, tc)
        t = _time_at_height1(z, g, h)
        if s < position_one(y, ydot, wind, finite_one(t)) < e:
            t_com = min(t_com, t)
    t_collide = 0.0 if inside else min(t_wall, t_com)
    y_min, y_max = blocks[0][0], blocks[-1][1]
    t_off = min(*crossings_one(fy, ydot, wind, y_min), *crossings_one(fy, ydot, wind, y_max))
    t_off = 0.0 if (fy < y_min or fy > y_max) else t_off
    t_hole = _time_at_height1(fz, g, min(h for _, _, h in blocks) - hopper.rho0)
    times = (t_td, t_collide, t_hole, t_off)
    first = min(range(4), key=lambda i: times[i])  # ties: the earlier entry
    t_safe = finite_one(times[first])
    v_td = (ydot + wind * t_safe, -g * t_safe)
    return (OK, COLLISION, HOLE, OFF_MAP)[first], block, t_safe, position_one(fy, ydot, wind,
                                                                         t_safe), v_td


def liftoff_clear(y_td, y_lo, v_lo, h, terrain: Terrain, hopper: Hopper, wind=0.0) -> bool:
    """Whether the COM clears the terrain from touchdown to the next apex (one stride)."""
    z_lo = h + hopper.rho0
    lo, hi = min(y_td, y_lo), max(y_td, y_lo)
    t_up = max(v_lo[1], 0.0) / hopper.g
    if v_lo[1] <= 0:
        return False
    for s, e, hb in terrain.as_lists():
        if hb > z_lo and s < hi and e > lo:  # swept into in stance
            return False
        for w in (s, e):
            for t in crossings_one(y_lo, v_lo[0], wind, w):
                if t <= t_up and position_one(z_lo, v_lo[1], -hopper.g, finite_one(t)) < hb:
                    return False
    return True


def bhop_stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0):
    """One stride on the terrain: `(next_apex, code, foothold)` (mirrors `bhop_stride`)."""
    code, block, _, y_foot, v_td = touchdown_one(apex, terrain, hopper, wind)
    h = terrain.as_lists()[block][2]
    y_lo, v_lo = stance(y_foot, v_td, u)
    clear = liftoff_clear(y_foot, y_lo, v_lo, h, terrain, hopper, wind)
    nxt = ascent(y_lo, v_lo, h, hopper, wind)
    if code == OK and not clear:
        code = COLLISION
    return nxt, code, (y_foot, h)
