"""SLIP solver programs that several test files check premises with, jitted once.

A test that jits its own closure around a SLIP solver compiles it anew: 10-25 s on the
2-core CPU. The closures here are the same Python functions wherever they are imported,
so the tests of one process share them, and their lowered programs are the same text, so
a second process finds them in the session's compilation cache. Each shape's first call
in a process holds a lock in the session's cache directory: a worker that reaches a program
while another one compiles it waits and then reads it from the cache, instead of compiling
it a second time (15-18 s each).
"""

import contextlib
import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxhop._core.params import Hopper
from jaxhop._core.paths import cache_dir, file_lock
from jaxhop._models.slip.deadbeat import deadbeat_slip

HOP = Hopper()
#: Lanes per call: batches are padded to a multiple of it (one compiled shape).
BATCH = 8

#: Batch shapes this process has run (compiled or read from the cache).
_seen: set = set()

_deadbeat_batch = jax.jit(jax.vmap(lambda a, g, h, w: deadbeat_slip(a, g, h, HOP, wind=w)))


def deadbeats(apex, goal, h, wind=0.0):
    """`deadbeat_slip` (the default search, the default hopper) for each row of `apex`,
    `goal` over a foothold at `h` (one per row) in a horizontal flight acceleration `wind`
    (one per row or one for all; traced, so every wind shares the program), in batches
    padded to multiples of `BATCH`: the controls and the solver's flags, as NumPy arrays."""
    n = len(apex)
    idx = np.minimum(np.arange(-(-n // BATCH) * BATCH), n - 1)
    wind = np.broadcast_to(np.asarray(wind, float), (n,))
    lock = (file_lock(os.path.join(cache_dir(), "slip-programs.lock")) if len(idx) not in _seen
            else contextlib.nullcontext())
    with lock:
        u, ok = _deadbeat_batch(*(jnp.asarray(np.asarray(x)[idx]) for x in (apex, goal, h, wind)))
    _seen.add(len(idx))
    return np.asarray(u)[:n], np.asarray(ok)[:n]
