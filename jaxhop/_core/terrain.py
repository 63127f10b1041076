"""Terrain: blocks, holes, ground segments, and the built-in maps (paper section III-C).

The JSON format of a terrain file is described in the README, "Command line".
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .errors import InputError
from .validate import number as _number
from .validate import short as _short

SEGMENT_LENGTH = 0.15
# Limits on user terrains: beyond them a plan is out of reach anyway (the reference map has
# 8 blocks and 60 segments), and an absurd file is an error, not an hour of planning.
MAX_BLOCKS = 1_000
MAX_SEGMENTS = 2_000
MAX_COORDINATE = 1.0e4  # |start|, |end|, |height| (m)
MAX_FILE_BYTES = 16 * 2**20
MAX_NAME = 200
MAX_GOAL_HEIGHT = 100.0  # goal apex at most this far above the ground (m)
MAX_SPEED = 100.0  # |ydot| of a goal or apex (m/s)

_BUILTIN = {
    "reference": (
        [
            (0.00, 1.20, 0.00),
            (1.20, 2.40, 0.30),
            (2.40, 3.30, 0.10),
            (3.30, 4.20, -0.20),
            (5.20, 6.10, 0.20),
            (6.10, 7.30, 0.00),
            (7.30, 8.50, 0.35),
            (8.50, 10.00, 0.00),
        ],
        (9.5, 1.3, 0.0),
    ),
    "long": (
        [
            (0.00, 0.90, 0.40),
            (0.90, 2.10, -0.40),
            (2.10, 3.00, 0.30),
            (3.60, 4.80, 0.60),
            (4.80, 5.40, 0.20),
            (5.40, 6.60, 0.00),
            (7.50, 8.70, 0.30),
            (8.70, 9.60, -0.10),
            (9.60, 10.50, 0.40),
            (10.50, 12.00, 0.00),
        ],
        (11.5, 1.3, 0.0),
    ),
    "flat": ([(0.0, 3.0, 0.0)], (2.5, 1.3, 0.0)),
}


class Terrain(eqx.Module):
    """Piecewise-constant terrain with holes.

    Blocks are `(start, end, height)`, sorted and non-overlapping; a gap between two blocks
    is a hole. The arrays are traced leaves so that a noisy map (perceived heights) reuses
    the compiled planner and simulator.

    Attributes:
        starts, ends, heights: block arrays, shape `(n_blocks,)`.
        name: a label (static).
        goal: the terrain's default global goal `(y, z, ydot)` or None (static).
    """

    starts: jnp.ndarray
    ends: jnp.ndarray
    heights: jnp.ndarray
    name: str = eqx.field(static=True, default="terrain")
    goal: tuple | None = eqx.field(static=True, default=None)

    @property
    def n_blocks(self) -> int:
        return int(self.starts.shape[0])

    @property
    def y_range(self) -> tuple[float, float]:
        return float(self.starts[0]), float(self.ends[-1])

    def blocks(self) -> list[tuple[float, float, float]]:
        return [
            (float(s), float(e), float(h))
            for s, e, h in zip(np.asarray(self.starts), np.asarray(self.ends),
                               np.asarray(self.heights))
        ]

    def with_heights(self, heights) -> Terrain:
        """The same map with other block heights (a perceived, noisy map)."""
        return Terrain(self.starts, self.ends, jnp.asarray(heights, float), self.name, self.goal)

    def unnamed(self) -> Terrain:
        """The same blocks without the name and goal, which are static fields: a jitted
        program keyed by them would be compiled again for every map of the same shape."""
        return Terrain(self.starts, self.ends, self.heights)

    def to_dict(self) -> dict:
        out = {
            "name": self.name,
            "blocks": [{"start": s, "end": e, "height": h} for s, e, h in self.blocks()],
        }
        if self.goal is not None:
            out["goal"] = list(self.goal)
        return out


def make_terrain(
    blocks: Sequence[Sequence[float]],
    goal: Sequence[float] | None = None,
    name: str = "terrain",
    seg_length: float = SEGMENT_LENGTH,
) -> Terrain:
    """Build a validated terrain from `(start, end, height)` triples.

    Raises:
        InputError: a block breaks a rule (finite, start < end, sorted, non-overlapping) or
            no block is long enough for one segment of length `seg_length`.
    """
    if len(blocks) == 0:
        raise InputError("blocks: the list is empty; a terrain needs at least one block")
    if len(blocks) > MAX_BLOCKS:
        raise InputError(f"blocks: {len(blocks)} blocks, at most {MAX_BLOCKS} allowed")
    rows = []
    for i, block in enumerate(blocks):
        if not isinstance(block, (list, tuple, np.ndarray)) or len(block) != 3:
            raise InputError(f"blocks[{i}]: expected (start, end, height), got "
                             f"{_short(block)}")
        s, e, h = (_number(v, f"blocks[{i}].{k}", MAX_COORDINATE)
                   for v, k in zip(block, ("start", "end", "height")))
        if not s < e:
            raise InputError(f"blocks[{i}]: start {s} must be less than end {e}")
        if rows and s < rows[-1][1] - 1e-12:
            prev = rows[-1]
            if s < prev[0]:
                raise InputError(f"blocks[{i}]: not sorted (start {s} < previous start {prev[0]})")
            raise InputError(f"blocks[{i}]: overlaps blocks[{i - 1}] (start {s} < previous end "
                             f"{prev[1]})")
        rows.append((s, e, h))
    if not any(e - s >= seg_length - 1e-9 for s, e, _ in rows):
        raise InputError(f"blocks: no block is at least one segment ({seg_length} m) long")
    n_seg = sum(math.floor((e - s) / seg_length + 1e-9) for s, e, _ in rows)
    if n_seg > MAX_SEGMENTS:
        raise InputError(f"blocks: {n_seg} segments of {seg_length} m, at most "
                         f"{MAX_SEGMENTS} allowed")
    arr = np.asarray(rows, dtype=float)
    terrain = Terrain(jnp.asarray(arr[:, 0]), jnp.asarray(arr[:, 1]), jnp.asarray(arr[:, 2]),
                      name=str(name), goal=None)
    if goal is not None:
        goal = check_goal(terrain, goal, "goal")
        terrain = Terrain(terrain.starts, terrain.ends, terrain.heights, terrain.name, goal)
    return terrain


def check_goal(terrain: Terrain, goal, field: str = "goal") -> tuple[float, float, float]:
    """Validate a global goal `(y, z, ydot)` on a terrain; returns it as floats.

    The goal apex must be finite, over the map (`start of the first block <= y <= end of the
    last`), higher than one leg length (1 m) above the block under it (over a hole: above
    the higher rim), at most `MAX_GOAL_HEIGHT` above it, and `|ydot| <= MAX_SPEED`.

    Raises:
        InputError: naming `field` and the rule the goal breaks.
    """
    if isinstance(goal, (str, bytes, dict)) or not hasattr(goal, "__len__") or len(goal) != 3:
        raise InputError(f"{field}: expected [y, z, ydot], got {_short(goal)}")
    y, z, ydot = (_number(v, f"{field}[{k}]", MAX_COORDINATE) for k, v in enumerate(goal))
    y0, y1 = terrain.y_range
    if not y0 <= y <= y1:
        raise InputError(f"{field}: y = {y:g} lies off the map [{y0:g}, {y1:g}]")
    blocks = terrain.blocks()
    under = [h for s, e, h in blocks if s <= y <= e]
    if not under:  # over a hole: the higher of its two rims
        under = [max((e, h) for _, e, h in blocks if e < y)[1],
                 min((s, h) for s, _, h in blocks if s > y)[1]]
    ground = max(under)
    if not z > ground + 1.0:
        raise InputError(f"{field}: z = {z:g} must exceed the ground under it ({ground:g}) by "
                         "more than the leg length 1 m")
    if z > ground + MAX_GOAL_HEIGHT:
        raise InputError(f"{field}: z = {z:g} is more than {MAX_GOAL_HEIGHT:g} m above the "
                         "ground")
    if abs(ydot) > MAX_SPEED:
        raise InputError(f"{field}: |ydot| = {abs(ydot):g} exceeds {MAX_SPEED:g} m/s")
    return (y, z, ydot)


def builtin_terrains() -> tuple[str, ...]:
    return tuple(_BUILTIN)


def builtin_terrain(name: str) -> Terrain:
    """One of the built-in terrains `reference`, `long`, `flat`."""
    if name not in _BUILTIN:
        raise InputError(f"unknown terrain {name!r}; built-in: {', '.join(_BUILTIN)}")
    blocks, goal = _BUILTIN[name]
    return make_terrain(blocks, goal, name)


def terrain_from_dict(data, source: str = "terrain") -> Terrain:
    """Validate and build a terrain from its JSON structure (README, "Command line")."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a JSON object with 'blocks', got "
                         f"{type(data).__name__}")
    unknown = set(data) - {"name", "blocks", "goal"}
    if unknown:
        raise InputError(f"{source}: unknown key(s) "
                         f"{_short(', '.join(sorted(map(str, unknown))))}")
    if "blocks" not in data:
        raise InputError(f"{source}: missing key 'blocks'")
    blocks = data["blocks"]
    if not isinstance(blocks, list):
        raise InputError(f"blocks: expected a list, got {type(blocks).__name__}")
    triples = []
    for i, b in enumerate(blocks):
        if not isinstance(b, dict):
            raise InputError(f"blocks[{i}]: expected an object with start, end, height")
        missing = [k for k in ("start", "end", "height") if k not in b]
        if missing:
            raise InputError(f"blocks[{i}]: missing key(s) {', '.join(missing)}")
        extra = set(b) - {"start", "end", "height"}
        if extra:
            raise InputError(f"blocks[{i}]: unknown key(s) "
                             f"{_short(', '.join(sorted(map(str, extra))))}")
        triples.append((b["start"], b["end"], b["height"]))
    name = data.get("name", os.path.splitext(os.path.basename(source))[0])
    if not isinstance(name, str):
        raise InputError(f"name: expected a string, got {_short(name)}")
    if len(name) > MAX_NAME or not name.isprintable():
        raise InputError(f"name: expected at most {MAX_NAME} printable characters")
    goal = data.get("goal")
    if goal is not None and not isinstance(goal, list):
        raise InputError(f"goal: expected [y, z, ydot], got {_short(goal)}")
    return make_terrain(triples, goal, name)


def load_terrain(name_or_path: str) -> Terrain:
    """A built-in terrain by name, or a terrain JSON file.

    Raises:
        InputError: unknown name, unreadable file, invalid JSON or an invalid terrain.
    """
    if name_or_path in _BUILTIN:
        return builtin_terrain(name_or_path)
    if not isinstance(name_or_path, str) or not os.path.exists(name_or_path):
        raise InputError(f"terrain {_short(name_or_path, 80)} is neither a built-in "
                         f"({', '.join(_BUILTIN)}) nor an existing file")
    where = f"terrain file {_short(name_or_path, 80)}"
    try:
        if os.path.getsize(name_or_path) > MAX_FILE_BYTES:
            raise InputError(f"{where}: larger than {MAX_FILE_BYTES >> 20} MiB")
        with open(name_or_path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as err:
        raise InputError(f"{where}: cannot read ({err.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{where}: cannot read (not UTF-8 text)") from None
    except json.JSONDecodeError as err:
        raise InputError(f"{where}: invalid JSON ({err.msg} at line {err.lineno})") from None
    except RecursionError:
        raise InputError(f"{where}: invalid JSON (nested too deeply)") from None
    return terrain_from_dict(data, name_or_path)


def save_terrain(terrain: Terrain, path: str) -> None:
    with open(path, "w") as f:
        json.dump(terrain.to_dict(), f, indent=1)


class Segments(eqx.Module):
    """Ground segments of length `2l` cut from the blocks (section III-C).

    Attributes:
        centre: `(n, 2)` centres `(y_j, h_j)`.
        block: `(n,)` index of the block each segment lies on.
        edge_distance: `(n,)` `de(p)`, distance from the centre to the nearer end of its block.
    """

    centre: jnp.ndarray
    block: jnp.ndarray
    edge_distance: jnp.ndarray

    @property
    def n(self) -> int:
        return int(self.block.shape[0])


def segments(terrain: Terrain, seg_length: float = SEGMENT_LENGTH) -> Segments:
    """Cut every block into `floor(L / 2l)` segments, centred in the block."""
    centres, blocks, edges = [], [], []
    for b, (s, e, h) in enumerate(terrain.blocks()):
        length = e - s
        n = int(math.floor(length / seg_length + 1e-9))
        left = s + 0.5 * (length - n * seg_length)
        for k in range(n):
            y = left + (k + 0.5) * seg_length
            centres.append((y, h))
            blocks.append(b)
            edges.append(min(y - s, e - y))
    return Segments(jnp.asarray(np.reshape(centres, (-1, 2)), float),
                    jnp.asarray(np.asarray(blocks, np.int32)), jnp.asarray(edges, float))


def random_terrain(
    key: jax.Array,
    length: float = 10.0,
    *,
    seg_length: float = SEGMENT_LENGTH,
    segments_per_block: tuple[int, int] = (6, 10),
    height_range: tuple[float, float] = (-0.3, 0.4),
    hole_probability: float = 0.2,
    hole_width: tuple[float, float] = (0.3, 0.9),
    name: str = "random",
) -> Terrain:
    """A seeded random terrain.

    Blocks are `n * 2l` long with `n` uniform in `segments_per_block`; heights are uniform in
    `height_range` rounded to 5 cm; after each block a hole follows with probability
    `hole_probability`, its width uniform in `hole_width`. The first and last blocks are at
    height 0; the last is at least 1.5 m long and reaches at least `length`. The default goal
    is 0.5 m before its end, 1.3 m above it, at rest.
    """
    rng = np.random.default_rng(_seed_words(key))
    blocks, y = [], 0.0
    while True:
        n = int(rng.integers(segments_per_block[0], segments_per_block[1] + 1))
        h = round(float(rng.uniform(*height_range)) / 0.05) * 0.05
        h = 0.0 if not blocks else round(h, 2)
        end = y + n * seg_length
        if end > length - 1.5:
            break
        blocks.append((round(y, 6), round(end, 6), h))
        y = end
        if rng.uniform() < hole_probability:
            y += round(float(rng.uniform(*hole_width)), 2)
    n_last = math.ceil((max(length, y + 1.5) - y) / seg_length - 1e-9)
    last = y + n_last * seg_length
    blocks.append((round(y, 6), round(last, 6), 0.0))
    return make_terrain(blocks, (last - 0.5, 1.3, 0.0), name)


def _seed_words(key) -> list[int]:
    """Integer seed words of a JAX key (typed or raw uint32) or a plain int seed."""
    if isinstance(key, (int, np.integer)):
        return [int(key)]
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return np.asarray(key).ravel().astype(np.int64).tolist()
