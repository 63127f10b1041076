"""An interrupted sweep resumes from its checkpoint and ends identical to an uninterrupted one."""

import os
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from jaxhop._core.params import disturbance_for
from jaxhop._core.terrain import builtin_terrain
from jaxhop._execution import batches as _execute
from jaxhop._execution.batches import run_batch
from jaxhop._execution.settings import ExecSettings, RunSettings
from jaxhop._planning.plan import build_plan


@pytest.fixture(scope="module")
def setup():
    plan = build_plan(builtin_terrain("flat"), progress=False)
    grid = _execute.sweep_grid(plan.terrain, dy=0.15, dz=0.15)
    init = grid[_execute.in_global_domain(grid, plan.tables(), plan.hopper)]
    return plan, init


def _same(a, b):
    for k in a:
        np.testing.assert_array_equal(np.nan_to_num(a[k], nan=-7.0), np.nan_to_num(b[k],
                                                                                   nan=-7.0))


PAPER = RunSettings(controller="paper")


def _in_chunks(**execution):
    """Chunks of 16 runs, with `execution`'s other settings."""
    return ExecSettings(chunk=16, **execution)


def _interrupt_after(n_saves, monkeypatch, plan, init, execution, **kw):
    """`run_batch` with a checkpoint, interrupted at its `n_saves + 1`-th chunk save (what
    SIGINT does in the middle of a sweep); returns the saved chunks' sizes."""
    saved = []
    real_save = _execute.ChunkStore.save

    def interrupt(self, start, stop, arrays):
        if len(saved) == n_saves:
            raise KeyboardInterrupt
        real_save(self, start, stop, arrays)
        saved.append(stop - start)

    monkeypatch.setattr(_execute.ChunkStore, "save", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_batch(plan, init, execution=execution, **kw)
    monkeypatch.setattr(_execute.ChunkStore, "save", real_save)
    return saved


@pytest.mark.slow
def test_interrupted_sweep_resumes(setup, tmp_path, monkeypatch):
    plan, init = setup
    kw = dict(settings=PAPER, key=jax.random.key(3), disturbance=disturbance_for("sensor"))
    full = run_batch(plan, init, execution=_in_chunks(), **kw)
    _interrupt_after(3, monkeypatch, plan, init, _in_chunks(checkpoint=str(tmp_path)), **kw)

    # A chunk killed while being written leaves only a temporary file; a torn chunk file
    # is ignored and recomputed.
    (chunk_dir,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    files = sorted(chunk_dir.glob("chunk-*.npz"))
    assert len(files) == 3
    files[-1].write_bytes(files[-1].read_bytes()[:50])

    computed = []
    real_jit = _execute.batch_jit

    def counting(*args):
        computed.append(1)
        return real_jit(*args)

    monkeypatch.setattr(_execute, "batch_jit", counting)
    resumed = run_batch(plan, init, execution=_in_chunks(checkpoint=str(tmp_path)), **kw)
    n_chunks = -(-len(init) // 16)
    assert len(computed) == n_chunks - 2  # the two intact chunks were not recomputed
    _same(full, resumed)
    # Other inputs never reuse these chunks.
    computed.clear()
    run_batch(plan, init, execution=_in_chunks(checkpoint=str(tmp_path)),
              **{**kw, "key": jax.random.key(4)})
    assert len(computed) == n_chunks


@pytest.mark.slow
def test_interrupted_pool_sweep_resumes(setup, tmp_path, monkeypatch):
    # The lane pool (SLIP sweeps' executor) saves a chunk when its last run ends; an
    # interrupted pool sweep resumes with only the missing runs and equals the chunked one.
    plan, init = setup
    kw = dict(settings=PAPER, key=jax.random.key(3), disturbance=disturbance_for("sensor"))
    full = run_batch(plan, init, execution=_in_chunks(), **kw)
    saved = _interrupt_after(2, monkeypatch, plan, init,
                             _in_chunks(checkpoint=str(tmp_path), pool=True), **kw)

    computed = []
    real_pool = _execute.pool_runs

    def counting(runs, *args, **kwargs):
        computed.append(len(runs))
        return real_pool(runs, *args, **kwargs)

    monkeypatch.setattr(_execute, "pool_runs", counting)
    resumed = run_batch(plan, init, execution=_in_chunks(checkpoint=str(tmp_path), pool=True),
                        **kw)
    assert computed == [len(init) - sum(saved)] and len(saved) == 2
    _same(full, resumed)


@pytest.mark.slow
def test_sigkill_then_rerun_from_cli(tmp_path):
    env = dict(os.environ, JAXHOP_CACHE=str(tmp_path / "cache"))
    ck = tmp_path / "ck"
    base = [sys.executable, "-m", "jaxhop", "sweep", "--terrain", "flat", "--noise",
            "sensor", "--dy", "0.05", "--dz", "0.05", "--chunk", "8", "--seed", "2"]
    ref = tmp_path / "ref.json"
    subprocess.run(base + ["--json", str(ref)], env=env, check=True, capture_output=True,
                   timeout=900)
    proc = subprocess.Popen(base + ["--checkpoint", str(ck), "--json", str(tmp_path / "x")],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 600
    while time.time() < deadline and not list(ck.glob("*/chunk-*.npz")):
        time.sleep(0.01)
    for sig in (signal.SIGINT, signal.SIGKILL):
        if proc.poll() is None:
            proc.send_signal(sig)
            time.sleep(0.05)
    proc.wait(timeout=60)
    out = tmp_path / "resumed.json"
    subprocess.run(base + ["--checkpoint", str(ck), "--json", str(out)], env=env, check=True,
                   capture_output=True, timeout=900)
    import json

    a, b = json.loads(ref.read_text()), json.loads(out.read_text())
    for k in ("n_initial_conditions", "success_rate", "mean_steps", "max_steps", "failures"):
        assert a[k] == b[k]
