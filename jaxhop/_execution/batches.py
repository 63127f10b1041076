"""Batches of runs over devices and processes (`run_batch`), and domain-of-attraction sweeps.

`run_batch` cuts the batch into chunks and runs them with the vmapped run loop
(`runloop.py`) or, for SLIP, the lane pool (`pool.py`); chunks go to the visible JAX
devices (one chunk per device, dispatched asynchronously). Under `jax.distributed`
each process runs its share of the chunks (`process_chunks`) and the results are gathered.
A sweep (`docs/decisions.md`, "Sweeps") runs the grid states (`sweep_grid`) in the global
domain (`in_global_domain`) and summarizes them (`summarize`).
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._control.decisions import in_global_domain, model_for
from .._control.runloop import RUN_FIELDS, batch_jit, run_chunk, run_init, run_result
from .._core.batching import chunk_index, pow2_at_least
from .._core.errors import InputError
from .._core.params import Disturbance
from .._core.programs import stored_array
from .._core.progress import Progress
from .._core.result import Result, failure_counts
from .._core.terrain import Terrain
from .._planning.plan import Plan, bucketed
from .checkpoint import ChunkStore, fingerprint
from .pool import pool_runs
from .settings import ExecSettings, RunSettings, SweepGrid

# The smallest chunk of a vmapped batch: a BHop run of one apex in a chunk of 32 takes 25 ms
# warm against 15 ms alone (2-core CPU, jax 0.10.2), while each chunk size compiles a
# program of its own (9-10 s).
SMALL_CHUNK = 32


def sweep_grid(terrain: Terrain, ydot0: float = 0.5, dy: float = 0.05, dz: float = 0.05,
               z_range: tuple[float, float] | None = None) -> np.ndarray:
    """Initial apex states on a grid in `(y, z)` over the terrain (`docs/decisions.md`,
    "Sweeps")."""
    y0, y1 = terrain.y_range
    h = np.asarray(terrain.heights)
    if z_range is None:
        z_range = (float(h.min()) + 1.0, float(h.max()) + 2.6)
    ys = np.arange(y0, y1 + 1e-9, dy)
    zs = np.arange(z_range[0], z_range[1] + 1e-9, dz)
    Y, Z = np.meshgrid(ys, zs, indexing="ij")
    return np.stack([Y.ravel(), Z.ravel(), np.full(Y.size, ydot0)], axis=1)


def run_batch(plan: Plan, apex0, settings: RunSettings | None = None, *, key=None,
              true_terrain: Terrain | None = None, disturbance: Disturbance | None = None,
              execution: ExecSettings | None = None):
    """Run many initial apexes through the reactive controller.

    `settings` (`RunSettings`): model, controller (default `"adaptive"`), goal, tolerance,
    stride limit. `key`: the runs' noise (run `i` draws from `fold_in(key, i)`; default
    `key(0)`). `true_terrain`: the map the runs hop on (default: the plan's).
    `disturbance`: wind, sensor, ground and landing noise (default: none). `execution`
    (`ExecSettings`): chunks, lanes, devices, checkpoints, progress bar.

    The batch is cut into chunks of `Model.chunk` runs (smaller batches: the next power of
    two, at least `SMALL_CHUNK`), the last one padded with copies of the batch's last run: one
    compilation serves every sweep, and a handful every smaller batch. Small chunks also end
    early: a vmapped while loop runs until the longest run of its chunk ends, and the copies
    end with the run they copy. Chunks are dispatched to
    the visible devices round-robin, asynchronously, and gathered in order. Run `i` draws its
    noise from `fold_in(key, i)`, so outcomes, strides and policies do not depend on the
    chunking or the number of devices. Apex values can differ in the last bits (about
    1e-14), because XLA may vectorise another batch shape differently.

    With `execution.checkpoint` (a directory), each finished chunk is written there
    atomically under a fingerprint of everything the results depend on; a rerun with the
    same inputs loads the finished chunks and computes only the rest, so an interrupted
    sweep loses at most the chunks in flight.

    With `execution.pool` (the default for SLIP), the runs go through a pool of
    `pool_lanes()` lanes per device instead, refilled between strides (`pool.py`): no run
    waits for a longer one. Chunks then only set what is checkpointed and what each
    `jax.distributed` process runs; results are the same run for run.

    Returns:
        dict of NumPy arrays: `code, steps, apexes, footholds, policies, recoveries`.
    """
    settings = RunSettings() if settings is None else settings
    execution = ExecSettings() if execution is None else execution
    chunk, checkpoint, progress = execution.chunk, execution.checkpoint, execution.progress
    apex0 = np.atleast_2d(np.asarray(apex0, float))
    n = apex0.shape[0]
    key = jax.random.key(0) if key is None else key
    model = model_for(settings.model)
    tables = plan.tables(slip=not model.instant_stance)
    true_terrain = plan.terrain if true_terrain is None else true_terrain
    disturbance = Disturbance() if disturbance is None else disturbance
    config = settings.config(plan.goal)
    devices = list(jax.local_devices() if execution.devices is None else execution.devices)
    if chunk is None:
        full = model.chunk
        chunk = full if n >= full else min(full, max(SMALL_CHUNK, pow2_at_least(n)))
    store = None
    if checkpoint is not None:
        store = ChunkStore(checkpoint, fingerprint(plan, apex0, key, true_terrain,
                                                    disturbance, config, chunk))
    pending = []
    consts = (*bucketed(tables, true_terrain), plan.hopper, disturbance, config)
    mine = process_chunks(-(-n // chunk))
    if model.pooled if execution.pool is None else execution.pool:
        return _run_pool(apex0, key, consts, n, chunk, mine, store, execution)
    on_device = {}  # the plan's tables are large: copy them to each device once, not per chunk
    for i, start in enumerate(range(0, n, chunk)):
        if i not in mine:
            continue  # another process's chunk (jax.distributed)
        stop = min(start + chunk, n)
        done = store.load(start, stop) if store else None
        if done is not None:
            pending.append((start, stop, done))
            continue
        idx = chunk_index(start, chunk, n)
        dev = devices[i % len(devices)]
        if dev not in on_device:
            on_device[dev] = jax.device_put(consts, dev)
        args = jax.device_put((apex0[idx], key, idx), dev)
        pending.append((start, stop, batch_jit(*args, *on_device[dev])))
    parts = {k: [] for k in RUN_FIELDS}
    bar = Progress(n, "runs", "run", enabled=progress)
    for start, stop, out in pending:
        arrays = [np.asarray(arr)[: stop - start] for arr in out]
        if store:
            store.save(start, stop, arrays)
        for name, arr in zip(parts, arrays):
            parts[name].append(arr)
        bar.update(stop - start)
    bar.close()
    return _combine(parts, [(a, b) for a, b, _ in pending], n, lambda: jax.eval_shape(
        run_chunk, jnp.zeros((1, 3)), key, np.zeros(1, int), *consts))


def _process_info() -> tuple[int, int]:
    """`(jax.process_index(), jax.process_count())`: a seam for tests."""
    return jax.process_index(), jax.process_count()


def process_chunks(n_chunks: int) -> range:
    """The chunks of a batch this process runs: its contiguous share, by process index.

    One process (the usual case) runs them all. Under `jax.distributed`, process `p` of `P`
    runs chunks `[n_chunks p // P, n_chunks (p + 1) // P)`: the shares are disjoint, cover
    every chunk and differ in size by at most one.
    """
    index, count = _process_info()
    return range(n_chunks * index // count, n_chunks * (index + 1) // count)


def _allgather(tree: dict) -> dict:
    from jax.experimental import multihost_utils

    return {k: np.asarray(v) for k, v in multihost_utils.process_allgather(tree).items()}


def _combine(parts: dict, spans: list, n: int, template) -> dict:
    """The whole batch from this process's chunks (`spans`) and, under `jax.distributed`,
    every other process's, gathered with `process_allgather`; `template()` gives the
    field shapes for a process that ran no chunk."""
    if _process_info()[1] == 1:
        return {k: np.concatenate(v) for k, v in parts.items()}
    like = ({k: v[0] for k, v in parts.items()} if spans
            else dict(zip(RUN_FIELDS, template())))
    full = {k: np.zeros((n,) + tuple(like[k].shape[1:]), like[k].dtype) for k in RUN_FIELDS}
    owned = np.zeros(n, np.int32)
    for j, (start, stop) in enumerate(spans):
        owned[start:stop] = 1
        for k in RUN_FIELDS:
            full[k][start:stop] = parts[k][j]
    every = _allgather({"owned": owned, **full})
    if not np.all(every["owned"].sum(axis=0) == 1):
        raise RuntimeError("jax.distributed: the processes' chunks do not cover the batch")
    owner = np.argmax(every["owned"], axis=0)
    return {k: every[k][owner, np.arange(n)] for k in RUN_FIELDS}


def _run_pool(apex0, key, consts, n, chunk, mine, store, execution: ExecSettings):
    """`run_batch` for SLIP: chunks (checkpointing, `jax.distributed` shares) as there, the
    runs themselves through `pool_runs`."""
    config = consts[-1]
    spans = [(start, min(start + chunk, n)) for i, start in enumerate(range(0, n, chunk))
             if i in mine]
    shapes = jax.eval_shape(run_result, jax.eval_shape(run_init, jnp.zeros(3), config),
                            config)
    out = {k: np.zeros((n,) + s.shape, s.dtype) for k, s in zip(RUN_FIELDS, shapes)}
    left = {}
    for start, stop in spans:
        done = store.load(start, stop) if store else None
        if done is None:
            left[start] = stop - start
        else:
            for name, arr in zip(RUN_FIELDS, done):
                out[name][start:stop] = arr
    todo = [r for start in left for r in range(start, start + left[start])]
    bar = Progress(len(todo), "runs", "run", enabled=execution.progress)

    def on_done(run, fields):
        for name, value in zip(RUN_FIELDS, fields):
            out[name][run] = value
        start = run - run % chunk
        left[start] -= 1
        if left[start] == 0 and store:
            stop = min(start + chunk, n)
            store.save(start, stop, [out[name][start:stop] for name in RUN_FIELDS])
        bar.update(1)

    if todo:
        pool_runs(todo, apex0, key, consts, config, on_done, execution.lanes,
                  devices=execution.devices)
    bar.close()
    parts = {k: [out[k][a:b] for a, b in spans] for k in RUN_FIELDS}
    return _combine(parts, spans, n, lambda: [np.zeros((1,) + s.shape, s.dtype)
                                              for s in shapes])


def summarize(result: dict, seconds: float) -> dict:
    """The summary of a sweep (the keys of `jaxhop sweep --json`)."""
    code, steps = result["code"], result["steps"]
    n = int(code.size)
    ok = code == Result.SUCCESS
    rec = result.get("recoveries", np.zeros(n, int))
    return {
        "n_initial_conditions": n,
        "success_rate": float(ok.mean()) if n else 0.0,
        "mean_steps": float(steps[ok].mean()) if ok.any() else 0.0,
        "max_steps": int(steps[ok].max()) if ok.any() else 0,
        "failures": failure_counts(code),
        # failed at the first apex or in the first stride, before any observation
        "first_stride_failures": int((~ok & (steps <= 1)).sum()),
        "recoveries": {"total": int(rec.sum()), "mean": float(rec.mean()) if n else 0.0,
                       "runs": int((rec > 0).sum())},
        "seconds": round(seconds, 3),
    }


MAX_GRID = 2_000_000


def evenly_spaced(initial: np.ndarray, runs: int | None) -> np.ndarray:
    """`runs` states of `initial` at evenly spaced positions (first and last included; all
    of them when `runs` is None or not smaller)."""
    initial = np.asarray(initial)
    if runs is None or runs >= initial.shape[0]:
        return initial
    if runs < 1:
        raise InputError(f"runs: must be at least 1, got {runs}")
    return initial[np.round(np.linspace(0, initial.shape[0] - 1, runs)).astype(int)]


def slip_verified(apexes, plan: Plan, settings: RunSettings | None = None, *,
                  key=None) -> np.ndarray:
    """Which apexes of the plan's global domain lie in its SLIP domain (`docs/decisions.md`,
    "SLIP domain of a sweep"): the SLIP controller's first stride from there, without
    disturbance on the plan's map, completes and ends in the global domain again.

    The stride is the SLIP lane pool's, with the run settings of the sweep it serves
    (`settings` and `key`, as `run_batch`'s, the model always SLIP), so that both use one
    compiled program. The strides' ends are kept on disk for the same states, plan and
    settings (`jaxhop._core.programs.stored_array`): a second sweep of a plan skips them.
    """
    apexes = np.atleast_2d(np.asarray(apexes, float))
    n = apexes.shape[0]
    key = jax.random.key(0) if key is None else key
    settings = RunSettings() if settings is None else settings
    config = dataclasses.replace(settings, model="slip").config(plan.goal)
    tables = plan.tables(slip=True)
    consts = (*bucketed(tables, plan.terrain), plan.hopper, Disturbance(), config)

    def first_strides():
        nxt = np.full((n, 3), np.nan)

        def on_done(run, fields):
            nxt[run] = fields[RUN_FIELDS.index("apexes")][1]

        if n:
            pool_runs(list(range(n)), apexes, key, consts, config, on_done, strides=1)
        return nxt

    nxt = stored_array("slip-verified", first_strides, (apexes, key, consts))
    completed = np.all(np.isfinite(nxt), axis=1)
    return completed & in_global_domain(np.where(completed[:, None], nxt, 0.0), tables,
                                        plan.hopper)


def sweep_initial(plan: Plan, grid: SweepGrid | None = None, *,
                  true_terrain: Terrain | None = None, settings: RunSettings | None = None,
                  key=None) -> np.ndarray:
    """The initial states of a sweep (`SweepGrid`): the grid states (`sweep_grid`) over
    `true_terrain` (default: the plan's map) in the global domain; with `grid.verify` (by
    default for the SLIP model of `settings`), only those in the plan's SLIP domain
    (`slip_verified`, run with `settings` and `key`); `grid.runs` of them evenly spaced.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    grid = SweepGrid() if grid is None else grid
    settings = RunSettings() if settings is None else settings
    verify = grid.verify
    if verify is None:
        verify = not model_for(settings.model).instant_stance
    states = sweep_grid(plan.terrain if true_terrain is None else true_terrain, grid.ydot0,
                        grid.dy, grid.dz)
    if states.shape[0] > MAX_GRID:
        raise InputError(f"dy/dz: the grid would exceed {MAX_GRID} initial states")
    initial = states[in_global_domain(states, plan.tables(), plan.hopper)]
    if initial.shape[0] and verify:
        initial = initial[slip_verified(initial, plan, settings, key=key)]
    if initial.shape[0] == 0:
        raise InputError("no grid state lies in the global domain (is the goal reachable?)")
    return evenly_spaced(initial, grid.runs)


def sweep(plan: Plan, settings: RunSettings | None = None, *, initial=None, key=None,
          true_terrain: Terrain | None = None, disturbance: Disturbance | None = None,
          execution: ExecSettings | None = None):
    """Domain-of-attraction sweep: run every grid state inside the global domain.

    `initial`: the initial apexes, an array of `(y, z, ydot)`, or the `SweepGrid` they are
    taken from (`sweep_initial`; default `SweepGrid()`, over `true_terrain`). The other
    arguments are `run_batch`'s.

    Returns:
        `(summary, initial_states, result)`.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    t0 = time.perf_counter()
    if initial is None or isinstance(initial, SweepGrid):
        initial = sweep_initial(plan, initial, true_terrain=true_terrain, settings=settings,
                                key=key)
    result = run_batch(plan, initial, settings, key=key, true_terrain=true_terrain,
                       disturbance=disturbance, execution=execution)
    return summarize(result, time.perf_counter() - t0), initial, result
