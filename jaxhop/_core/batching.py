"""Fixed-shape batching: chunked maps over devices and padding to shape buckets.

Every jitted batch in jaxhop runs on a few fixed shapes, so that one compilation serves a
whole plan, sweep or course: a batch is cut into chunks of one size, the last chunk padded
by repeating its last item, and variable-length tables are padded up to a bucket.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .terrain import Terrain


def bucket(n: int, step: int) -> int:
    """The smallest positive multiple of `step` that holds `n` items (at least `step`)."""
    return max(step, step * -(-n // step))


def pow2_at_least(n: int) -> int:
    """The smallest power of two that holds `n` items (1 for `n <= 1`): batch sizes from a
    handful of shapes."""
    return 1 << (max(n, 1) - 1).bit_length()


def chunk_index(start: int, size: int, n: int) -> np.ndarray:
    """Indices `start .. start + size - 1`, the ones past the end repeating item `n - 1`."""
    return np.arange(start, start + size).clip(max=max(n - 1, 0))


def chunked_map(fn, n: int, size: int, batched, consts=(), *, tail: int | None = None,
                bar=None, devices=None):
    """`fn(*batched_chunk, *consts)` over `n` items in padded chunks, on every device.

    Chunks hold `size` items while that many remain and `tail` items (default `size`) for
    the rest, so that padding wastes at most `tail` items of work and only two shapes are
    ever compiled. Chunks go to `devices` (default: every local device) round-robin and are
    all dispatched before any result is read, so each device works on its share at once;
    `consts` are copied to each device once.

    Returns:
        The outputs concatenated over items as NumPy arrays, with `fn`'s tree structure.

    Raises:
        ValueError: if `n` is 0 (there is no output shape to return).
    """
    if n <= 0:
        raise ValueError("chunked_map: nothing to map")
    tail = size if tail is None else tail
    devices = jax.local_devices() if devices is None else devices
    on_device = {}
    pending = []
    start = 0
    while start < n:
        c = size if n - start >= size else tail
        dev = devices[len(pending) % len(devices)]
        if dev not in on_device:
            on_device[dev] = jax.device_put(consts, dev)
        idx = chunk_index(start, c, n)
        args = [jax.device_put(np.asarray(a)[idx], dev) for a in batched]
        count = min(c, n - start)
        pending.append((count, fn(*args, *on_device[dev])))
        start += count
    parts = []
    for count, out in pending:
        parts.append(jax.tree.map(lambda x, c=count: np.asarray(x)[:c], out))
        if bar is not None:
            bar.update(count)
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


def pad_to(x, n: int, fill) -> jnp.ndarray:
    """`x` padded along its first axis to `n` rows with copies of `fill` (a row or scalar).

    Padded on the host and copied to the device once: as JAX operations the padding would
    compile anew for every new length (on a course, at every snapshot that changes it)."""
    x = np.asarray(x)
    k = n - x.shape[0]
    if k < 0:
        raise ValueError(f"pad_to: {x.shape[0]} rows do not fit in {n}")
    row = np.broadcast_to(np.asarray(fill, x.dtype), (k,) + x.shape[1:])
    return jnp.asarray(np.concatenate([x, row]))


def pad_terrain(t: Terrain, n: int) -> Terrain:
    """`t` with `n` blocks: zero-length blocks at its far end, at its last height."""
    end, h = np.asarray(t.ends)[-1], np.asarray(t.heights)[-1]
    return Terrain(pad_to(t.starts, n, end), pad_to(t.ends, n, end),
                   pad_to(t.heights, n, h), t.name, None)


def run_once(flag, fn, init, fixed: bool = False):
    """`fn(zero)` where the traced `flag` holds, else `init`, as a while loop of at most one
    turn: under `vmap` a batch in which no lane needs it skips it (a `cond` would not).

    `fn` must add `zero` (a traced 0.0 that depends on the loop's carry) to an input of its
    computation: XLA's while-loop invariant code motion would otherwise hoist an invariant
    `fn` out of the loop, to run whether or not the flag holds (measured: 8x the time of a
    deadbeat solve that never needed it). jaxhop's programs compile without that pass
    (`COMPILER_OPTIONS`); a plain `jax.jit` of them runs it.

    `fixed`: `fn` runs on every lane and `flag` selects its result (`bounded_while`)."""
    if fixed:
        return _select(flag, fn(jnp.zeros(())), init)

    def body(c):
        zero = jnp.where(c[0], 0.0, jnp.nan)
        return jnp.asarray(False), fn(zero)

    _, out = jax.lax.while_loop(lambda c: c[0], body, (jnp.asarray(flag), init))
    return out


def bounded_while(cond, body, init, turns: int, fixed: bool = False):
    """`lax.while_loop(cond, body, init)` for a loop that ends within `turns` turns.

    `fixed`: a loop of exactly `turns` turns instead (a `scan`), in which a lane whose
    `cond` no longer holds keeps its carry: the same result, with no data-dependent loop.
    On an accelerator every turn of a data-dependent loop waits for the host and runs
    until the slowest lane ends; there a fixed loop costs the same work without the waits
    (`docs/slip.md`, "Fixed-shape trial strides"). `turns` must bound the while loop's
    turns, or the fixed loop stops early."""
    if not fixed:
        return jax.lax.while_loop(cond, body, init)

    def turn(carry, _):
        return _select(cond(carry), body(carry), carry), None

    return jax.lax.scan(turn, init, None, length=turns)[0]


def _select(flag, new, old):
    return jax.tree.map(lambda a, b: jnp.where(flag, a, b), new, old)
