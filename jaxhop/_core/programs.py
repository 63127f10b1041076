"""Traced programs kept on disk, so that a fresh process neither traces nor compiles them.

JAX's persistent compilation cache spares a second process the compilation, but not the
tracing and lowering that produce the cache key: for the SLIP lane pool's step (a SLIP
decision with its nested diffrax solves) that is about a minute of Python on every start
(60-65 s traced and 6 s lowered on the 2-core CPU, jax 0.10.2). The
pool step is therefore exported once (`jax.export`, StableHLO) and saved beside JAX's
compilation cache, in `<compilation cache dir>/jaxhop-programs`; a later process loads it
in milliseconds, and JAX's cache then supplies the compiled executable. The plan's stages
(`jaxhop._planning.stages.stored`) are saved the same way, one program per chunk shape:
a course's first updates in a process otherwise traced each stage for their smaller
chunks (docs/parkour_reactive.md, "Updates against the leg's flight").

A saved program is named by a SHA-256 of everything it was traced from: jaxhop's source
files, the versions of JAX and the libraries traced into it, the backend, and the
arguments' tree structure (with its static fields) and shapes. Reloading is therefore only
ever done by the same code and library versions, which is why the export may contain
LAPACK / solver calls without a cross-version compatibility guarantee. No compilation cache
directory (JAX's cache turned off) means nothing is saved. A file that cannot be read is
reported and replaced; a program that cannot be exported runs traced, as plain `jax.jit`.

`stored_array` keeps a computed array the same way, under a SHA-256 that also covers the
values of its inputs and the number of devices (a run's last bits depend on its lanes).

Every jaxhop program compiles with `COMPILER_OPTIONS` (`jit`): XLA's while-loop invariant
code motion computes the trip count of each loop it visits by extracting and cloning the
loop's computation, at every turn of its simplification fix point. A SLIP decision nests
diffrax's step loops in event root finds, Gauss-Newton turns, table starts and candidates
inside the run loop, and that pass alone took three quarters of the lane pool step's
compilation: 341 s, against 56 s without it (2-core CPU, jax 0.10.2), while a warm pool
run of 128 reference states took 2.2 s either way (same outcomes; apexes within 2e-7).
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import warnings
from importlib import metadata

import jax
import jax.export as jex
import numpy as np

from .paths import atomic_write

_typeof = getattr(jax, "typeof", None) or jax.core.get_aval
_LIBS = ("jax", "jaxlib", "diffrax", "equinox", "optimistix", "lineax", "numpy")
# The linear solves of optimistix / lineax lower to these on CPU (others are added from
# the export error on another backend).
_KNOWN_CALLS = ("lapack_dgeqrf_ffi", "lapack_dorgqr_ffi", "lapack_dormqr_ffi",
                "lapack_dgetrf_ffi", "lapack_dtrsm_ffi", "lapack_dpotrf_ffi")


#: XLA debug options every jaxhop program is compiled with (see above).
COMPILER_OPTIONS = {"xla_disable_hlo_passes": "while-loop-invariant-code-motion"}


def jit(fn, **kwargs):
    """`jax.jit(fn, **kwargs)` compiled with `COMPILER_OPTIONS`."""
    return jax.jit(fn, compiler_options=COMPILER_OPTIONS, **kwargs)


PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # jaxhop/


def source_files() -> list[str]:
    """Every source file of the package, relative to its root, in a fixed order: what a
    saved program was traced from."""
    out = []
    for folder, dirs, files in os.walk(PACKAGE_ROOT):
        dirs.sort()
        out += [os.path.relpath(os.path.join(folder, name), PACKAGE_ROOT)
                for name in sorted(files) if name.endswith(".py")]
    return out


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    h = hashlib.sha256()
    for rel in source_files():
        h.update(rel.encode())
        with open(os.path.join(PACKAGE_ROOT, rel), "rb") as f:
            h.update(f.read())
    return h.hexdigest()


@functools.cache
def _version(lib: str) -> str:
    try:
        return metadata.version(lib)
    except metadata.PackageNotFoundError:
        return "-"


def program_key(name: str, leaves, treedef) -> str:
    """SHA-256 (hex) of the program `name` traced on these argument leaves and structure."""
    parts = [name, _source_hash(), jax.default_backend(), str(jax.config.jax_enable_x64),
             str(treedef)]
    parts += [f"{lib}={_version(lib)}" for lib in _LIBS]
    for leaf in leaves:
        aval = _typeof(leaf)
        parts.append(f"{aval.str_short()}:{getattr(aval, 'weak_type', False)}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


_LOADED = {}  # this process's programs, by key: one jit (and its compilations) each
# Each key by what it depends on that varies within a process (the name, the arguments'
# structure and avals): hashing the sources, versions and avals again costs ~0.2 ms a call.
_KEYS = {}


def _folder() -> str | None:
    xla = jax.config.jax_compilation_cache_dir
    return None if not xla else os.path.join(xla, "jaxhop-programs")


def _export(flat, leaves):
    calls = set(_KNOWN_CALLS)
    for _ in range(3):
        try:
            checks = [jex.DisabledSafetyCheck.custom_call(c) for c in sorted(calls)]
            return jex.export(jax.jit(flat), disabled_checks=checks)(*leaves)
        except ValueError as err:
            more = set(re.findall(r"custom_call @(\w+)", str(err))) - calls
            if "custom calls" not in str(err) or not more:
                raise
            calls |= more
    raise ValueError("export: too many custom calls")


def stored_program(name: str, fn, args: tuple, log=None):
    """`fn` as a jitted function of the flat leaves of `args`, returning the flat leaves of
    its output: loaded from disk when this program was saved before, else traced, exported
    and saved. Call it with `jax.tree_util.tree_leaves` of arguments shaped as `args`.

    `log`: where a problem with the saved file is reported (default: a warning).
    """
    leaves, treedef = jax.tree_util.tree_flatten(args)
    seen = (name, treedef, jax.config.jax_enable_x64, tuple(map(_typeof, leaves)))
    if seen not in _KEYS:
        _KEYS[seen] = program_key(name, leaves, treedef)
    key = _KEYS[seen]
    if key not in _LOADED:
        def flat(*lv):
            return jax.tree_util.tree_leaves(fn(*jax.tree_util.tree_unflatten(treedef, lv)))

        _LOADED[key] = _load_or_export(name, key, flat, leaves, log)
    return _LOADED[key]


def _load_or_export(name, key, flat, leaves, log):
    report = log or (lambda m: warnings.warn(m, stacklevel=4))
    folder = _folder()
    path = None
    if folder is not None:
        path = os.path.join(folder, f"{name}-{key[:32]}.jax")
        if os.path.exists(path):
            try:
                with open(path, "rb") as f:
                    return jit(jex.deserialize(bytearray(f.read())).call)
            except Exception as err:  # noqa: BLE001 - any unreadable file is re-exported
                report(f"program {path}: unreadable ({type(err).__name__}); re-exporting")
    try:
        exported = _export(flat, leaves)
        blob = exported.serialize()
    except Exception:  # noqa: BLE001 - no export (e.g. no flatbuffers): trace as usual
        return jit(flat)
    if path is not None:
        _save(path, lambda f: f.write(blob), report)
    return jit(exported.call)


def _save(path: str, write, report) -> None:
    """`atomic_write(path, write)` into a folder made where missing; a failure is reported,
    not raised."""
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        atomic_write(path, write)
    except OSError as err:
        report(f"cannot save {path}: {err.strerror}")


def _value_bytes(leaf) -> bytes:
    leaf = jax.random.key_data(leaf) if jax.dtypes.issubdtype(
        getattr(leaf, "dtype", None), jax.dtypes.prng_key) else leaf
    arr = np.ascontiguousarray(np.asarray(leaf))
    return f"{arr.dtype}{arr.shape}".encode() + arr.tobytes()


def stored_array(name: str, compute, inputs, log=None) -> np.ndarray:
    """`compute()` (an array computed from `inputs` alone, by jaxhop), from disk when the
    same inputs were computed before with the same code, libraries and device count.

    `log`: where a problem with the saved file is reported (default: a warning).
    """
    leaves, treedef = jax.tree_util.tree_flatten(inputs)
    h = hashlib.sha256(program_key(name, leaves, treedef).encode())
    h.update(f"devices={jax.local_device_count()}".encode())
    for leaf in leaves:
        h.update(_value_bytes(leaf))
    report = log or (lambda m: warnings.warn(m, stacklevel=3))
    folder = _folder()
    path = None if folder is None else os.path.join(folder, f"{name}-{h.hexdigest()[:32]}.npy")
    if path is not None and os.path.exists(path):
        try:
            return np.load(path, allow_pickle=False)
        except Exception as err:  # noqa: BLE001 - any unreadable file is computed again
            report(f"stored {path}: unreadable ({type(err).__name__}); computing it again")
    value = np.asarray(compute())
    if path is not None:
        _save(path, lambda f: np.save(f, value, allow_pickle=False), report)
    return value
