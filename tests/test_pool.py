"""The lane pool's schedule does not depend on its threads' timing."""

import json
import os
import subprocess
import sys

import pytest

_SCRIPT = r"""
import json, time
import jax, numpy as np, jaxhop
from jaxhop._execution import pool as _pool

plan = jaxhop.build_plan(jaxhop.builtin_terrain("flat"), progress=False)
grid = jaxhop.sweep_grid(plan.terrain, dy=0.2, dz=0.2)
init = grid[jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)]
real = _pool._lane_batch


def attempt(seed):
    # Each step's lanes, per device, with a random delay before it: threads that take runs
    # as they get to them would share them out differently on every attempt.
    rng, steps = np.random.default_rng(seed), {}

    def slow(pick, treedef, dev):
        time.sleep(float(rng.uniform(0.0, 0.004)))
        steps.setdefault(str(dev), []).append([int(p[0]) for p in pick])
        return real(pick, treedef, dev)

    _pool._lane_batch = slow
    out = jaxhop.run_batch(plan, init, jaxhop.RunSettings(controller="paper"),
                           key=jax.random.key(2), disturbance=jaxhop.disturbance_for("sensor"),
                           execution=jaxhop.ExecSettings(pool=True))
    _pool._lane_batch = real
    return steps, np.nan_to_num(out["apexes"]).tolist(), out["steps"].tolist()


a, b = attempt(0), attempt(1)
print(json.dumps({"devices": len(jax.devices()), "runs": len(init), "a": a, "b": b}))
"""


@pytest.mark.slow  # starts processes
def test_runs_are_dealt_to_devices_in_a_fixed_order(tmp_path):
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAXHOP_CACHE=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["devices"] == 2 and res["runs"] > 64  # more runs than one step's lanes
    (steps_a, apexes_a, n_a), (steps_b, apexes_b, n_b) = res["a"], res["b"]
    assert sorted(steps_a) == sorted(steps_b) and len(steps_a) == 2
    for dev in steps_a:  # the same lanes, step for step, on each device
        assert steps_a[dev] == steps_b[dev]
    assert apexes_a == apexes_b and n_a == n_b


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
