"""A sweep split over several devices equals the one-device sweep, run by run."""

import json
import os
import subprocess
import sys

import pytest

_SCRIPT = r"""
import json, sys, jax
import numpy as np, jaxhop
plan = jaxhop.build_plan(jaxhop.builtin_terrain("flat"), progress=False)
grid = jaxhop.sweep_grid(plan.terrain, dy=0.1, dz=0.1)
init = grid[jaxhop.in_global_domain(grid, plan.tables(), plan.hopper)]
paper = jaxhop.RunSettings(controller="paper")
r = jaxhop.run_batch(plan, init, paper, key=jax.random.key(5),
                     disturbance=jaxhop.disturbance_for("sensor"))
# The same runs through the lane pool (one host thread per device, lanes refilled
# between strides), which SLIP sweeps use.
p = jaxhop.run_batch(plan, init, paper, key=jax.random.key(5),
                     disturbance=jaxhop.disturbance_for("sensor"),
                     execution=jaxhop.ExecSettings(pool=True))
print(json.dumps({"devices": len(jax.devices()), "code": r["code"].tolist(),
                  "steps": r["steps"].tolist(),
                  "last": np.nan_to_num(r["apexes"][:, -1]).round(12).tolist(),
                  "pool_code": p["code"].tolist(), "pool_steps": p["steps"].tolist(),
                  "pool_policies": p["policies"].tolist(), "policies": r["policies"].tolist(),
                  "pool_feet": np.nan_to_num(p["footholds"]).round(9).tolist(),
                  "feet": np.nan_to_num(r["footholds"]).round(9).tolist()}))
"""


def _run(n_devices):
    # The session's plan cache is shared: both processes load the plan the first built.
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n_devices}")
    out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_two_devices_equal_one():
    # Two devices split the runs as any number does (every n-th run, one host thread per
    # device); each device compiles every program once, so two keep the test short.
    one, two = _run(1), _run(2)
    assert one["devices"] == 1 and two["devices"] == 2
    assert len(one["code"]) > 100
    assert one["code"] == two["code"] and one["steps"] == two["steps"]
    assert one["last"] == two["last"]
    # The lane pool gives the same runs, stride for stride, on one device and on two.
    assert len(set(one["steps"])) > 3  # runs of many lengths: lanes are refilled
    for res in (one, two):
        assert res["pool_code"] == one["code"] and res["pool_steps"] == one["steps"]
        assert res["pool_policies"] == one["policies"] and res["pool_feet"] == one["feet"]
