"""Sweeps over several processes (`jax.distributed`): each runs its share of the chunks."""

import json
import os
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest

import jaxhop
from jaxhop._core.params import disturbance_for
from jaxhop._core.terrain import builtin_terrain
from jaxhop._execution import batches as _execute
from jaxhop._execution.batches import process_chunks, run_batch
from jaxhop._planning.plan import build_plan


@pytest.mark.parametrize("count", [1, 2, 3, 4, 7])
@pytest.mark.parametrize("n_chunks", [0, 1, 2, 5, 18, 101])
def test_shares_partition_the_chunks(monkeypatch, count, n_chunks):
    shares = []
    for index in range(count):
        monkeypatch.setattr(_execute, "_process_info", lambda i=index: (i, count))
        shares.append(list(process_chunks(n_chunks)))
    flat = [c for share in shares for c in share]
    assert flat == list(range(n_chunks))  # disjoint, in order, and covering every chunk
    sizes = [len(s) for s in shares]
    assert max(sizes) - min(sizes) <= 1


@pytest.fixture(scope="module")
def setup():
    plan = build_plan(builtin_terrain("flat"), progress=False)
    grid = _execute.sweep_grid(plan.terrain, dy=0.15, dz=0.15)
    init = grid[_execute.in_global_domain(grid, plan.tables(), plan.hopper)]
    return plan, init


class _Gathered(Exception):
    pass


@pytest.mark.slow
@pytest.mark.parametrize("count", [2, 3, 40])
def test_faked_processes_gather_the_one_process_result(setup, monkeypatch, count):
    """Each faked process computes only its chunks; the gathered batch equals one process's."""
    plan, init = setup
    kw = dict(settings=jaxhop.RunSettings(controller="paper"), key=jax.random.key(7),
              disturbance=disturbance_for("sensor"), execution=jaxhop.ExecSettings(chunk=16))
    whole = run_batch(plan, init, **kw)
    n_chunks = -(-len(init) // 16)
    assert n_chunks >= 3

    computed = {}
    real_jit = _execute.batch_jit
    local = {}

    def counting(apex0, keys, *rest):
        computed.setdefault(index, []).append(np.asarray(apex0)[0].tolist())
        return real_jit(apex0, keys, *rest)

    def capture(tree):  # first pass: record what each process contributes
        local[index] = tree
        raise _Gathered

    monkeypatch.setattr(_execute, "batch_jit", counting)
    monkeypatch.setattr(_execute, "_allgather", capture)
    for index in range(count):
        monkeypatch.setattr(_execute, "_process_info", lambda i=index: (i, count))
        with pytest.raises(_Gathered):
            run_batch(plan, init, **kw)
    # Every chunk ran exactly once, on the process whose share it is.
    for index in range(count):
        monkeypatch.setattr(_execute, "_process_info", lambda i=index: (i, count))
        expected = [init[16 * c].tolist() for c in process_chunks(n_chunks)]
        assert computed.get(index, []) == expected
    assert sum(len(v) for v in computed.values()) == n_chunks
    # Second pass: the collective returns every process's contribution, stacked.
    stacked = {k: np.stack([local[i][k] for i in range(count)]) for k in local[0]}
    monkeypatch.setattr(_execute, "_allgather", lambda tree: stacked)
    for index in range(count):
        monkeypatch.setattr(_execute, "_process_info", lambda i=index: (i, count))
        got = run_batch(plan, init, **kw)
        for k in whole:
            assert got[k].dtype == whole[k].dtype
            np.testing.assert_array_equal(got[k], whole[k])
    # A gather that misses a chunk is an error, never a silent hole.
    broken = dict(stacked, owned=stacked["owned"].copy())
    broken["owned"][:, 0] = 0
    monkeypatch.setattr(_execute, "_allgather", lambda tree: broken)
    with pytest.raises(RuntimeError, match="cover"):
        run_batch(plan, init, **kw)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.heavy
def test_two_real_processes_equal_one(tmp_path):
    """`jaxhop sweep --distributed` on 2 local CPU processes writes the one-process JSON."""
    env = dict(os.environ, JAXHOP_CACHE=str(tmp_path / "cache"), JAXHOP_CPU_DEVICES="1")
    base = [sys.executable, "-m", "jaxhop", "sweep", "--terrain", "flat", "--noise",
            "sensor", "--dy", "0.1", "--dz", "0.1", "--chunk", "16", "--seed", "4"]
    one = tmp_path / "one.json"
    subprocess.run(base + ["--json", str(one)], env=env, check=True, capture_output=True,
                   timeout=900)  # also fills the plan cache that both processes then load
    port = _free_port()
    procs = []
    for k in range(2):
        penv = dict(env, JAX_COORDINATOR_ADDRESS=f"localhost:{port}", JAX_NUM_PROCESSES="2",
                    JAX_PROCESS_ID=str(k))
        procs.append(subprocess.Popen(base + ["--distributed", "--json",
                                              str(tmp_path / f"d{k}.json")], env=penv,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True))
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-2000:]
    assert not (tmp_path / "d1.json").exists()  # only process 0 writes
    a, b = json.loads(one.read_text()), json.loads((tmp_path / "d0.json").read_text())
    a.pop("seconds"), b.pop("seconds")
    assert a == b and a["n_initial_conditions"] > 100
