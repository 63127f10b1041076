"""Result codes of a stride and of a run: failure is data, one code per run.

The integer values are part of the output format (sweep and run JSON, checkpoints), so
they never change: `0` is a completed stride / a run that reached the goal, `-1` a run
still going, positive values the failures.
"""

from enum import IntEnum


class Result(IntEnum):
    """Outcome of a stride or of a run (`docs/decisions.md`, "Execution").

    `RESTRICTED` and `MARGIN` only occur on parkour courses: a touchdown strictly inside a
    restricted floor area or a margin band next to an obstacle edge. `SLIP` only occurs in
    MuJoCo runs (`jaxhop.mujoco`): a foot that slid on the ground in stance.
    """

    RUNNING = -1
    SUCCESS = 0
    COLLISION = 1
    HOLE = 2
    OFF_MAP = 3
    OUTSIDE_DOMAIN = 4
    MAX_STEPS = 5
    SOLVER = 6
    RESTRICTED = 7
    MARGIN = 8
    SLIP = 9


#: Failures on a terrain, in code order (code `i + 1` is `FAILURE_NAMES[i]`).
FAILURE_NAMES = tuple(r.name.lower() for r in Result if Result.SUCCESS < r <= Result.SOLVER)
#: Failures on a parkour course: the terrain's, then the forbidden touchdowns.
COURSE_FAILURE_NAMES = tuple(r.name.lower() for r in Result
                             if Result.SUCCESS < r <= Result.MARGIN)
#: Failures of a MuJoCo run on a terrain: the terrain's and a sliding foot.
SIM_FAILURE_NAMES = FAILURE_NAMES + (Result.SLIP.name.lower(),)
#: Names of the codes a run on a terrain can end with, indexed by code.
RESULT_NAMES = ("success",) + FAILURE_NAMES


def result_name(code: int) -> str:
    """The name of a result code (`"success"`, `"collision"`, ..., `"margin"`)."""
    return Result(int(code)).name.lower()


def failure_counts(code, names=FAILURE_NAMES) -> dict:
    """How many runs ended with each failure of `names` (names of `Result` members)."""
    return {name: int((code == Result[name.upper()]).sum()) for name in names}
