"""SLIP runs: a pool of lanes refilled between strides (`docs/decisions.md`, "SLIP runs: a
lane pool instead of vmapped chunks").

A vmapped while loop runs until the longest run of its chunk ends: with SLIP strides (a
deadbeat solve each) a chunk holding one run that loops to max_steps costs 60 strides per
lane where most runs need about 12. So SLIP runs go through a pool instead: every device
steps `pool_lanes()` runs by one stride (`run_step`, vmapped), the host retires the runs
that ended and puts the next ones in their lanes (one host thread per device, each with
its own share of the runs; on a CPU all of them on its first device, `worker_devices`).
On a CPU a thread keeps more runs in progress than it has lanes and steps, each time, the
run that has waited longest with its neighbours on the terrain (`_choose`): their
decisions take alike work, and a batched decision lasts as long as its slowest lane.
Lanes with nothing to run repeat a live run of their thread (same cost, results
discarded). The lane count is fixed, so one compilation per device serves every sweep:
`POOL_LANES` on a CPU, where lanes share a core; `ACCELERATOR_LANES`
on a GPU or TPU, where a step costs about the same for one lane as for thousands (its
time is the chain of small solver steps, not the arithmetic); `$JAXHOP_POOL_LANES`
overrides both.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from .._control.runloop import RunConfig, World, run_init, run_live, run_result, run_step
from .._core.programs import stored_program

POOL_LANES = 32
ACCELERATOR_LANES = 4096


def pool_lanes(device=None) -> int:
    """Lanes per device: `$JAXHOP_POOL_LANES`, else by the device's platform."""
    env = os.environ.get("JAXHOP_POOL_LANES")
    if env:
        lanes = int(env) if env.strip().isdigit() else 0
        if lanes < 1:
            raise ValueError(f"JAXHOP_POOL_LANES must be a positive integer, got {env!r}")
        return lanes
    device = device or jax.local_devices()[0]
    return POOL_LANES if device.platform == "cpu" else ACCELERATOR_LANES


def worker_devices(devices) -> list:
    """The device of each of the pool's host threads, one thread per device in `devices`.

    On a CPU every thread runs on the first device: JAX's CPU client runs concurrent
    executions of one device on its cores, as fast as on a device per core (two threads on
    two cores: the same throughput either way), and the step, whose executable is bound to
    its device, is compiled once instead of once per device (the SLIP step: about a minute
    each on the 2-core CPU)."""
    devices = list(devices)
    if devices and all(d.platform == "cpu" for d in devices):
        return [devices[0]] * len(devices)
    return devices


#: Runs in progress per host thread, in units of its lanes, where a step costs what its
#: slowest lane costs (a CPU): each step takes the run that has waited longest and the
#: runs nearest to it on the terrain, whose decisions take alike work.
CPU_WINDOW = 16


def pool_window(device) -> int:
    """Runs in progress per thread, in lanes: `CPU_WINDOW` on a CPU, 1 elsewhere (every
    run in progress steps in every step)."""
    return CPU_WINDOW if device.platform == "cpu" else 1


def _choose(active, lanes: int, apex0) -> list[int]:
    """The runs of `active` (`[run, carry leaves, fresh, turn]`; the first leaf is the
    run's apex, `run_init`, and a fresh run's is its `apex0` row) that step next, in list order:
    all of them where they fit the lanes, else the one that has waited longest (the
    earliest `turn`, then the earliest in the list) and the `lanes - 1` runs whose apex
    lies nearest to its apex in `y` (ties: the earlier in the list). A SLIP decision in a
    batch lasts as long as its slowest lane, and runs over the same stretch of terrain
    decide on the same policies (`docs/decisions.md`, "SLIP runs: a lane pool instead of
    vmapped chunks")."""
    if len(active) <= lanes:
        return list(range(len(active)))
    y = np.asarray([apex0[a[0]][0] if a[2] else a[1][0][0] for a in active])
    head = min(range(len(active)), key=lambda i: (active[i][3], i))
    gap = np.abs(y - y[head])
    gap[head] = -1.0
    return sorted(np.argsort(gap, kind="stable")[:lanes].tolist())


def _pool_step(carry, fresh, apex0, index, key, tables, true_terrain, hopper, disturbance,
               config):
    # Lanes marked `fresh` start their run here (`run_init` from `apex0`).
    carry = jax.vmap(lambda c, f, a: jax.tree.map(lambda new, old: jnp.where(f, new, old),
                                                  run_init(a, config), c))(carry, fresh, apex0)
    keys = jax.vmap(jax.random.fold_in, (None, 0))(key, index)
    world = World(tables, true_terrain, hopper, disturbance)
    carry = jax.vmap(run_step, (0, 0, None, None))(carry, keys, world, config)
    live = jax.vmap(lambda c: run_live(c, config))(carry)
    final = jax.vmap(lambda c: run_result(c, config)[0])(carry)
    return carry, live, final


def _lane_batch(pick, treedef, dev):
    """The carries, run indices and `fresh` flags of the lanes, on `dev`."""
    batch = [np.stack([p[1][i] for p in pick]) for i in range(treedef.num_leaves)]
    index = np.asarray([p[0] for p in pick])
    fresh = np.asarray([p[2] for p in pick])
    return jax.tree_util.tree_unflatten(treedef, jax.device_put(batch, dev)), index, fresh


def pool_runs(runs, apex0, key, consts, config: RunConfig, on_done, lanes=None, *,
              strides: int | None = None, devices=None):
    """Run `runs` (indices into `apex0`) through the pool; `on_done(run, fields)` is called
    as each ends, with `fields` in `RUN_FIELDS` order. `consts` are `(tables, true_terrain,
    hopper, disturbance, config)`. `strides`: end every run after that many apexes (its
    code is then `run_result`'s for a run cut off), with the same compiled step.
    `devices`: default, every local device.

    One host thread per device, each with its own queue (every `n_devices`-th run), on the
    device `worker_devices` gives it: the threads step concurrently, and none waits for
    another after the first step (the compilation). A run's last bits depend on the lane
    it occupies and on its neighbours (XLA vectorises the lanes), so the runs are dealt to
    the threads in a fixed order rather than taken from a shared queue as each thread gets
    to it: the same runs then give bitwise the same results on the same number of
    devices, whatever the threads' timing.
    """
    if not runs:
        return
    lanes = pool_lanes() if lanes is None else lanes
    # Placeholder leaves for a lane whose run starts in the next step (`fresh`).
    blank, treedef = jax.tree_util.tree_flatten(jax.device_get(run_init(jnp.zeros(3), config)))
    devices = list(jax.local_devices() if devices is None else devices)
    lock, stop = threading.Lock(), threading.Event()
    slots = worker_devices(devices)
    compiled = threading.Event()  # the step has run once: the others find it compiled

    def worker(dev, queue, wait):
        try:
            work(dev, queue, wait)
        finally:
            compiled.set()  # also when it failed: no thread waits for it

    def work(dev, queue, wait):
        on_dev = jax.device_put((key,) + tuple(consts), dev)
        window = lanes * pool_window(dev)
        active = []  # [run, carry leaves, fresh, the turn it last stepped or came in]
        turn = 0
        while not stop.is_set():
            while queue and len(active) < window:
                active.append([queue.popleft(), blank, True, turn])
            if not active:
                return
            chosen = _choose(active, lanes, apex0)
            # Spare lanes repeat live runs (same cost; their results are discarded).
            pick = [active[chosen[j % len(chosen)]][:3] for j in range(lanes)]
            carry, index, fresh = _lane_batch(pick, treedef, dev)
            if wait:
                compiled.wait()
                wait = False
            out = step(*jax.tree_util.tree_leaves((carry, *jax.device_put(
                (fresh, apex0[index], index), dev), *on_dev)))
            compiled.set()
            *leaves, live, final = [np.asarray(x) for x in out]
            ended = []
            for slot, i in enumerate(chosen):
                run = active[i][0]
                mine = [x[slot] for x in leaves]
                _, _, steps, k, (apexes, feet, used), control = (
                    jax.tree_util.tree_unflatten(treedef, mine))
                if live[slot] and (strides is None or k < strides):
                    active[i] = [run, mine, False, turn]
                else:
                    active[i] = None
                    ended.append((run, (final[slot], steps, apexes, feet, used,
                                        control.recoveries)))
            active = [a for a in active if a is not None]
            turn += 1
            with lock:
                for run, fields in ended:
                    on_done(run, fields)

    # The step, loaded from disk or traced once here on lanes as the workers build them
    # (`jaxhop._core.programs`; tracing a SLIP decision takes about 20 s of Python): the device
    # threads then find it in jit's cache and only compile it (or load it from JAX's cache).
    carry0, index0, fresh0 = _lane_batch([(runs[0], blank, True)] * lanes, treedef, devices[0])
    args0 = (carry0, fresh0, apex0[index0], index0, key, *consts)
    step = stored_program("pool-step", _pool_step, args0)
    step.trace(*jax.tree_util.tree_leaves(args0))
    # Threads sharing a device wait for the first one's first step, which compiles the
    # step for that device; on other devices they compile concurrently.
    with ThreadPoolExecutor(len(slots)) as ex:
        futures = [ex.submit(worker, dev, deque(runs[i::len(slots)]),
                             dev in slots[:i])
                   for i, dev in enumerate(slots)]
        try:
            for f in futures:
                f.result()
        finally:
            stop.set()
