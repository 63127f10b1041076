"""Batches of runs over devices and processes (`run_batch`), and domain-of-attraction sweeps.

`run_batch` cuts the batch into chunks and runs them with the vmapped run loop
(`jaxhop._runloop`) or, for SLIP, the lane pool (`jaxhop._pool`); chunks go to the visible
JAX devices (one chunk per device, dispatched asynchronously). Under `jax.distributed`
each process runs its share of the chunks (`process_chunks`) and the results are gathered.
A sweep (`docs/decisions.md`, "Sweeps") runs the grid states (`sweep_grid`) in the global
domain (`in_global_domain`) and summarizes them (`summarize`).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ._batching import chunk_index, pow2_at_least
from ._checkpoint import ChunkStore as _ChunkStore
from ._checkpoint import fingerprint
from ._errors import InputError
from ._models import bhop_stride as bhop_stride
from ._models import in_global_domain as in_global_domain
from ._models import model_for
from ._params import Disturbance
from ._plan import Plan, bucketed
from ._pool import pool_runs as _pool_runs
from ._programs import stored_array
from ._progress import Progress
from ._result import Result, failure_counts
from ._runloop import RUN_FIELDS, _batch, run_config, run_init, run_result
from ._runloop import batch_jit as _batch_jit
from ._terrain import Terrain


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


def run_batch(plan: Plan, apex0, *, key=None, true_terrain: Terrain | None = None,
              disturbance: Disturbance | None = None, goal=None, max_steps: int = 60,
              tolerance=None, chunk: int | None = None, progress: bool = False,
              checkpoint: str | None = None, model: str = "bhop", pool: bool | None = None,
              energy_feedback: bool = False, controller: str = "paper"):
    """Run many initial apexes through the reactive controller.

    `controller`: `"paper"` (the paper's, Fig. 8) or `"adaptive"` (disturbance observer,
    wind-aware deadbeat, recovery outside the domains; `docs/decisions.md`, "Adaptive
    controller").

    The batch is cut into chunks of `Model.chunk` runs (smaller batches: the next power of
    two), the last one padded: one compilation serves every sweep. Small chunks also end early: a
    vmapped while loop runs until the longest run of its chunk ends. Chunks are dispatched to
    the visible devices round-robin, asynchronously, and gathered in order. Run `i` draws its
    noise from `fold_in(key, i)`, so outcomes, strides and policies do not depend on the
    chunking or the number of devices. Apex values can differ in the last bits (about
    1e-14), because XLA may vectorise another batch shape differently.

    With `checkpoint` (a directory), each finished chunk is written there atomically under a
    fingerprint of everything the results depend on; a rerun with the same inputs loads the
    finished chunks and computes only the rest, so an interrupted sweep loses at most the
    chunks in flight.

    With `pool` (the default for `model="slip"`), the runs go through a pool of
    `pool_lanes()` lanes per device instead, refilled between strides (`jaxhop._pool`): no run
    waits for a longer one. Chunks then only set what is checkpointed and what each
    `jax.distributed` process runs; results are the same run for run.

    Returns:
        dict of NumPy arrays: `code, steps, apexes, footholds, policies, recoveries`.
    """
    apex0 = np.atleast_2d(np.asarray(apex0, float))
    n = apex0.shape[0]
    key = jax.random.key(0) if key is None else key
    model = model_for(model)
    tables = plan.tables(slip=not model.instant_stance)
    true_terrain = plan.terrain if true_terrain is None else true_terrain
    disturbance = Disturbance() if disturbance is None else disturbance
    config = run_config(plan.goal if goal is None else goal, tolerance, max_steps, model,
                        controller, energy_feedback)
    devices = jax.local_devices()
    if chunk is None:
        full = model.chunk
        chunk = full if n >= full else pow2_at_least(n)
    store = None
    if checkpoint is not None:
        store = _ChunkStore(checkpoint, fingerprint(plan, apex0, key, true_terrain,
                                                     disturbance, config, chunk))
    pending = []
    consts = (*bucketed(tables, true_terrain), plan.hopper, disturbance, config)
    mine = process_chunks(-(-n // chunk))
    if model.pooled if pool is None else pool:
        return _run_pool(apex0, key, consts, config, n, chunk, mine, store, progress)
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
        pending.append((start, stop, _batch_jit(*args, *on_device[dev])))
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
        _batch, jnp.zeros((1, 3)), key, np.zeros(1, int), *consts))


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


def _run_pool(apex0, key, consts, config, n, chunk, mine, store, progress):
    """`run_batch` for SLIP: chunks (checkpointing, `jax.distributed` shares) as there, the
    runs themselves through `_pool_runs`."""
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
    bar = Progress(len(todo), "runs", "run", enabled=progress)

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
        _pool_runs(todo, apex0, key, consts, config, on_done)
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


def slip_verified(apexes, plan: Plan, *, key=None, goal=None, max_steps: int = 60,
                  tolerance=None, controller: str = "paper") -> np.ndarray:
    """Which apexes of the plan's global domain lie in its SLIP domain (`docs/decisions.md`,
    "SLIP domain of a sweep"): the SLIP controller's first stride from there, without
    disturbance on the plan's map, completes and ends in the global domain again.

    The stride is the SLIP lane pool's, with the run settings of the sweep it serves
    (`key, goal, max_steps, tolerance, controller`, as `run_batch`), so that both use one
    compiled program. The strides' ends are kept on disk for the same states, plan and
    settings (`jaxhop._programs.stored_array`): a second sweep of a plan skips them.
    """
    apexes = np.atleast_2d(np.asarray(apexes, float))
    n = apexes.shape[0]
    key = jax.random.key(0) if key is None else key
    config = run_config(plan.goal if goal is None else goal, tolerance, max_steps, "slip",
                        controller)
    tables = plan.tables(slip=True)
    consts = (*bucketed(tables, plan.terrain), plan.hopper, Disturbance(), config)

    def first_strides():
        nxt = np.full((n, 3), np.nan)

        def on_done(run, fields):
            nxt[run] = fields[RUN_FIELDS.index("apexes")][1]

        if n:
            _pool_runs(list(range(n)), apexes, key, consts, config, on_done, strides=1)
        return nxt

    nxt = stored_array("slip-verified", first_strides, (apexes, key, consts))
    completed = np.all(np.isfinite(nxt), axis=1)
    return completed & in_global_domain(np.where(completed[:, None], nxt, 0.0), tables,
                                        plan.hopper)


def sweep_initial(plan: Plan, true_terrain: Terrain | None = None, ydot0: float = 0.5,
                  dy: float = 0.05, dz: float = 0.05, runs: int | None = None,
                  verify: bool | dict = False) -> np.ndarray:
    """The initial states of a sweep: the grid states (`sweep_grid`) in the global domain
    (with `verify`, in its SLIP domain: `slip_verified`, with the run settings in `verify`
    when it is a dict), `runs` of them evenly spaced when given.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    grid = sweep_grid(plan.terrain if true_terrain is None else true_terrain, ydot0, dy, dz)
    if grid.shape[0] > MAX_GRID:
        raise InputError(f"dy/dz: the grid would exceed {MAX_GRID} initial states")
    initial = grid[in_global_domain(grid, plan.tables(), plan.hopper)]
    if initial.shape[0] and verify:
        initial = initial[slip_verified(initial, plan,
                                        **(verify if isinstance(verify, dict) else {}))]
    if initial.shape[0] == 0:
        raise InputError("no grid state lies in the global domain (is the goal reachable?)")
    return evenly_spaced(initial, runs)


def sweep(plan: Plan, *, initial=None, key=None, true_terrain: Terrain | None = None,
          disturbance: Disturbance | None = None, ydot0: float = 0.5, dy: float = 0.05,
          dz: float = 0.05, max_steps: int = 60, tolerance=None, chunk: int | None = None,
          checkpoint: str | None = None, model: str = "bhop", progress: bool = False,
          controller: str = "paper", runs: int | None = None, verify: bool | None = None):
    """Domain-of-attraction sweep: run every grid state inside the global domain.

    The grid (`sweep_grid`) covers `true_terrain` (default: the plan's map); `initial`
    replaces it. `runs`: only that many of the grid's states, evenly spaced
    (`sweep_initial`). `verify`: only the states in the plan's SLIP domain
    (`slip_verified`; default: for `model="slip"`). The other arguments are `run_batch`'s.

    Returns:
        `(summary, initial_states, result)`.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    t0 = time.perf_counter()
    if verify is None:
        verify = not model_for(model).instant_stance
    if initial is None:
        settings = dict(key=key, max_steps=max_steps, tolerance=tolerance,
                        controller=controller)
        initial = sweep_initial(plan, true_terrain, ydot0, dy, dz, runs,
                                settings if verify else False)
    result = run_batch(plan, initial, key=key, true_terrain=true_terrain,
                       disturbance=disturbance, max_steps=max_steps, tolerance=tolerance,
                       chunk=chunk, progress=progress, checkpoint=checkpoint, model=model,
                       controller=controller)
    return summarize(result, time.perf_counter() - t0), initial, result
