"""Finished chunks of a batch of runs on disk, under a fingerprint of their inputs.

`run_batch(checkpoint=DIR)` writes each finished chunk atomically; a rerun with the same
inputs loads them and computes only the rest, so an interrupted sweep loses at most the
chunks in flight.
"""

from __future__ import annotations

import hashlib
import os
import zipfile

import jax
import numpy as np

from .._control.runloop import RUN_FIELDS
from .._core.paths import atomic_write
from .._core.version import VERSION
from .._planning.plan import Plan


def fingerprint(plan: Plan, apex0, key, true_terrain, disturbance, config, chunk) -> str:
    """A hash of everything the results of a batch depend on."""
    h = hashlib.sha256()
    on = None if config.adaptive_on is None else bool(config.adaptive_on)
    for part in (VERSION, chunk, config.model.name, config.controller, on,
                 plan.terrain.blocks(),
                 true_terrain.blocks(), plan.goal.tolist(), config.max_steps,
                 [float(plan.hopper.m), float(plan.hopper.g), float(plan.hopper.rho0)]):
        h.update(repr(part).encode())
    for arr in (plan.order, plan.goals, plan.situated, apex0, jax.random.key_data(key),
                disturbance.wind, disturbance.sensor, config.goal, config.tolerance):
        h.update(np.ascontiguousarray(np.asarray(arr)).tobytes())
    return h.hexdigest()


class ChunkStore:
    """Finished chunks of a sweep on disk: `<dir>/<fingerprint>/chunk-<start>-<stop>.npz`."""

    def __init__(self, root: str, fingerprint: str):
        self.dir = os.path.join(root, fingerprint[:32])
        os.makedirs(self.dir, exist_ok=True)

    def _path(self, start, stop):
        return os.path.join(self.dir, f"chunk-{start:09d}-{stop:09d}.npz")

    def load(self, start, stop):
        try:
            with np.load(self._path(start, stop)) as z:
                arrays = [z[k] for k in RUN_FIELDS]
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
            return None  # missing or unreadable: compute it again
        if any(a.shape[0] != stop - start for a in arrays):
            return None
        return arrays

    def save(self, start, stop, arrays):
        path = self._path(start, stop)
        atomic_write(path, lambda f: np.savez(f, **dict(zip(RUN_FIELDS, arrays))), sync=True)
