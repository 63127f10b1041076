"""Reactive execution (Fig. 8), disturbances (section VI-C) and domain-of-attraction sweeps.

`run_one` handles one initial apex; `run_batch` vmaps it and splits the batch over the
visible JAX devices (one chunk per device, dispatched asynchronously). Under `jax.distributed`
each process runs its share of the chunks (`process_chunks`) and the results are gathered.
"""

from __future__ import annotations

import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from ._bhop import ascent, deadbeat_bhop, stance
from ._errors import InputError
from ._flight import (
    COLLISION,
    FAILURE_NAMES,
    MAX_STEPS,
    OK,
    OUTSIDE_DOMAIN,
    RUNNING,
    SOLVER,
    SUCCESS,
    liftoff_clear,
    touchdown,
)
from ._params import Disturbance, Hopper
from ._plan import Plan, PlanTables
from ._policies import candidate_situated
from ._terrain import Terrain


def bhop_stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0):
    """One BHop stride on the terrain: descent, touchdown, stance, rise to the next apex.

    Returns:
        `(next_apex, code, foothold)`: `code` is `OK` or a failure; `foothold = (y, h)`.
    """
    code, block, _, y_foot, v_td = touchdown(apex, jnp.array([0.0, -hopper.rho0]), terrain,
                                             hopper, wind)
    h = terrain.heights[block]
    y_lo, v_lo = stance(y_foot, v_td, u)
    clear = liftoff_clear(y_foot, y_lo, v_lo, h, terrain, hopper, wind)
    nxt = ascent(y_lo, v_lo, h, hopper, wind)
    code = jnp.where(code == OK, jnp.where(clear, OK, COLLISION), code)
    return nxt, code, jnp.stack([y_foot, h])


def first_match(apex, tables: PlanTables, hopper: Hopper):
    """The first deployed policy whose domain contains `apex`.

    Only the first deployed instantiated policy of each situated policy can ever be the
    first match (they share a domain), so the order reduces to `best_pos` per situated
    policy; the situated candidates are those on the segment of the nominal touchdown.

    Returns:
        `(found, situated, instantiated)`.
    """
    ids, pos = _match_positions(apex, tables, hopper)
    k = jnp.argmin(pos)
    found = pos[k] < _NO_MATCH
    return found, ids[k], tables.best_inst[ids[k]]


_NO_MATCH = jnp.iinfo(jnp.int32).max


def _match_positions(apex, tables: PlanTables, hopper: Hopper):
    """Situated candidates near the apex and their deployment position (`_NO_MATCH` where
    the domain does not contain the apex)."""
    ids, inside = candidate_situated(apex, tables.table, tables.templates, tables.terrain,
                                     hopper)
    return ids, jnp.where(inside, tables.best_pos[ids], _NO_MATCH)


MODELS = ("bhop", "slip")


def decide(apex, tables: PlanTables, hopper: Hopper, model: str = "bhop"):
    """Controls for one measured apex: first match, deadbeat to its goal, clip to its limits.

    `model = "bhop"`: BHop deadbeat (eqs 25-29) clipped to the template's limits;
    `"slip"`: the position-aware SLIP deadbeat (eqs 12-16) within the SLIP limits.

    Returns:
        `(found, u, instantiated)`.
    """
    if model == "slip":
        return decide_slip(apex, tables, hopper)
    found, s, a = first_match(apex, tables, hopper)
    nt = tables.templates.n
    h = tables.table.centre[s // nt, 1]
    tmpl = tables.templates.row(s % nt)
    u = deadbeat_bhop(apex, tables.goals[a], h, hopper)
    lo = jnp.stack([tmpl.dy_lo, tmpl.th_lo, tmpl.k_lo])
    hi = jnp.stack([tmpl.dy_hi, tmpl.th_hi, tmpl.k_hi])
    u = jnp.where(jnp.isfinite(u), u, hi)
    return found, jnp.clip(u, lo, hi), a


# SLIP decisions (docs/decisions.md, "SLIP on BHop plans"): the deadbeat is tried on the
# first SLIP_CANDIDATES matching policies in deployment order; the first whose predicted
# apex lands within SLIP_ACCEPT of its goal wins, else the smallest scaled miss.
SLIP_CANDIDATES = 2
SLIP_ACCEPT = (0.05, 0.05, 0.05)


def decide_slip(apex, tables: PlanTables, hopper: Hopper, n_candidates: int = SLIP_CANDIDATES):
    """SLIP controls for one measured apex: the deadbeat on the best SLIP-reachable match.

    The BHop plan's domains and goals ignore what the SLIP stance cannot do (the paper's
    eqs 35-37 only approximate it), so the goal of the first match may be out of one SLIP
    stride's reach (e.g. stopping at the global goal from a foothold a few cm off). The
    controller runs the SLIP deadbeat (eqs 12-16) for the `n_candidates` highest-priority
    matching policies, predicts each stride over the policy's foothold height, and takes the
    first in deployment order whose prediction lies within `SLIP_ACCEPT` of its goal; when
    none does, the one with the smallest miss relative to `SLIP_ACCEPT`.

    Returns:
        `(found, u, instantiated)`.
    """
    from ._slip import slip_stride
    from ._slip_deadbeat import SEARCH_TOL, deadbeat_slip

    ids, pos = _match_positions(apex, tables, hopper)
    neg, k = jax.lax.top_k(-pos, n_candidates)
    valid = -neg < _NO_MATCH
    sit = ids[k]
    inst = tables.best_inst[sit]
    goals = tables.goals[inst]
    h = tables.table.centre[sit // tables.templates.n, 1]

    def one(goal, h_):
        u, ok = deadbeat_slip(apex, goal, h_, hopper, terrain=tables.terrain)
        pred, code, _ = slip_stride(apex, u, tables.terrain, hopper, 0.0, SEARCH_TOL)
        miss = jnp.max(jnp.abs(pred - goal) / jnp.asarray(SLIP_ACCEPT))
        return u, jnp.where((code == OK) & jnp.all(jnp.isfinite(pred)), miss, jnp.inf)

    u, miss = jax.vmap(one)(goals, h)
    miss = jnp.where(valid, miss, jnp.inf)
    good = miss <= 1.0
    pick = jnp.where(jnp.any(good), jnp.argmax(good), jnp.argmin(miss))
    # No candidate at all (outside every domain) or no completed stride: the first match.
    pick = jnp.where(jnp.isfinite(miss[pick]), pick, 0)
    return valid[0], u[pick], inst[pick]


def stride(apex, u, terrain: Terrain, hopper: Hopper, wind=0.0, model: str = "bhop",
           energy=None):
    """One stride of the chosen model on the terrain: `(next_apex, code, foothold)`.

    `energy` (SLIP only): the target apex energy for `bottom_kd`.
    """
    if model == "slip":
        from ._slip import slip_stride

        return slip_stride(apex, u, terrain, hopper, wind, energy=energy)
    return bhop_stride(apex, u, terrain, hopper, wind)


class RunConfig(eqx.Module):
    """Execution settings."""

    goal: jnp.ndarray
    tolerance: jnp.ndarray = eqx.field(default_factory=lambda: jnp.full(3, 0.05))
    max_steps: int = eqx.field(static=True, default=60)
    model: str = eqx.field(static=True, default="bhop")
    energy_feedback: bool = eqx.field(static=True, default=False)


def _run_init(apex0, config: RunConfig):
    """The carry of a run at its first apex: `(apex, code, steps, k, buffers)`."""
    n = config.max_steps
    apex0 = jnp.asarray(apex0, float)
    buffers = (jnp.full((n + 1, 3), jnp.nan).at[0].set(apex0), jnp.full((n, 2), jnp.nan),
               jnp.full((n,), -1, jnp.int32))
    return (apex0, jnp.asarray(RUNNING), jnp.asarray(0, jnp.int32), jnp.asarray(0), buffers)


def _run_live(carry, config: RunConfig):
    _, code, _, k, _ = carry
    return (code == RUNNING) & (k < config.max_steps)


def _run_stride(carry, key, tables: PlanTables, true_terrain: Terrain, hopper: Hopper,
                disturbance: Disturbance, config: RunConfig):
    """One decision and stride of a live run (`run_one`'s loop body)."""
    apex, code, steps, k, (apexes, feet, used) = carry
    at_goal = jnp.all(jnp.abs(apex - config.goal) <= config.tolerance)
    noise = jax.random.uniform(jax.random.fold_in(key, k), (3,), minval=-1.0, maxval=1.0)
    measured = apex + noise * disturbance.sensor
    found, u, a = decide(measured, tables, hopper, config.model)
    energy = None
    if config.model == "slip" and config.energy_feedback:
        goal = tables.goals[a]
        energy = hopper.m * (hopper.g * goal[1] + 0.5 * goal[2] ** 2)
    nxt, s_code, foot = stride(apex, u, true_terrain, hopper, disturbance.wind, config.model,
                               energy)
    s_code = jnp.where(jnp.all(jnp.isfinite(nxt)) | (s_code != OK), s_code, SOLVER)
    code = jnp.where(at_goal, SUCCESS, jnp.where(~found, OUTSIDE_DOMAIN,
                                                 jnp.where(s_code == OK, RUNNING, s_code)))
    stepping = ~at_goal & found
    ok = stepping & (s_code == OK)
    apexes = apexes.at[k + 1].set(jnp.where(ok, nxt, jnp.nan))
    feet = feet.at[k].set(jnp.where(stepping, foot, jnp.nan))
    used = used.at[k].set(jnp.where(stepping, a, -1).astype(jnp.int32))
    apex = jnp.where(ok, nxt, apex)
    return apex, code, steps + stepping.astype(jnp.int32), k + 1, (apexes, feet, used)


def _run_result(carry, config: RunConfig):
    """`(code, steps, apexes, footholds, policies)` of a finished (or cut-off) run."""
    apex, code, steps, _, (apexes, feet, used) = carry
    at_goal = jnp.all(jnp.abs(apex - config.goal) <= config.tolerance)
    code = jnp.where(code == RUNNING, jnp.where(at_goal, SUCCESS, MAX_STEPS), code)
    return code, steps, apexes, feet, used


def run_one(apex0, key, tables: PlanTables, true_terrain: Terrain, hopper: Hopper,
            disturbance: Disturbance, config: RunConfig):
    """Run the reactive controller from one initial apex until success or failure.

    The controller sees the apex plus sensor noise (fresh at every apex, from `key`); the
    stride runs on `true_terrain` with the disturbance's wind.

    Returns:
        `(code, steps, apexes, footholds, policies)`: result code, strides taken, the
        `(max_steps + 1, 3)` apex sequence (NaN after the end), `(max_steps, 2)` footholds and
        the instantiated policy used at each stride (-1 after the end).
    """
    # A while loop, not a scan: a batch stops when its longest run ends.
    carry = jax.lax.while_loop(
        lambda c: _run_live(c, config),
        lambda c: _run_stride(c, key, tables, true_terrain, hopper, disturbance, config),
        _run_init(apex0, config))
    return _run_result(carry, config)


def _batch(apex0, key, index, tables, true_terrain, hopper, disturbance, config):
    # Run i's noise comes from fold_in(key, i): independent of batch size and chunking.
    keys = jax.vmap(jax.random.fold_in, (None, 0))(key, index)
    return jax.vmap(run_one, (0, 0, None, None, None, None, None))(
        apex0, keys, tables, true_terrain, hopper, disturbance, config)


_batch_jit = jax.jit(_batch)


def _in_domain(apexes, tables: PlanTables, hopper: Hopper):
    return jax.vmap(lambda z: first_match(z, tables, hopper)[0])(apexes)


_in_domain_jit = jax.jit(_in_domain)


def in_global_domain(apexes, tables: PlanTables, hopper: Hopper) -> np.ndarray:
    """Which apexes lie in the union of the deployed policies' domains."""
    return np.asarray(_in_domain_jit(jnp.asarray(apexes, float), tables, hopper))


def run_batch(plan: Plan, apex0, *, key=None, true_terrain: Terrain | None = None,
              disturbance: Disturbance | None = None, goal=None, max_steps: int = 60,
              tolerance=None, chunk: int | None = None, progress: bool = False,
              checkpoint: str | None = None, model: str = "bhop", pool: bool | None = None,
              energy_feedback: bool = False):
    """Run many initial apexes through the reactive controller.

    The batch is cut into chunks of `CHUNK` runs (smaller batches: the next power of two), the
    last one padded: one compilation serves every sweep. Small chunks also end early: a
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
    `POOL_LANES` lanes per device instead, refilled between strides (`_pool_runs`): no run
    waits for a longer one. Chunks then only set what is checkpointed and what each
    `jax.distributed` process runs; results are the same run for run.

    Returns:
        dict of NumPy arrays: `code, steps, apexes, footholds, policies`.
    """
    apex0 = np.atleast_2d(np.asarray(apex0, float))
    n = apex0.shape[0]
    key = jax.random.key(0) if key is None else key
    tables = plan.tables()
    true_terrain = plan.terrain if true_terrain is None else true_terrain
    disturbance = Disturbance() if disturbance is None else disturbance
    config = RunConfig(goal=jnp.asarray(plan.goal if goal is None else goal, float),
                       tolerance=jnp.full(3, 0.05) if tolerance is None
                       else jnp.asarray(tolerance, float), max_steps=max_steps, model=model,
                       energy_feedback=energy_feedback)
    devices = jax.local_devices()
    if chunk is None:
        full = SLIP_CHUNK if model == "slip" else CHUNK
        chunk = full if n >= full else 1 << (max(n, 1) - 1).bit_length()
    store = None
    if checkpoint is not None:
        store = _ChunkStore(checkpoint, _fingerprint(plan, apex0, key, true_terrain,
                                                     disturbance, config, chunk))
    pending = []
    consts = (tables, true_terrain, plan.hopper, disturbance, config)
    mine = process_chunks(-(-n // chunk))
    if model == "slip" if pool is None else pool:
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
        idx = np.arange(start, start + chunk).clip(max=n - 1)
        dev = devices[i % len(devices)]
        if dev not in on_device:
            on_device[dev] = jax.device_put(consts, dev)
        args = jax.device_put((apex0[idx], key, idx), dev)
        pending.append((start, stop, _batch_jit(*args, *on_device[dev])))
    parts = {k: [] for k in RUN_FIELDS}
    bar = tqdm(total=n, desc="runs", unit="run", disable=not progress, file=sys.stderr,
               leave=False)
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


RUN_FIELDS = ("code", "steps", "apexes", "footholds", "policies")
CHUNK = 256
# SLIP strides cost a deadbeat solve per lane and run lengths vary more (a vmapped while loop
# runs until the chunk's longest run ends), so SLIP sweeps use smaller chunks.
SLIP_CHUNK = 32


def _fingerprint(plan: Plan, apex0, key, true_terrain, disturbance, config, chunk) -> str:
    import hashlib

    from . import __version__

    h = hashlib.sha256()
    for part in (__version__, chunk, config.model, plan.terrain.blocks(),
                 true_terrain.blocks(), plan.goal.tolist(), config.max_steps,
                 [float(plan.hopper.m), float(plan.hopper.g), float(plan.hopper.rho0)]):
        h.update(repr(part).encode())
    for arr in (plan.order, plan.goals, plan.situated, apex0, jax.random.key_data(key),
                disturbance.wind, disturbance.sensor, config.goal, config.tolerance):
        h.update(np.ascontiguousarray(np.asarray(arr)).tobytes())
    return h.hexdigest()


class _ChunkStore:
    """Finished chunks of a sweep on disk: `<dir>/<fingerprint>/chunk-<start>-<stop>.npz`."""

    def __init__(self, root: str, fingerprint: str):
        import os

        self.dir = os.path.join(root, fingerprint[:32])
        os.makedirs(self.dir, exist_ok=True)

    def _path(self, start, stop):
        import os

        return os.path.join(self.dir, f"chunk-{start:09d}-{stop:09d}.npz")

    def load(self, start, stop):
        import zipfile

        try:
            with np.load(self._path(start, stop)) as z:
                arrays = [z[k] for k in RUN_FIELDS]
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
            return None  # missing or unreadable: compute it again
        if any(a.shape[0] != stop - start for a in arrays):
            return None
        return arrays

    def save(self, start, stop, arrays):
        import os

        path = self._path(start, stop)
        tmp = path + ".tmp"
        with open(tmp, "wb") as f:
            np.savez(f, **dict(zip(RUN_FIELDS, arrays)))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)


def sweep_grid(terrain: Terrain, ydot0: float = 0.5, dy: float = 0.05, dz: float = 0.05,
               z_range: tuple[float, float] | None = None) -> np.ndarray:
    """Initial apex states on a grid in `(y, z)` over the terrain (SPEC section 12)."""
    y0, y1 = terrain.y_range
    h = np.asarray(terrain.heights)
    if z_range is None:
        z_range = (float(h.min()) + 1.0, float(h.max()) + 2.6)
    ys = np.arange(y0, y1 + 1e-9, dy)
    zs = np.arange(z_range[0], z_range[1] + 1e-9, dz)
    Y, Z = np.meshgrid(ys, zs, indexing="ij")
    return np.stack([Y.ravel(), Z.ravel(), np.full(Y.size, ydot0)], axis=1)


def summarize(result: dict, seconds: float) -> dict:
    """SPEC section 15 sweep keys."""
    code, steps = result["code"], result["steps"]
    n = int(code.size)
    ok = code == SUCCESS
    return {
        "n_initial_conditions": n,
        "success_rate": float(ok.mean()) if n else 0.0,
        "mean_steps": float(steps[ok].mean()) if ok.any() else 0.0,
        "max_steps": int(steps[ok].max()) if ok.any() else 0,
        "failures": {name: int((code == i + 1).sum()) for i, name in enumerate(FAILURE_NAMES)},
        "seconds": round(seconds, 3),
    }


MAX_GRID = 2_000_000


def sweep(plan: Plan, *, initial=None, key=None, true_terrain: Terrain | None = None,
          disturbance: Disturbance | None = None, ydot0: float = 0.5, dy: float = 0.05,
          dz: float = 0.05, max_steps: int = 60, tolerance=None, chunk: int | None = None,
          checkpoint: str | None = None, model: str = "bhop", progress: bool = False):
    """Domain-of-attraction sweep: run every grid state inside the global domain.

    The grid (`sweep_grid`) covers `true_terrain` (default: the plan's map); `initial`
    replaces it. The other arguments are `run_batch`'s.

    Returns:
        `(summary, initial_states, result)`.

    Raises:
        InputError: the grid would exceed `MAX_GRID` states, or no state to run.
    """
    t0 = time.perf_counter()
    if initial is None:
        grid = sweep_grid(plan.terrain if true_terrain is None else true_terrain, ydot0, dy, dz)
        if grid.shape[0] > MAX_GRID:
            raise InputError(f"dy/dz: the grid would exceed {MAX_GRID} initial states")
        initial = grid[in_global_domain(grid, plan.tables(), plan.hopper)]
        if initial.shape[0] == 0:
            raise InputError("no grid state lies in the global domain (is the goal reachable?)")
    result = run_batch(plan, initial, key=key, true_terrain=true_terrain,
                       disturbance=disturbance, max_steps=max_steps, tolerance=tolerance,
                       chunk=chunk, progress=progress, checkpoint=checkpoint, model=model)
    return summarize(result, time.perf_counter() - t0), initial, result


# --- SLIP runs: a pool of lanes refilled between strides ----------------------------------
# A vmapped while loop runs until the longest run of its chunk ends: with SLIP strides (a
# deadbeat solve each) a chunk holding one run that loops to max_steps costs 60 strides
# per lane where most runs need about 12. So SLIP runs go through a pool instead: every
# device steps POOL_LANES runs by one stride (`_run_stride`, vmapped), the host retires
# the runs that ended and puts the next ones in their lanes (one host thread per device,
# one shared queue). Lanes with nothing to run repeat a live run of their device (same
# cost, results discarded). The lane count is fixed, so one compilation per device serves
# every sweep.
POOL_LANES = 8


def _pool_step(carry, fresh, apex0, index, key, tables, true_terrain, hopper, disturbance,
               config):
    # Lanes marked `fresh` start their run here (`_run_init` from `apex0`).
    carry = jax.vmap(lambda c, f, a: jax.tree.map(lambda new, old: jnp.where(f, new, old),
                                                  _run_init(a, config), c))(carry, fresh, apex0)
    keys = jax.vmap(jax.random.fold_in, (None, 0))(key, index)
    carry = jax.vmap(_run_stride, (0, 0, None, None, None, None, None))(
        carry, keys, tables, true_terrain, hopper, disturbance, config)
    live = jax.vmap(lambda c: _run_live(c, config))(carry)
    final = jax.vmap(lambda c: _run_result(c, config)[0])(carry)
    return carry, live, final


_pool_step_jit = jax.jit(_pool_step)


def _pool_runs(runs, apex0, key, consts, config: RunConfig, on_done, lanes=POOL_LANES):
    """Run `runs` (indices into `apex0`) through the pool; `on_done(run, fields)` is called
    as each ends, with `fields` in `RUN_FIELDS` order.

    One host thread per device, all taking runs from one queue: the devices step (and, the
    first time, compile) concurrently, and none waits for another.
    """
    import threading
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    # Placeholder leaves for a lane whose run starts in the next step (`fresh`).
    blank, treedef = jax.tree_util.tree_flatten(jax.device_get(_run_init(jnp.zeros(3), config)))
    queue, lock, stop = deque(runs), threading.Lock(), threading.Event()

    def worker(dev):
        on_dev = jax.device_put((key,) + tuple(consts), dev)
        active = []  # (run, carry leaves, fresh)
        while not stop.is_set():
            with lock:
                while queue and len(active) < lanes:
                    active.append((queue.popleft(), blank, True))
            if not active:
                return
            # Spare lanes repeat live runs (same cost; their results are discarded).
            pick = [active[j % len(active)] for j in range(lanes)]
            batch = [np.stack([p[1][i] for p in pick]) for i in range(treedef.num_leaves)]
            index = np.asarray([p[0] for p in pick])
            fresh = np.asarray([p[2] for p in pick])
            carry = jax.tree_util.tree_unflatten(treedef, jax.device_put(batch, dev))
            carry, live, final = _pool_step_jit(carry, *jax.device_put(
                (fresh, apex0[index], index), dev), *on_dev)
            leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(carry)]
            live, final = np.asarray(live), np.asarray(final)
            still, ended = [], []
            for slot, (run, _, _) in enumerate(active):
                mine = [x[slot] for x in leaves]
                if live[slot]:
                    still.append((run, mine, False))
                else:
                    _, _, steps, _, (apexes, feet, used) = jax.tree_util.tree_unflatten(
                        treedef, mine)
                    ended.append((run, (final[slot], steps, apexes, feet, used)))
            active = still
            with lock:
                for run, fields in ended:
                    on_done(run, fields)

    devices = jax.local_devices()
    with ThreadPoolExecutor(len(devices)) as ex:
        futures = [ex.submit(worker, dev) for dev in devices]
        try:
            for f in futures:
                f.result()
        finally:
            stop.set()


def _run_pool(apex0, key, consts, config, n, chunk, mine, store, progress):
    """`run_batch` for SLIP: chunks (checkpointing, `jax.distributed` shares) as there, the
    runs themselves through `_pool_runs`."""
    spans = [(start, min(start + chunk, n)) for i, start in enumerate(range(0, n, chunk))
             if i in mine]
    shapes = jax.eval_shape(_run_result, jax.eval_shape(_run_init, jnp.zeros(3), config),
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
    bar = tqdm(total=len(todo), desc="runs", unit="run", disable=not progress,
               file=sys.stderr, leave=False)

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

