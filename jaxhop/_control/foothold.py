"""Foothold sensing of the adaptive controller: the true height of the block under the foot.

At touchdown a robot knows the height of the ground under its foot from its leg geometry.
The adaptive controller (`docs/decisions.md`, "Adaptive controller") uses it twice:

- for the stance it is in: the BHop stance is instantaneous at touchdown, so its controls
  are computed with the sensed height; a SLIP lands with the touchdown angle chosen in
  flight and re-plans its decompression at the bottom (eq 12 with the sensed height,
  `jaxhop._models.slip.stride.bottom_kd`) where the sensed height differs from its map;
- for the rest of the run: it remembers its last `MEMORY` footholds `(y, h)` and corrects
  its map with them, block by block (`corrected_heights`), so that a block perceived too
  high or too low is right from the second visit on.

The memory is part of the controller's state per run (`Footholds`), pure and vmappable. It
is kept as positions, not block indices, so it stays meaningful when the map changes
(parkour courses): a remembered foothold corrects the block of the current map that
contains it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from .._core.terrain import Terrain

#: Footholds remembered per run (a ring buffer; the newest replaces the oldest).
MEMORY = 8


class Footholds(NamedTuple):
    """The sensed footholds of one run: positions `y`, heights `h`, and the stride `t` at
    which each was sensed (-1: empty slot)."""

    y: jnp.ndarray
    h: jnp.ndarray
    t: jnp.ndarray


def footholds_init() -> Footholds:
    """Nothing sensed yet."""
    return Footholds(jnp.zeros(MEMORY), jnp.zeros(MEMORY), jnp.full(MEMORY, -1, jnp.int32))


def remember(mem: Footholds, foot, sensed, t) -> Footholds:
    """Store the foothold `foot = (y, h)` sensed at stride `t` (if `sensed`)."""
    i = jnp.asarray(t, jnp.int32) % MEMORY
    return Footholds(jnp.where(sensed, mem.y.at[i].set(foot[0]), mem.y),
                     jnp.where(sensed, mem.h.at[i].set(foot[1]), mem.h),
                     jnp.where(sensed, mem.t.at[i].set(jnp.asarray(t, jnp.int32)), mem.t))


def foothold_blocks(mem: Footholds, terrain: Terrain):
    """The block of `terrain` each remembered foothold lies on (-1: none).

    A foothold on the shared edge of two blocks belongs to the one whose mapped height is
    nearer to the sensed height.
    """
    on = ((mem.y[:, None] >= terrain.starts[None, :]) & (mem.y[:, None] <= terrain.ends[None, :])
          & (mem.t[:, None] >= 0))
    miss = jnp.where(on, jnp.abs(terrain.heights[None, :] - mem.h[:, None]), jnp.inf)
    block = jnp.argmin(miss, axis=1)
    return jnp.where(jnp.any(on, axis=1), block, -1)


def corrected_heights(mem: Footholds, terrain: Terrain):
    """The map's block heights with each block the run has stood on set to the height sensed
    there (the latest sensing of the block wins)."""
    block = foothold_blocks(mem, terrain)
    hit = block[:, None] == jnp.arange(terrain.n_blocks)[None, :]
    latest = jnp.max(jnp.where(hit, mem.t[:, None], -1), axis=0)
    pick = hit & (mem.t[:, None] == latest[None, :])
    sensed = jnp.sum(jnp.where(pick, mem.h[:, None], 0.0), axis=0)
    return jnp.where(latest >= 0, sensed, terrain.heights)


def mapped_height(foot, heights, terrain: Terrain):
    """The corrected map's height under the foothold `foot = (y, h)` (NaN off every block;
    on a shared edge, the block nearer in height to `h`)."""
    on = (foot[0] >= terrain.starts) & (foot[0] <= terrain.ends)
    block = jnp.argmin(jnp.where(on, jnp.abs(heights - foot[1]), jnp.inf))
    return jnp.where(jnp.any(on), heights[block], jnp.nan)
