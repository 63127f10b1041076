"""The same `jaxhop sweep` command with the same seed writes the same JSON (timings aside),
in one process or another, on one device or on four."""

import json
import os
import subprocess
import sys

import pytest

from jaxhop._cli.main import main

COMMAND = ["sweep", "--terrain", "flat", "--noise", "sensor", "--seed", "11", "--dy", "0.1",
           "--dz", "0.1", "--chunk", "32"]
TIMING_KEYS = {"seconds"}


def _load(path) -> dict:
    data = json.loads(path.read_text())
    assert data["n_initial_conditions"] > 100  # several chunks of 32
    return {k: v for k, v in data.items() if k not in TIMING_KEYS}


@pytest.mark.slow
def test_same_command_twice_same_json(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(COMMAND + ["--json", str(a)]) == 0
    assert main(COMMAND + ["--json", str(b)]) == 0
    assert _load(a) == _load(b)


_FOUR = """
import sys, jax
from jaxhop._cli.main import main
rc = main(sys.argv[1:])
print("devices", len(jax.devices()))
sys.exit(rc)
"""


# `tests/test_devices.py` checks the same runs on one device and on two, run by run, in CI;
# this end-to-end check of the command's JSON on four devices runs with the heavy tests.
@pytest.mark.heavy
@pytest.mark.slow
def test_four_forced_devices_same_json(tmp_path):
    one = tmp_path / "one.json"
    assert main(COMMAND + ["--json", str(one)]) == 0
    four = tmp_path / "four.json"
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAXHOP_CPU_DEVICES="4")  # the plan cache (JAXHOP_CACHE) is shared
    out = subprocess.run([sys.executable, "-c", _FOUR, *COMMAND, "--json", str(four)],
                         env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "devices 4" in out.stdout
    assert _load(one) == _load(four)
