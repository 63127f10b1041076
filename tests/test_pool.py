"""The lane pool's schedule does not depend on its threads' timing."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

_SCRIPT = r"""
import json, time
import jax, numpy as np, jaxhop
from jaxhop._core import programs
from jaxhop._execution import pool as _pool

plan = jaxhop.build_plan(jaxhop.builtin_terrain("flat"), progress=False)
grid = jaxhop.sweep_grid(plan.terrain, dy=0.2, dz=0.2)
init = grid[jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)]
real = _pool._lane_batch
planning = set(programs._LOADED)  # the plan's stages, saved programs too


def attempt(seed):
    # Each step's lanes, per thread (named by the parity of its runs: the threads' devices
    # are all the first one on a CPU), with a random delay before it: threads that take
    # runs as they get to them would share them out differently on every attempt.
    rng, steps = np.random.default_rng(seed), {}

    def slow(pick, treedef, dev):
        time.sleep(float(rng.uniform(0.0, 0.004)))
        steps.setdefault(str(pick[0][0] % 2), []).append([int(p[0]) for p in pick])
        return real(pick, treedef, dev)

    _pool._lane_batch = slow
    out = jaxhop.run_batch(plan, init, jaxhop.RunSettings(controller="paper"),
                           key=jax.random.key(2), disturbance=jaxhop.disturbance_for("sensor"),
                           execution=jaxhop.ExecSettings(pool=True))
    _pool._lane_batch = real
    return steps, np.nan_to_num(out["apexes"]).tolist(), out["steps"].tolist()


a, b = attempt(0), attempt(1)
# The pool step's compiled executables (one per device it ran on).
compiled = sum(f._cache_size() for k, f in programs._LOADED.items() if k not in planning)
print(json.dumps({"devices": len(jax.devices()), "runs": len(init), "a": a, "b": b,
                  "compiled": compiled}))
"""


@pytest.mark.slow  # starts processes
def test_runs_are_dealt_to_the_threads_in_a_fixed_order_and_compiled_once(tmp_path):
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAXHOP_CACHE=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["devices"] == 2 and res["runs"] > 64  # more runs than one step's lanes
    (steps_a, apexes_a, n_a), (steps_b, apexes_b, n_b) = res["a"], res["b"]
    assert sorted(steps_a) == sorted(steps_b) and len(steps_a) == 2
    for thread in steps_a:  # the same lanes, step for step, in each thread
        assert steps_a[thread] == steps_b[thread]
    assert apexes_a == apexes_b and n_a == n_b
    # Two CPU devices, two threads, one compilation of the step (both threads on one device).
    assert res["compiled"] == 1


def test_pool_threads_share_the_first_cpu_device():
    from jaxhop._execution.pool import worker_devices

    cpus, gpus = [_Device("cpu"), _Device("cpu")], [_Device("gpu"), _Device("gpu")]
    assert worker_devices(cpus) == [cpus[0], cpus[0]]
    assert worker_devices(gpus) == gpus


class _Device:
    def __init__(self, platform):
        self.platform = platform


def test_lane_count_follows_the_platform_and_the_override(monkeypatch):
    from jaxhop._execution import pool as _pool

    monkeypatch.delenv("JAXHOP_POOL_LANES", raising=False)
    assert _pool.pool_lanes(_Device("cpu")) == 32
    assert _pool.pool_lanes(_Device("gpu")) == 4096
    monkeypatch.setenv("JAXHOP_POOL_LANES", "64")
    assert _pool.pool_lanes(_Device("gpu")) == 64
    for bad in ("0", "-3", "many"):
        monkeypatch.setenv("JAXHOP_POOL_LANES", bad)
        try:
            _pool.pool_lanes(_Device("cpu"))
        except ValueError as err:
            assert "JAXHOP_POOL_LANES" in str(err)
        else:
            raise AssertionError(f"{bad!r} was accepted")


def test_a_step_takes_the_longest_waiting_run_and_its_nearest_neighbours():
    from jaxhop._execution.pool import _choose

    rng = np.random.default_rng(3)
    apex0 = rng.uniform(0.0, 10.0, (40, 3))
    # [run, carry leaves (the apex first), fresh, turn]: runs 0-19 in progress, 20-39 fresh.
    moved = apex0 + 1.0
    active = [[r, [moved[r]], False, int(rng.integers(0, 5))] for r in range(20)]
    active += [[r, None, True, 5] for r in range(20, 40)]
    y = np.array([moved[r, 0] if r < 20 else apex0[r, 0] for r in range(40)])
    assert _choose(active[:8], 8, apex0) == list(range(8))  # all fit: every one steps
    got = _choose(active, 8, apex0)
    head = min(range(40), key=lambda i: (active[i][3], i))
    # Brute force: the head, then the 7 others nearest to it in y.
    others = sorted((abs(y[i] - y[head]), i) for i in range(40) if i != head)[:7]
    assert got == sorted([head] + [i for _, i in others])
    assert got == sorted(got) and len(set(got)) == 8
