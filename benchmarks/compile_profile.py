"""Where the test suite's time goes: tracing, lowering and XLA compilation per test.

A pytest plugin, and a summary of what it wrote (`docs/development.md`, "Where the suite's
time goes"):

    PYTHONPATH=benchmarks pytest -p compile_profile        # writes compile-profile/*.json
    python benchmarks/compile_profile.py compile-profile   # per file, per program

Each pytest process (every xdist worker) writes `<dir>/<worker>.json`, `dir` being
`$JAXHOP_COMPILE_PROFILE` (default `compile-profile`): for every test its wall time
(setup, call and teardown) and the seconds JAX reports through `jax.monitoring` while it
ran (jaxpr tracing, lowering to MLIR, XLA compilation, persistent-cache reads), and the
compiled programs that took over half a second, by name. Processes the tests start
(command lines, notebook kernels) are not counted: their time is in the test's wall time
only.
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import sys
import time

import pytest

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read",
}
#: Compilations shorter than this (s) are left out of the per-program list.
PROGRAM_MIN_S = 0.5

_totals = collections.defaultdict(float)
_programs = collections.defaultdict(float)
_rows = []


def _listen(event, duration, **kwargs):
    name = EVENTS.get(event)
    if name is None:
        return
    _totals[name] += duration
    if name == "compile":
        _programs[kwargs.get("fun_name", "?")] += duration


def pytest_configure(config):
    import jax

    jax.monitoring.register_event_duration_secs_listener(_listen)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    # Around setup, call and teardown, in the process that runs the test (not in the
    # pytest-xdist controller, which only hears of it).
    totals, programs = dict(_totals), dict(_programs)
    start = time.perf_counter()
    yield
    row = {"test": item.nodeid, "wall": time.perf_counter() - start}
    for name, seconds in _totals.items():
        row[name] = seconds - totals.get(name, 0.0)
    spent = {fn: s - programs.get(fn, 0.0) for fn, s in _programs.items()}
    row["programs"] = {fn: round(s, 2) for fn, s in spent.items() if s >= PROGRAM_MIN_S}
    _rows.append(row)


def pytest_sessionfinish(session):
    if not _rows:  # the pytest-xdist controller
        return
    folder = os.environ.get("JAXHOP_COMPILE_PROFILE", "compile-profile")
    os.makedirs(folder, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(os.path.join(folder, f"{worker}.json"), "w") as f:
        json.dump({"tests": _rows}, f, indent=1)


def summary(folder: str, top: int = 15) -> str:
    """The per-file and per-program tables of the JSON files in `folder`."""
    rows = []
    for path in sorted(glob.glob(os.path.join(folder, "*.json"))):
        with open(path) as f:
            rows += json.load(f)["tests"]
    if not rows:
        raise SystemExit(f"no profile in {folder}: run pytest -p compile_profile first")
    cols = ("wall", "trace", "lower", "compile")
    files = collections.defaultdict(collections.Counter)
    programs = collections.Counter()
    compilations = collections.Counter()
    for r in rows:
        f = files[r["test"].split("::")[0]]
        f["tests"] += 1
        for c in cols:
            f[c] += r.get(c, 0.0)
        for fn, s in r.get("programs", {}).items():
            programs[fn] += s
            compilations[fn] += 1
    total = collections.Counter()
    for f in files.values():
        total.update(f)
    out = [f"{len(rows)} tests; seconds: " + ", ".join(f"{c} {total[c]:.0f}" for c in cols),
           "", f"{'file':40s} {'tests':>5s} " + " ".join(f"{c:>8s}" for c in cols)]
    for name, f in sorted(files.items(), key=lambda kv: -kv[1]["wall"]):
        out.append(f"{name:40s} {f['tests']:5d} " + " ".join(f"{f[c]:8.1f}" for c in cols))
    out += ["", f"programs compiled for {PROGRAM_MIN_S} s or more, by total seconds:"]
    for fn, s in programs.most_common(top):
        out.append(f"{s:8.1f} s  {compilations[fn]:3d} x  {fn}")
    return "\n".join(out)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", nargs="?", default="compile-profile",
                   help="where the plugin wrote its JSON files")
    p.add_argument("--top", type=int, default=15, help="programs to list")
    args = p.parse_args(argv)
    print(summary(args.folder, args.top))


if __name__ == "__main__":
    sys.exit(main())
