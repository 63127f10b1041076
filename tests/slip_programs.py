"""SLIP solver programs that several test files check premises with, jitted once.

A test that jits its own closure around a SLIP solver compiles it anew: 10-25 s on the
2-core CPU. The closures here are the same Python functions wherever they are imported,
so the tests of one process share them, and their lowered programs are the same text, so
a second process finds them in the session's compilation cache.
"""

import jax
import jax.numpy as jnp
import numpy as np

from jaxhop._core.params import Hopper
from jaxhop._models.slip.deadbeat import deadbeat_slip

HOP = Hopper()
#: Lanes per call: batches are padded to a multiple of it (one compiled shape).
BATCH = 8

_deadbeat_batch = jax.jit(jax.vmap(lambda a, g, h: deadbeat_slip(a, g, h, HOP)))


def deadbeats(apex, goal, h):
    """`deadbeat_slip` (the default search, the default hopper) for each row of `apex`,
    `goal` over a foothold at `h` (one per row), in batches padded to multiples of
    `BATCH`: the controls and the solver's flags, as NumPy arrays."""
    n = len(apex)
    idx = np.minimum(np.arange(-(-n // BATCH) * BATCH), n - 1)
    u, ok = _deadbeat_batch(jnp.asarray(np.asarray(apex)[idx]),
                            jnp.asarray(np.asarray(goal)[idx]), jnp.asarray(np.asarray(h)[idx]))
    return np.asarray(u)[:n], np.asarray(ok)[:n]
