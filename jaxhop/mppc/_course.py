"""Parkour courses: block obstacles and restricted floor areas, possibly changing.

The JSON format is described in docs/mppc.md, "Course data".
"""

import json
from dataclasses import dataclass
from functools import partial
from importlib import resources
from pathlib import Path

import numpy as np

from .._core.errors import InputError
from .._core.validate import number
from .._core.validate import short as _short

_DATA = "data/courses"
_TOP_KEYS = {"name", "start", "goal", "obstacles", "restricted", "margins", "snapshots"}
# Limits on user courses (the shipped ones: 7.2-14.4 m, at most 7 blocks, 11 snapshots).
MAX_COORDINATE = 1.0e3  # |position|, width, |start|, |goal| (m)
MAX_SPAN = 1.0e3  # goal - start (m)
MAX_HEIGHT = 10.0  # obstacle height (m)
MAX_MARGIN = 1.0  # margins (m)
MAX_ITEMS = 1_000  # obstacles, restricted areas, snapshots
MAX_FILE_BYTES = 16 * 2**20
MAX_NAME = 200
_number = partial(number, limit=MAX_COORDINATE)  # a finite JSON number of sane size


@dataclass(frozen=True, eq=False)
class Environment:
    """What the planner sees at one replan: obstacles `[A, B] x [0, H]`, restricted `[a, b]`.

    Obstacles are sorted by front `A`, do not overlap, and have `B > A`, `H > 0`. Host-side
    NumPy data (it is never traced: the planner pads what it needs into JAX arrays).
    """

    front: np.ndarray
    back: np.ndarray
    height: np.ndarray
    restricted_lo: np.ndarray
    restricted_hi: np.ndarray

    def surface(self, x):
        """Height of the landable surface under `x` (0 on the floor, `H` on a block top)."""
        x = np.asarray(x, dtype=float)
        on = (x[..., None] > self.front) & (x[..., None] < self.back)
        return np.max(np.where(on, self.height, 0.0), axis=-1, initial=0.0)


@dataclass(frozen=True, eq=False)
class Course:
    """A parkour course: start, goal, margins and the environments over time.

    `snapshots` is a tuple of `(from_jump, Environment)` pairs: each replaces the
    environment from replan `from_jump` (0-based) on.
    """

    name: str
    start: float
    goal: float
    margin_h: float
    margin_v: float
    environment: Environment
    snapshots: tuple = ()

    def environment_at(self, replan: int) -> Environment:
        """The environment in force at replan `replan` (0-based)."""
        env = self.environment
        for from_jump, snap in self.snapshots:
            if from_jump <= replan:
                env = snap
        return env

    def final(self) -> "Course":
        """The course with its last snapshot as a fixed environment (`--final-snapshot`)."""
        env = self.snapshots[-1][1] if self.snapshots else self.environment
        return Course(self.name, self.start, self.goal, self.margin_h, self.margin_v, env, ())

    def to_dict(self) -> dict:
        """The course in its JSON format (docs/mppc.md, "Course data")."""

        def env_dict(env):
            return {
                "obstacles": [
                    {"position": (a + b) / 2, "width": b - a, "height": h}
                    for a, b, h in zip(env.front.tolist(), env.back.tolist(), env.height.tolist())
                ],
                "restricted": [
                    {"position": (a + b) / 2, "width": b - a}
                    for a, b in zip(env.restricted_lo.tolist(), env.restricted_hi.tolist())
                ],
            }

        out = {"name": self.name, "start": self.start, "goal": self.goal,
               "margins": {"horizontal": self.margin_h, "vertical": self.margin_v}}
        out.update(env_dict(self.environment))
        if self.snapshots:
            out["snapshots"] = [{"from_jump": k, **env_dict(e)} for k, e in self.snapshots]
        return out


def _items(value, field: str) -> list:
    if not isinstance(value, list):
        raise InputError(f"{field}: expected a list, got {type(value).__name__}")
    if len(value) > MAX_ITEMS:
        raise InputError(f"{field}: {len(value)} entries, at most {MAX_ITEMS} allowed")
    for i, item in enumerate(value):
        if not isinstance(item, dict):
            raise InputError(f"{field}[{i}]: expected an object")
    return value


def _keys(item: dict, allowed: set, required: set, field: str):
    extra = set(item) - allowed
    if extra:
        raise InputError(f"{field}: unknown key {_short(sorted(extra)[0])}")
    missing = required - set(item)
    if missing:
        raise InputError(f"{field}: missing key {sorted(missing)[0]!r}")


def _environment(obstacles, restricted, field: str) -> Environment:
    boxes = []
    for i, o in enumerate(_items(obstacles, f"{field}obstacles")):
        f = f"{field}obstacles[{i}]"
        _keys(o, {"position", "width", "height"}, {"position", "width", "height"}, f)
        p = _number(o["position"], f + ".position")
        w = _number(o["width"], f + ".width", positive=True)
        h = _number(o["height"], f + ".height", positive=True, limit=MAX_HEIGHT)
        boxes.append((p - w / 2, p + w / 2, h))
    boxes.sort()
    for (a0, b0, _), (a1, _, _) in zip(boxes, boxes[1:]):
        if a1 < b0:
            raise InputError(f"{field}obstacles: blocks [{a0:g}, {b0:g}] and one at {a1:g} overlap")
    areas = []
    for i, r in enumerate(_items(restricted, f"{field}restricted")):
        f = f"{field}restricted[{i}]"
        _keys(r, {"position", "width"}, {"position", "width"}, f)
        p = _number(r["position"], f + ".position")
        w = _number(r["width"], f + ".width", positive=True)
        areas.append((p - w / 2, p + w / 2))
    areas.sort()
    arr = np.array(boxes, dtype=float).reshape(-1, 3)
    res = np.array(areas, dtype=float).reshape(-1, 2)
    return Environment(arr[:, 0], arr[:, 1], arr[:, 2], res[:, 0], res[:, 1])


def _legal_endpoint(env: Environment, x: float, mh: float, field: str):
    near = np.minimum(np.abs(x - env.front), np.abs(x - env.back))
    if near.size and near.min() < mh:
        raise InputError(f"{field}: {x:g} lies within the horizontal margin of an obstacle edge")
    if np.any((x > env.restricted_lo) & (x < env.restricted_hi)):
        raise InputError(f"{field}: {x:g} lies in a restricted area")


def course_from_dict(data, default_name: str = "course") -> Course:
    """Build and validate a `Course` from its JSON object (docs/mppc.md, "Course data").

    **Arguments:**
    - `data`: the parsed JSON object.
    - `default_name`: the name used when `data` has none.

    **Returns:** the `Course`.

    **Raises:** `InputError` naming the offending field for any malformed entry.
    """
    if not isinstance(data, dict):
        raise InputError("course: expected a JSON object at the top level")
    _keys(data, _TOP_KEYS, {"start", "goal", "obstacles"}, "course")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise InputError("name: expected a non-empty string")
    if len(name) > MAX_NAME or not name.isprintable():
        raise InputError(f"name: expected at most {MAX_NAME} printable characters")
    start = _number(data["start"], "start")
    goal = _number(data["goal"], "goal")
    if goal <= start:
        raise InputError(f"goal: must be greater than start ({start:g}), got {goal:g}")
    if goal - start > MAX_SPAN:
        raise InputError(f"goal: at most {MAX_SPAN:g} m after start, got {goal - start:g}")
    margins = data.get("margins", {"horizontal": 0.03, "vertical": 0.05})
    if not isinstance(margins, dict):
        raise InputError("margins: expected an object")
    _keys(margins, {"horizontal", "vertical"}, {"horizontal", "vertical"}, "margins")
    mh = _number(margins["horizontal"], "margins.horizontal", nonneg=True, limit=MAX_MARGIN)
    mv = _number(margins["vertical"], "margins.vertical", nonneg=True, limit=MAX_MARGIN)
    env = _environment(data["obstacles"], data.get("restricted", []), "")
    snapshots = []
    last = -1
    for i, s in enumerate(_items(data.get("snapshots", []), "snapshots")):
        f = f"snapshots[{i}]"
        _keys(s, {"from_jump", "obstacles", "restricted"}, {"from_jump", "obstacles"}, f)
        k = s["from_jump"]
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= 10**6:
            raise InputError(f"{f}.from_jump: expected an integer in [0, 1e6], got "
                             f"{_short(k)}")
        if k <= last:
            raise InputError(f"{f}.from_jump: must increase from one snapshot to the next")
        last = k
        snapshots.append((k, _environment(s["obstacles"], s.get("restricted", []), f + ".")))
    for k, e in [(0, env)] + snapshots:
        where = "" if k == 0 and e is env else f" (snapshot from jump {k})"
        _legal_endpoint(e, goal, mh, "goal" + where)
    _legal_endpoint(env if not snapshots or snapshots[0][0] > 0 else snapshots[0][1], start,
                    mh, "start")
    return Course(name, start, goal, mh, mv, env, tuple(snapshots))


def list_courses() -> list[str]:
    """Names of the courses shipped with jaxhop (`mppc-sim-1`, `mppc-hw-dynamic-1`, ...)."""
    root = resources.files("jaxhop").joinpath(_DATA)
    return sorted(
        p.name[:-5]
        for p in root.iterdir()
        if p.name.endswith(".json") and p.name.startswith("mppc-")
    )


def load_course(name_or_path: str) -> Course:
    """Load a shipped course by name, or a course JSON file by path.

    **Arguments:**
    - `name_or_path`: a shipped name (see `list_courses`) or a path to a JSON file.

    **Returns:** the validated `Course`.

    **Raises:** `InputError` if no such course exists or the file is malformed.
    """
    name = str(name_or_path)
    if name in list_courses():
        text = resources.files("jaxhop").joinpath(f"{_DATA}/{name}.json").read_text()
        default = name
    else:
        path = Path(name)
        if not path.is_file():
            raise InputError(
                f"course: {name!r} is neither a shipped course ({', '.join(list_courses())}) "
                "nor a file"
            )
        try:
            if path.stat().st_size > MAX_FILE_BYTES:
                raise InputError(f"course: {name!r} is larger than {MAX_FILE_BYTES >> 20} MiB")
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise InputError(f"course: cannot read {name!r}: {e.strerror}") from None
        except UnicodeDecodeError:
            raise InputError(f"course: cannot read {name!r}: not UTF-8 text") from None
        default = path.stem
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"course: {name!r} is not valid JSON ({e.msg}, line {e.lineno})") from None
    except RecursionError:
        raise InputError(f"course: {name!r} is not valid JSON (nested too deeply)") from None
    return course_from_dict(data, default)


def reference_results() -> dict:
    """The original planner's results on the shipped courses (`mppc_reference_results.json`)."""
    root = resources.files("jaxhop").joinpath(_DATA)
    return json.loads(root.joinpath("mppc_reference_results.json").read_text())


def random_course(
    seed: int,
    length: float = 7.2,
    n_obstacles: tuple[int, int] = (3, 6),
    n_restricted: tuple[int, int] = (1, 4),
) -> Course:
    """A seeded random static course in the style of the MPPC experiments.

    Blocks are 0.1-0.3 m wide and 0.1-0.3 m high, restricted areas 0.2-0.5 m wide; the
    first and last 0.5 m are clear floor. Nothing guarantees the course can be crossed.

    **Arguments:**
    - `seed`: seed of the NumPy generator.
    - `length`: goal position (start is 0).
    - `n_obstacles`, `n_restricted`: inclusive ranges of the numbers of each.

    **Returns:** the `Course`, named `random-<seed>`.
    """
    rng = np.random.default_rng(seed)
    lo, hi = 0.5, length - 0.5
    boxes = []
    for _ in range(int(rng.integers(n_obstacles[0], n_obstacles[1] + 1))):
        for _try in range(20):
            w = rng.uniform(0.1, 0.3)
            a = rng.uniform(lo, hi - w)
            if all(a + w + 0.05 < a0 or a > b0 + 0.05 for a0, b0, _ in boxes):
                boxes.append((a, a + w, rng.uniform(0.1, 0.3)))
                break
    areas = []
    for _ in range(int(rng.integers(n_restricted[0], n_restricted[1] + 1))):
        for _try in range(20):
            w = rng.uniform(0.2, 0.5)
            a = rng.uniform(lo, hi - w)
            if all(a + w < a0 or a > b0 for a0, b0 in areas):
                areas.append((a, a + w))
                break
    data = {
        "name": f"random-{seed}",
        "start": 0.0,
        "goal": float(length),
        "margins": {"horizontal": 0.03, "vertical": 0.05},
        "obstacles": [
            {"position": (a + b) / 2, "width": b - a, "height": h} for a, b, h in boxes
        ],
        "restricted": [{"position": (a + b) / 2, "width": b - a} for a, b in areas],
    }
    return course_from_dict(data)
