"""At least 1 000 generated malformed inputs: each ends with exit 2 and a one-line message.

A seeded generator mutates a valid terrain file, a valid course file and valid command
lines of every subcommand (`plan`, `sweep`, `run`, `step`, `parkour`, `demo`). Every case
goes through the CLI entry point `jaxhop._cli.main.main` in this process, with everything that
would plan, run or compile replaced by a tripwire: a bad input must be rejected before any
work starts. A handful of the cases also run as real `jaxhop` processes.
"""

from __future__ import annotations

import collections
import copy
import json
import math
import os
import random
import subprocess
import sys

import pytest

from jaxhop._cli.main import main
from jaxhop._core.terrain import terrain_from_dict
from jaxhop.mppc._course import course_from_dict

SEED = 20_261_121

TERRAIN = {
    "name": "t",
    "blocks": [{"start": 0.0, "end": 1.2, "height": 0.0},
               {"start": 1.5, "end": 3.0, "height": 0.2},
               {"start": 3.0, "end": 4.5, "height": 0.0}],
    "goal": [4.0, 1.3, 0.0],
}
COURSE = {
    "name": "c", "start": 0.0, "goal": 3.0,
    "obstacles": [{"position": 1.0, "width": 0.2, "height": 0.2},
                  {"position": 2.0, "width": 0.2, "height": 0.1}],
    "restricted": [{"position": 1.5, "width": 0.3}],
    "margins": {"horizontal": 0.03, "vertical": 0.05},
    "snapshots": [{"from_jump": 2, "obstacles": [{"position": 1.0, "width": 0.2,
                                                  "height": 0.3}], "restricted": []}],
}
# Values that no number field accepts: wrong types, non-finite, too large for a float, or
# beyond the documented magnitude limits.
BAD_NUMBERS = [math.nan, math.inf, -math.inf, "1", "abc", "", None, True, False, [], [1.0],
               {}, {"v": 1}, 10**400, -(10**400), 1e300, -1e300, 2e4]
BAD_VECTORS = ["", "1", "1,2", "1,2,3,4", "a,b,c", "nan,1,2", "1,inf,2", "1,2,-inf",
               "1e400,1,1", "1;2;3", "1 2 3", ",,", "1,,2", "0x1,2,3", "None,1,2", "1,2,3,",
               "[1,2,3]", "1,2,3e999"]


class Tripwire(Exception):
    """Raised where real work would start: validation came too late."""


Case = collections.namedtuple("Case", "category argv needle")


def _dump(data) -> str:
    return json.dumps(data, allow_nan=True)


class _Files:
    """Writes each generated file once, under a fresh temporary folder."""

    def __init__(self, root):
        self.root, self.n = root, 0

    def __call__(self, content, suffix=".json") -> str:
        self.n += 1
        path = os.path.join(self.root, f"f{self.n:05d}{suffix}")
        mode = "wb" if isinstance(content, bytes) else "w"
        with open(path, mode) as f:
            f.write(content)
        return path


# --- terrain files ---------------------------------------------------------------------


def _terrain_cases(rng: random.Random, write) -> list[Case]:
    out = []

    def add(kind, data_or_text, needle=None):
        text = data_or_text if isinstance(data_or_text, (str, bytes)) else _dump(data_or_text)
        path = write(text)
        cmd = rng.choice(["plan", "sweep", "run", "step"])
        argv = [cmd, "--terrain", path]
        if cmd == "step":
            argv += ["--model", "bhop", "--apex", "1.0,1.5,0.5", "--controls", "0.1,0.05,1.2"]
        elif cmd != "plan" and rng.random() < 0.5:
            argv += ["--noise", rng.choice(["none", "sensor", "wind", "ground"]),
                     "--seed", str(rng.randrange(1000))]
        out.append(Case("terrain:" + kind, argv, needle))

    def base():
        return copy.deepcopy(TERRAIN)

    for i in range(3):
        for key in ("start", "end", "height"):
            for v in BAD_NUMBERS:
                d = base()
                d["blocks"][i][key] = v
                add("bad number", d, f"blocks[{i}].{key}")
    for j in range(3):
        for v in BAD_NUMBERS:
            d = base()
            d["goal"][j] = v
            add("bad number", d, f"goal[{j}]")
    for g in ([], [1.0], [4.0, 1.3], [4.0, 1.3, 0.0, 1.0], "4,1.3,0", 5, {"y": 4.0},
              [[4.0], [1.3], [0.0]], True):
        d = base()
        d["goal"] = g
        add("wrong type", d, "goal")
    # Goals that are numbers but not a goal: off the map, under or far above the ground,
    # too fast.
    for _ in range(12):
        d = base()
        d["goal"][0] = rng.choice([rng.uniform(-100, -0.01), rng.uniform(4.51, 100)])
        add("bad goal", d, "goal")
        d = base()
        d["goal"][1] = rng.uniform(-5.0, 1.0)
        add("bad goal", d, "goal")
        d = base()
        d["goal"][1] = rng.uniform(100.5, 9000.0)
        add("bad goal", d, "goal")
        d = base()
        d["goal"][2] = rng.choice([-1, 1]) * rng.uniform(100.5, 5000.0)
        add("bad goal", d, "goal")
    # Negative or zero lengths.
    for i in range(3):
        for _ in range(4):
            d = base()
            b = d["blocks"][i]
            b["end"] = b["start"] - rng.choice([0.0, rng.uniform(0.001, 2.0)])
            add("negative length", d, f"blocks[{i}]")
    # Unsorted and overlapping blocks.
    for perm in ([1, 0, 2], [0, 2, 1], [2, 1, 0], [2, 0, 1], [1, 2, 0]):
        d = base()
        d["blocks"] = [d["blocks"][k] for k in perm]
        add("unsorted", d, "blocks[")
    for _ in range(24):
        d = base()
        i = rng.choice([1, 2])
        prev = d["blocks"][i - 1]
        d["blocks"][i]["start"] = prev["end"] - rng.uniform(0.01, prev["end"] - prev["start"])
        add("overlapping", d, f"blocks[{i}]")
    for _ in range(6):
        d = base()
        d["blocks"].insert(rng.randrange(4), copy.deepcopy(rng.choice(d["blocks"])))
        add("overlapping", d, "blocks[")
    # Empty things.
    for text in ("", " ", "\n", "{}", "[]", "null", '{"blocks": []}',
                 '{"name": "x", "goal": [4, 1.3, 0]}', '""', "0"):
        add("empty", text)
    # Unknown keys.
    for _ in range(16):
        d = base()
        d["".join(rng.choice("abcxyz_") for _ in range(rng.randint(1, 8)))] = rng.random()
        add("unknown key", d, "unknown key")
    for i in range(3):
        for key in ("x", "Start", "width", "hight", ""):
            d = base()
            d["blocks"][i][key] = 1.0
            add("unknown key", d, f"blocks[{i}]")
    for i in range(3):
        for key in ("start", "end", "height"):
            d = base()
            del d["blocks"][i][key]
            add("missing key", d, f"blocks[{i}]")
    # Wrong types of the containers.
    for v in ("abc", 5, {}, None, True, {"start": 0, "end": 1, "height": 0}):
        d = base()
        d["blocks"] = v
        add("wrong type", d, "blocks")
    for v in (5, "x", [0.0, 1.2, 0.0], None, [], True):
        d = base()
        d["blocks"][rng.randrange(3)] = v
        add("wrong type", d, "blocks[")
    for v in (5, [], {}, None, True, "a\nb", "\x00", "x" * 500):
        d = base()
        d["name"] = v
        add("wrong type", d, "name")
    for v in ([TERRAIN], 5, "terrain", True):
        add("wrong type", v)
    # Absurd sizes.
    d = base()
    d["blocks"] = [{"start": 0.2 * k, "end": 0.2 * k + 0.15, "height": 0.0}
                   for k in range(1001)]
    d["goal"] = [1.0, 1.3, 0.0]
    add("absurd size", d, "blocks")
    for end in (400.0, 1000.0, 9999.0):
        d = base()
        d["blocks"][2]["end"] = end
        add("absurd size", d, "segments")
    for _ in range(8):
        d = base()
        d["blocks"][rng.randrange(3)]["height"] = rng.choice([-1, 1]) * rng.uniform(1.1e4, 1e9)
        add("absurd size", d, "height")
    d = base()
    d["blocks"] = [{"start": 0.01 * k, "end": 0.01 * k + 0.01, "height": 0.0}
                   for k in range(50)]
    d["goal"] = [0.2, 1.3, 0.0]
    add("absurd size", d, "segment")
    add("absurd size", "[" * 100_000 + "]" * 100_000, "nested")
    add("absurd size", '{"blocks": ' + "[" * 50_000 + "]" * 50_000 + "}", "nested")
    add("absurd size", " " * (17 * 2**20) + _dump(TERRAIN), "larger")
    # Not JSON at all.
    good = _dump(TERRAIN)
    for _ in range(20):
        add("invalid JSON", good[: rng.randrange(1, len(good) - 1)], "invalid JSON")
    for text in ("{'blocks': []}", '{"blocks": [],}', "blocks: []", good + "}", good + good,
                 "\ufeff" + good, "NaN-", '{"blocks": [{"start": 0, "end": 1, "height": 0,}]}'):
        add("invalid JSON", text, "JSON")
    for _ in range(6):
        add("not text", bytes(rng.randrange(128, 256) for _ in range(rng.randint(1, 64))),
            "UTF-8")
    add("not text", good.encode("utf-16"), None)
    return out


# --- course files ----------------------------------------------------------------------


def _course_cases(rng: random.Random, write) -> list[Case]:
    out = []

    def add(kind, data_or_text, needle=None):
        text = data_or_text if isinstance(data_or_text, (str, bytes)) else _dump(data_or_text)
        argv = ["parkour", "--course", write(text)]
        if rng.random() < 0.3:
            argv.append("--final-snapshot")
        out.append(Case("course:" + kind, argv, needle))

    def base():
        return copy.deepcopy(COURSE)

    fields = [(("start",), "start"), (("goal",), "goal"),
              (("margins", "horizontal"), "margins.horizontal"),
              (("margins", "vertical"), "margins.vertical")]
    for i in range(2):
        for k in ("position", "width", "height"):
            fields.append((("obstacles", i, k), f"obstacles[{i}].{k}"))
    for k in ("position", "width"):
        fields.append((("restricted", 0, k), f"restricted[0].{k}"))
    for k in ("position", "width", "height"):
        fields.append((("snapshots", 0, "obstacles", 0, k), f"snapshots[0].obstacles[0].{k}"))
    for path, needle in fields:
        for v in BAD_NUMBERS:
            d = base()
            node = d
            for p in path[:-1]:
                node = node[p]
            node[path[-1]] = v
            add("bad number", d, needle)
    # Non-positive or absurd widths and heights, bad margins.
    for _ in range(10):
        d = base()
        i, k = rng.randrange(2), rng.choice(["width", "height"])
        d["obstacles"][i][k] = -rng.choice([0.0, rng.uniform(0.001, 1.0)])
        add("negative length", d, f"obstacles[{i}].{k}")
        d = base()
        d["restricted"][0]["width"] = -rng.choice([0.0, rng.uniform(0.001, 1.0)])
        add("negative length", d, "restricted[0].width")
        d = base()
        d["margins"][rng.choice(["horizontal", "vertical"])] = -rng.uniform(1e-6, 1.0)
        add("negative length", d, "margins")
    for _ in range(6):
        d = base()
        d["obstacles"][rng.randrange(2)]["height"] = rng.uniform(10.5, 999.0)
        add("absurd size", d, "height")
        d = base()
        d["margins"]["vertical"] = rng.uniform(1.5, 900.0)
        add("absurd size", d, "margins.vertical")
    # Goal not after start, too far, or not a legal landing point; start not legal.
    for _ in range(8):
        d = base()
        d["goal"] = d["start"] - rng.choice([0.0, rng.uniform(0.01, 5.0)])
        add("bad goal", d, "goal")
        d = base()
        d["goal"] = rng.uniform(1000.5, 1000.9)
        d["start"] = 0.0
        add("absurd size", d, "goal")
    for g in (1.5, 1.4, 1.62, 0.9, 1.1, 1.905, 2.1, 0.91):
        d = base()
        d["goal"] = g
        add("bad goal", d, "goal")
    for s in (1.5, 1.45, 0.9, 1.1, 1.92):
        d = base()
        d["start"] = s
        add("bad start", d, "start")
    # Overlapping and unsorted-overlapping obstacles.
    for _ in range(16):
        d = base()
        o = d["obstacles"]
        o[1]["position"] = o[0]["position"] + rng.uniform(-0.19, 0.19)
        if rng.random() < 0.5:
            o.reverse()
        add("overlapping", d, "overlap")
    d = base()
    d["snapshots"][0]["obstacles"].append({"position": 1.05, "width": 0.2, "height": 0.1})
    add("overlapping", d, "snapshots[0].obstacles")
    # Unknown and missing keys.
    for where in ("top", "obstacle", "restricted", "margins", "snapshot"):
        for _ in range(4):
            d = base()
            key = "".join(rng.choice("abcqxz_") for _ in range(rng.randint(1, 8)))
            node = {"top": d, "obstacle": d["obstacles"][1], "restricted": d["restricted"][0],
                    "margins": d["margins"], "snapshot": d["snapshots"][0]}[where]
            node[key] = 1.0
            add("unknown key", d, "unknown key")
    for path in (("start",), ("goal",), ("obstacles",), ("margins", "vertical"),
                 ("obstacles", 0, "height"), ("restricted", 0, "position"),
                 ("snapshots", 0, "from_jump"), ("snapshots", 0, "obstacles")):
        d = base()
        node = d
        for p in path[:-1]:
            node = node[p]
        del node[path[-1]]
        add("missing key", d, "missing key")
    # Wrong types and empty things.
    for key, vals, needle in (
            ("obstacles", ("x", 5, {}, None, True, [5], [[1.0, 0.2, 0.2]], ["o"]), "obstacles"),
            ("restricted", ("x", 5, {}, None, [1.5]), "restricted"),
            ("margins", ([], "x", 5, None, {}), "margins"),
            ("snapshots", ({}, "x", 5, None, [5]), "snapshots"),
            ("name", ("", 5, [], None, "a\nb", "\x07", "n" * 300), "name")):
        for v in vals:
            d = base()
            d[key] = v
            add("wrong type", d, needle)
    for v in (-1, 1.5, "2", True, None, [2], 10**7, 10**400):
        d = base()
        d["snapshots"][0]["from_jump"] = v
        add("wrong type", d, "from_jump")
    d = base()
    d["snapshots"].append(copy.deepcopy(d["snapshots"][0]))
    add("unsorted", d, "from_jump")
    d = base()
    d["snapshots"] = [dict(d["snapshots"][0], from_jump=5), dict(d["snapshots"][0],
                                                                 from_jump=3)]
    add("unsorted", d, "from_jump")
    for text in ("", "{}", "[]", "null", "0", '""', '{"start": 0, "goal": 3}'):
        add("empty", text)
    for v in ([COURSE], 5, "course"):
        add("wrong type", v, "course")
    # Absurd sizes.
    d = base()
    d["obstacles"] = [{"position": 0.5 + 0.002 * k, "width": 0.001, "height": 0.1}
                      for k in range(1001)]
    add("absurd size", d, "obstacles")
    d = base()
    d["restricted"] = [{"position": 0.5, "width": 0.1}] * 1001
    add("absurd size", d, "restricted")
    d = base()
    d["snapshots"] = [dict(d["snapshots"][0], from_jump=k) for k in range(1001)]
    add("absurd size", d, "snapshots")
    for _ in range(6):
        d = base()
        d["obstacles"][1]["position"] = rng.choice([-1, 1]) * rng.uniform(1.1e3, 1e12)
        add("absurd size", d, "obstacles[1].position")
    add("absurd size", "[" * 100_000 + "]" * 100_000, "nested")
    add("absurd size", " " * (17 * 2**20) + _dump(COURSE), "larger")
    good = _dump(COURSE)
    for _ in range(16):
        add("invalid JSON", good[: rng.randrange(1, len(good) - 1)], "JSON")
    for text in ("{'start': 0}", good + ",", "start=0", good.replace(":", "=", 1)):
        add("invalid JSON", text, "JSON")
    for _ in range(4):
        add("not text", bytes(rng.randrange(128, 256) for _ in range(rng.randint(1, 64))),
            "UTF-8")
    return out


# --- command lines ---------------------------------------------------------------------

VALID = {
    "plan": ["plan", "--terrain", "flat"],
    "sweep": ["sweep", "--terrain", "flat", "--dy", "0.5", "--dz", "0.5"],
    "run": ["run", "--terrain", "flat", "--apex", "0.5,1.6,0.5"],
    "step-bhop": ["step", "--model", "bhop", "--apex", "0.2,1.4,0.8", "--controls",
                  "0.1,0.05,1.2"],
    "step-slip": ["step", "--model", "slip", "--apex", "0,1.3,1.0", "--controls",
                  "0.15,20000,20000"],
    "parkour": ["parkour", "--course", "mppc-sim-1"],
    "demo": ["demo", "--out", "OUT"],
}


def _with(argv, option, value):
    """`argv` with `option` set to `value` (replaced if present), as `--option=value`."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
            continue
        if a == option:
            skip = True
            continue
        out.append(a)
    return out + [f"{option}={value}"]


def _cli_cases(rng: random.Random, tmp) -> list[Case]:
    out = []

    def add(kind, argv, needle):
        out.append(Case("cli:" + kind, argv, needle))

    def ctx(name):
        argv = list(VALID[name])
        if name in ("sweep", "run") and rng.random() < 0.5:
            argv += ["--noise", rng.choice(["none", "sensor", "wind", "ground"])]
        return argv

    vector_options = [("plan", "--goal"), ("sweep", "--goal"), ("run", "--goal"),
                      ("sweep", "--tolerance"), ("run", "--tolerance"), ("run", "--apex"),
                      ("step-bhop", "--apex"), ("step-slip", "--apex"),
                      ("step-bhop", "--controls"), ("step-slip", "--controls")]
    for name, opt in vector_options:
        for v in BAD_VECTORS:
            add("bad vector", _with(ctx(name), opt, v), opt)
    scalar = {
        "--seed": ["-1", "1.5", "abc", "", "1e3", str(2**63), "nan", "0x10", "1,2", "10**3"],
        "--max-steps": ["0", "-1", "1.5", "0.5", "abc", "", "10001", "1e3", "nan", "inf",
                        str(10**30)],
        "--dy": ["0", "-0.1", "nan", "inf", "abc", "", "1e-9", "1e-7", "1,2", "-inf"],
        "--dz": ["0", "-0.1", "nan", "inf", "abc", "", "1e-9", "1e-7", "1,2", "-0"],
        "--ydot0": ["nan", "inf", "abc", "", "1e3", "-500", "1,2", "1e400"],
        "--chunk": ["0", "-1", "0.5", "2.5", "abc", "", "1e9", str(10**8), "nan"],
    }
    for opt, values in scalar.items():
        names = ["sweep", "run"] if opt in ("--seed", "--max-steps") else ["sweep"]
        for name in names:
            for v in values:
                add("bad number", _with(ctx(name), opt, v), opt)
    for name in ("step-bhop", "step-slip"):
        for v in ("nan", "inf", "-inf", "abc", "", "1e3", "-1e5", "1,2", "1e400"):
            add("bad number", _with(ctx(name), "--wind", v), "--wind")
    for v in ("0", "-0.01", "nan", "inf", "abc", "", "0.2", "1e-9", "0.0001", "1,2"):
        add("bad number", _with(ctx("parkour"), "--grid", v), "--grid")
    # Numbers of the right form but not a sane input.
    for name in ("plan", "sweep", "run"):
        for g in ("10,1.3,0", "-1,1.3,0", "2.5,0.5,0", "2.5,1.0,0", "2.5,500,0", "2.5,1.3,500",
                  "1e5,1.3,0"):
            add("bad goal", _with(ctx(name), "--goal", g), "--goal")
        if name != "plan":
            for t in ("-0.1,0.05,0.05", "0.05,-1e-9,0.05", "1e3,0.05,0.05"):
                add("bad tolerance", _with(ctx(name), "--tolerance", t), "--tolerance")
    for name in ("step-bhop", "step-slip"):
        # A foot at or below the ground: at 1.0 the BHop foot (straight down) touches it;
        # the SLIP foot at th_td = 0.15 hangs 1.1 cm higher, so 0.98 puts it below.
        low = "0.2,1.0,0.8" if name == "step-bhop" else "0.2,0.98,0.8"
        for a in ("0.2,0.5,0.8", "0.2,-3,0.8", low, "0.2,1e5,0.8", "0.2,1.4,1e3"):
            add("bad apex", _with(ctx(name), "--apex", a), "--apex")
        a = "50,1.4,0.8"
        add("bad apex", _with(ctx(name), "--apex", a) + ["--terrain", "flat"], "--apex")
    for a in ("0.5,1e5,0.5", "-2e4,1.6,0.5", "0.5,1.6,150", "0.5,1.6,-1e300"):
        add("bad apex", _with(ctx("run"), "--apex", a), "--apex")
    for c in ("5,0.05,1.2", "0.1,2,1.2", "0.1,-1.6,1.2", "0.1,0.05,-1", "0.1,0.05,-5",
              "0.1,0.05,1e5"):
        add("bad controls", _with(ctx("step-bhop"), "--controls", c), "--controls")
    for c in ("2,20000,20000", "-1.6,20000,20000", "0.15,0,20000", "0.15,20000,-1",
              "0.15,1e9,20000"):
        add("bad controls", _with(ctx("step-slip"), "--controls", c), "--controls")
    # Choices, unknown options and subcommands, missing arguments.
    for name, opt, v in (("sweep", "--noise", "storm"), ("run", "--noise", ""),
                         ("plan", "--pickbest", "fast"), ("sweep", "--pickbest", ""),
                         ("plan", "--model", "quadruped"), ("sweep", "--model", "SLIP"),
                         ("run", "--model", "quadruped"), ("step-bhop", "--model", "x"),
                         ("parkour", "--planner", "snopt")):
        add("bad choice", _with(ctx(name), opt, v), "invalid choice")
    for name in VALID:
        for extra in (["--frobnicate"], ["--frobnicate=1"], ["stray"], ["-x"]):
            add("unknown option", ctx(name) + extra, "unrecognized")
    for argv in ([], ["frobnicate"], ["Plan"], ["--terrain", "flat"], ["step"],
                 ["step", "--apex", "0,1.3,1"], ["step", "--controls", "0.1,0.05,1.2"],
                 ["parkour"], ["sweep", "--seed"], ["run", "--apex"], ["plan", "--goal"],
                 ["parkour", "--course"], ["demo", "--out"], ["demo", "--no-cache=yes"]):
        add("missing or unknown", argv, None)
    # Paths.
    a_file = os.path.join(tmp, "a-file")
    with open(a_file, "w") as f:
        f.write("x")
    nowhere = os.path.join(tmp, "no", "such", "dir", "x.json")
    for name in VALID:
        for opt in ("--json",) + (("--plot",) if name in ("sweep", "run", "parkour") else ()):
            for v in (nowhere, tmp, ""):
                add("bad path", _with(ctx(name), opt, v), opt)
    for v in ("nowhere", "", "reference.json", tmp):
        add("bad path", _with(ctx("plan"), "--terrain", v), "terrain")
        add("bad path", _with(ctx("parkour"), "--course", v), "course")
    for v in (a_file, ""):
        add("bad path", _with(ctx("demo"), "--out", v), "--out")
        add("bad path", _with(ctx("sweep"), "--checkpoint", v), "--checkpoint")
    return out


def generate(root) -> list[Case]:
    """Every malformed case, deterministically from `SEED`."""
    os.makedirs(root, exist_ok=True)
    rng = random.Random(SEED)
    write = _Files(root)
    cases = _terrain_cases(rng, write) + _course_cases(rng, write) + _cli_cases(rng, root)
    demo_out = os.path.join(root, "demo-out")
    return [c._replace(argv=[demo_out if a == "OUT" else a for a in c.argv]) for c in cases]


@pytest.fixture
def tripwires(monkeypatch):
    """Everything that would build a plan, run, simulate or compile raises `Tripwire`."""
    # Each is patched where the command line looks it up when it runs (`jaxhop step` takes
    # its stride from the model, `decisions.py`, which reads both names at call time).
    from jaxhop._cli import demo
    from jaxhop._control import decisions
    from jaxhop._execution import batches
    from jaxhop._models.slip import stride
    from jaxhop._planning import cache, plan
    from jaxhop.mppc import _cli as mppc_cli

    def trip(*args, **kwargs):
        raise Tripwire("validation came too late")

    for module, name in ((plan, "build_plan"), (cache, "get_plan"), (batches, "sweep"),
                         (batches, "run_batch"), (decisions, "bhop_stride"),
                         (stride, "slip_stride"), (demo, "demo"), (mppc_cli, "run_course")):
        monkeypatch.setattr(module, name, trip)


def test_bases_are_valid():
    """The unmutated inputs pass validation: the mutations are what is rejected."""
    terrain_from_dict(copy.deepcopy(TERRAIN))
    course_from_dict(copy.deepcopy(COURSE))


def test_generator_is_deterministic(tmp_path):
    a = generate(str(tmp_path / "a"))
    b = generate(str(tmp_path / "b"))
    assert [c.category for c in a] == [c.category for c in b]
    assert [[x.replace(str(tmp_path / "a"), "") for x in c.argv] for c in a] == \
        [[x.replace(str(tmp_path / "b"), "") for x in c.argv] for c in b]
    files = sorted(os.listdir(tmp_path / "a"))
    assert files == sorted(os.listdir(tmp_path / "b")) and len(files) > 500
    for name in files:
        if name.endswith(".json"):
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def _mkroot(tmp_path):
    return str(tmp_path / "cases")


@pytest.mark.slow
def test_malformed_inputs_exit_2(tmp_path, capsys, tripwires):
    cases = generate(_mkroot(tmp_path))
    failures = []
    for case in cases:
        capsys.readouterr()
        try:
            code = main(case.argv)
        except SystemExit as err:  # argparse's own exit would be a bug too
            code = err.code
        except Tripwire:
            code = "tripwire"
        except Exception as err:  # a traceback
            code = f"{type(err).__name__}: {err}"
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        ok = (code == 2 and len(lines) == 1 and lines[0].startswith("jaxhop: error: ")
              and "Traceback" not in captured.err and not captured.out
              and (case.needle is None or case.needle in lines[0]))
        if not ok:
            failures.append((case, code, captured.err[-300:]))
    counts = collections.Counter(c.category.split(":")[0] for c in cases)
    kinds = collections.Counter(c.category for c in cases)
    print(f"\n{len(cases)} malformed inputs: " + ", ".join(f"{k} {v}" for k, v in
                                                           sorted(counts.items())))
    print("; ".join(f"{k} {v}" for k, v in sorted(kinds.items())))
    assert not failures, "\n".join(f"{c.category} {c.argv[:8]!r} -> {code!r}: {err!r}"
                                   for c, code, err in failures[:20])
    assert len(cases) >= 1000
    assert min(counts["terrain"], counts["course"], counts["cli"]) >= 250


@pytest.mark.slow  # starts processes
def test_real_processes_agree(tmp_path):
    """A few cases as real processes: exit status 2, one stderr line, no traceback."""
    cases = generate(_mkroot(tmp_path))
    rng = random.Random(SEED + 1)
    picked = [rng.choice([c for c in cases if c.category.startswith(kind)])
              for kind in ("terrain:", "course:", "cli:bad number", "cli:unknown option",
                           "cli:bad path")]
    for case in picked:
        proc = subprocess.run([sys.executable, "-m", "jaxhop", *case.argv],
                              capture_output=True, text=True, timeout=300,
                              env=dict(os.environ, JAXHOP_CACHE=str(tmp_path / "cache")))
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2, (case, proc.stderr[-500:])
        assert len(lines) == 1 and "Traceback" not in proc.stderr, (case, proc.stderr)
        assert case.needle is None or case.needle in lines[0], (case, lines)
