"""Parkour course -> terrain for the reactive planner (`docs/parkour_reactive.md`).

A course (`docs/mppc.md`, "Course data") is a flat floor at height 0 with cuboid obstacles,
restricted floor areas and margins. The reactive planner of the 2012 paper works on a
piecewise-constant terrain (section III). `course_map` cuts the floor at every obstacle edge, at
every edge +- `Mh` and at every restricted-area boundary, so that each resulting block is
either wholly landable or wholly forbidden:

* obstacles become blocks of their height on the floor;
* restricted areas become floor blocks on which no policy is situated (`allowed = False`),
  and a touchdown strictly inside one is the failure `restricted`;
* the horizontal margin `Mh`: the bands within `Mh` of an obstacle edge (on the floor and
  on the top) are forbidden blocks too; a touchdown inside one is the failure `margin`;
* floors are also cut on an absolute lattice (every `cell` segments, default 8): segments
  are centred in their block (section VI-A), so without it an obstacle appearing in a
  long stretch of floor would shift every segment of that stretch; and (`align=True`,
  the default) a floor block with one end on the lattice has its segments on the
  absolute grid `k 2l` from that end and its slack at the other (`_align`), so that
  moving that other end (an obstacle edge) keeps its segments;
* the vertical margin `Mv`: in the *planner's* map the two `Mh` bands on an obstacle's
  top are raised by `Mv`, so every collision-free region the planner computes keeps the
  foot `Mv` above an obstacle's front and back edges. The simulator uses the true map.
  Both maps have the same blocks (`Terrain.with_heights`), as under ground noise.

The floor reaches `pad` leg lengths beyond start and goal (off the map is `off_map`).
Neither the `Terrain` class nor `touchdown` change: the forbidden blocks are a boolean
per block beside the terrain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._core.params import Hopper
from .._core.result import COURSE_FAILURE_NAMES, Result
from .._core.terrain import SEGMENT_LENGTH, Terrain, make_terrain
from .._planning.templates import REFERENCE_HOPPER
from ..mppc._course import Course, Environment
from ..mppc._robot import Robot

#: Failure codes of a touchdown in a restricted area / margin band, and all course failures.
RESTRICTED = Result.RESTRICTED
MARGIN = Result.MARGIN
PARKOUR_FAILURES = COURSE_FAILURE_NAMES
#: Goal apex height above the virtual ground, in leg lengths (the paper's 1.3 m goal over
#: flat ground for a 1 m leg).
GOAL_ZR = 0.3
#: Floor beyond start and goal, in leg lengths.
PAD = 3.0
#: Lattice of floor cuts, in segments (see `course_map`).
CELL = 8


def _on_lattice(y: float, step: float) -> bool:
    k = round(y / step)
    return abs(y - k * step) < 1e-9


def _align(rows: list, seg: float, step: float) -> list:
    """Landable blocks with one end on the lattice: segments on the grid from that end.

    `segments` centres a block's segments, so a block re-cut at one end (an obstacle, or
    its margin band, moved by a millimetre) would move all of them, and an incremental
    update would have to redo every policy on them. A landable floor block `[a, b]` that
    starts on a lattice cut of `course_map` and ends anywhere else is split at `a + n 2l`
    (`n = floor((b - a) / 2l)`, as many segments as centring gives it) into `n` whole
    segments flush with the lattice cut, hence on the absolute grid `k 2l`, and a rest
    shorter than a segment (no segment, the same surface) at the free end; mirrored for a
    block ending on the lattice. Moving the free end (an obstacle edge) then changes only
    the rest, and the last segment when a grid point is crossed. The uncovered floor is
    the same slack as with centring, all of it at the free end instead of half at each;
    putting the last segment at the free end instead would leave a gap between segments
    in the middle of the floor, which landing noise finds (docs/parkour_reactive.md).
    Blocks with both ends on the lattice hold whole segments already; blocks with neither
    (obstacle tops, floor between two close obstacles) stay centred.
    """
    out = []
    for a, b, h, hp, kind in rows:
        n = math.floor((b - a) / seg + 1e-9)
        la, lb = _on_lattice(a, step), _on_lattice(b, step)
        if kind != 0 or n == 0 or la == lb or n * seg > b - a - 1e-9:
            out.append((a, b, h, hp, kind))
            continue
        cut = round(a + n * seg, 12) if la else round(b - n * seg, 12)
        out += [(a, cut, h, hp, kind), (cut, b, h, hp, kind)]
    return out


def leg_hopper(robot: Robot | None = None, mass: float = 1.0) -> Hopper:
    """The MPPC hopping leg as a BHop: `rho0 = rt` (takeoff extension), the robot's gravity.

    The leg's mass is not given by the MPPC paper; BHop and SLIP strides do not depend on it
    once the templates' energies are scaled with it (Froude scaling), so it is 1 kg.
    """
    robot = robot or Robot()
    return Hopper(m=float(mass), g=float(robot.g), rho0=float(robot.r_takeoff))


@dataclass(frozen=True, eq=False)
class CourseMap:
    """One environment of a course as terrains for the reactive planner.

    Attributes:
        true: the terrain the simulator uses.
        plan: the planner's terrain (same blocks; `Mh` bands on obstacle tops raised `Mv`).
        allowed: `(n_blocks,)` blocks on which policies may be situated.
        kind: `(n_blocks,)` 0 landable, `RESTRICTED` or `MARGIN`.
        goal: the goal apex `(y, z, ydot)`.
    """

    true: Terrain
    plan: Terrain
    allowed: np.ndarray
    kind: np.ndarray
    goal: np.ndarray

    def forbidden_intervals(self) -> np.ndarray:
        """`(n, 3)` rows `(lo, hi, kind)` of the forbidden blocks."""
        b = np.asarray(self.true.blocks())
        sel = self.kind > 0
        return np.column_stack([b[sel, 0], b[sel, 1], self.kind[sel]]).reshape(-1, 3)

    def signature(self) -> list[tuple]:
        """Per block `(start, end, plan height, true height, kind)` (for diffs)."""
        return [(s, e, hp, ht, int(k)) for (s, e, hp), (_, _, ht), k in
                zip(self.plan.blocks(), self.true.blocks(), self.kind)]


def course_map(course: Course, env: Environment | None = None,
               hopper: Hopper | None = None, pad: float = PAD,
               goal_zr: float = GOAL_ZR, cell: int = CELL, align: bool = True) -> CourseMap:
    """Terrains, forbidden blocks and goal apex of one environment of `course`.

    Arguments:
        course: the course (margins, start, goal).
        env: the environment (default: the course's first).
        hopper: the hopper (default: the MPPC leg, `leg_hopper()`): sets the padding and
            the goal apex height.
        pad, goal_zr: floor beyond start/goal and goal height above the virtual ground, in
            leg lengths.
        cell: floor blocks are also cut on an absolute lattice of `cell` segments (0: not).
        align: put the segments of a landable block with one end on the lattice on the
            absolute grid `k 2l` from that end (`_align`): a snapshot then keeps the
            segments away from its changes, and an incremental update redoes less
            (docs/parkour_reactive.md). `False`: every block's segments centred, as
            `segments` cuts any terrain. Needs `cell > 0`.
    """
    env = course.environment if env is None else env
    hopper = leg_hopper() if hopper is None else hopper
    leg = float(hopper.rho0)
    lo, hi = course.start - pad * leg, course.goal + pad * leg
    mh, mv = course.margin_h, course.margin_v
    front, back, height = (np.asarray(a, float) for a in (env.front, env.back, env.height))
    r_lo, r_hi = np.asarray(env.restricted_lo, float), np.asarray(env.restricted_hi, float)
    cuts = np.concatenate([[lo, hi], front, back, front - mh, front + mh, back - mh, back + mh,
                           r_lo, r_hi])
    seg = SEGMENT_LENGTH * leg / REFERENCE_HOPPER[2]
    # An absolute lattice of cuts (every `cell` segments), so that a local change of the
    # course changes only nearby blocks (segments are centred in their block).
    if cell:
        step = cell * seg
        lattice = np.arange(np.ceil(lo / step), np.floor(hi / step) + 1) * step
        cuts = np.concatenate([cuts, lattice])
    cuts = np.unique(np.round(cuts[(cuts >= lo) & (cuts <= hi)], 12))
    rows = []  # (start, end, true h, plan h, kind)
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a < 1e-9:
            continue
        m = 0.5 * (a + b)
        on = (front < m) & (m < back)
        h = float(height[on].max()) if on.any() else 0.0
        near = bool(np.any(np.abs(m - front) < mh) or np.any(np.abs(m - back) < mh))
        kind = RESTRICTED if np.any((r_lo < m) & (m < r_hi)) else (MARGIN if near else 0)
        hp = h + mv if (on.any() and near) else h
        if rows and rows[-1][2:] == (h, hp, kind) and not (cell and _on_lattice(a, seg * cell)):
            rows[-1] = (rows[-1][0], b, h, hp, kind)
        else:
            rows.append((float(a), float(b), h, hp, kind))
    if align and cell:
        rows = _align(rows, seg, seg * cell)
    goal = np.array([course.goal, float(env.surface(course.goal)) + leg * (1.0 + goal_zr),
                     0.0])
    # The goal is kept beside the terrain (`make_terrain`'s goal check assumes a 1 m leg).
    true = make_terrain([r[:3] for r in rows], None, course.name,
                        seg_length=seg)
    plan = true.with_heights(np.array([r[3] for r in rows]))
    kind = np.array([r[4] for r in rows], dtype=np.int64)
    return CourseMap(true, plan, kind == 0, kind, goal)


#: Extra dimensionless energy band for the MPPC leg (units of m g rho0): the paper's top
#: band ends at 1120 J = 1.43 m g rho0; the leg's top takeoff speed 2.7 m/s gives
#: 0.5 v^2 / (g rt) = 2.38.
LEG_EXTRA_ENERGY = ((1.43, 2.4),)


def leg_templates(hopper: Hopper | None = None, extra_energy=LEG_EXTRA_ENERGY,
                  model: str = "bhop"):
    """Froude-scaled templates for the MPPC leg (`scaled_templates`).

    The paper's set without its fast backward band (`RV = [-2.5, -1]`: a course is run
    forwards; `[-1, 0]` remains for stopping), plus `extra_energy` bands.

    `model="slip"`: the forward bands only (`RV = [0, 1]` and `[1, 2.5]`, which hold
    `ydot = 0` for stopping), with the SLIP adjustments of eqs 35-37 scaled to the hopper.
    A BHop plan hops backwards on narrow tops to gather speed; a SLIP stride that starts
    and ends moving backward never moves forward, so those routes ask for strides no SLIP
    does (docs/parkour_reactive.md, "SLIP on the leg").
    """
    from .._control.decisions import model_for
    from .._planning.templates import make_templates, paper_templates, scaled_templates

    hopper = leg_hopper() if hopper is None else hopper
    paper = paper_templates()
    arr = paper.as_array()
    slip = not model_for(model).instant_stance
    keep = arr[:, 0] >= -1e-12 if slip else arr[:, 1] > -1.0 + 1e-12
    base = make_templates(arr[keep], paper.seg_length)
    out = scaled_templates(hopper, extra_energy=extra_energy, base=base)
    return out.for_slip(hopper=hopper) if slip else out
