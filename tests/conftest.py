import os
import tempfile

# Every program the tests compile goes into the session's compilation cache, the small
# ones too (JAX keeps only those that took a second or more): the other workers and the
# processes and notebook kernels the tests start, which inherit the environment, read
# them instead of compiling each operation again.
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import jax  # noqa: E402 - after the setting above, which jax reads when imported

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_persistent_cache_min_compile_time_secs",
                  float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))


def _test_cache() -> str:
    """A cache directory for this test session, never the user's.

    The pytest-xdist workers of one session share it (named by the run's id): the SLIP
    table, plans and compiled programs one worker made are there for the others, and for
    the processes and notebook kernels the tests start, which inherit the environment.
    Concurrent writers are safe: the plan cache and the table write through temporary files
    and replace, the table build holds a file lock, and JAX's compilation cache writes
    atomically.
    """
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run is None:
        return tempfile.mkdtemp(prefix="jaxhop-test-cache-")
    path = os.path.join(tempfile.gettempdir(), f"jaxhop-test-cache-{run}")
    os.makedirs(path, exist_ok=True)
    return path


os.environ.setdefault("JAXHOP_CACHE", _test_cache())
# Tests that give a process a cache of its own (to test the plan cache) still share the
# session's compiled programs.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(os.environ["JAXHOP_CACHE"],
                                                                "xla"))

# The tests' own programs (and eager calls) compile as jaxhop's do (`jaxhop.COMPILER_OPTIONS`),
# the processes they start included.
import jaxhop  # noqa: E402 - after the cache directories above

_flags = os.environ.get("XLA_FLAGS", "").split()
os.environ["XLA_FLAGS"] = " ".join(_flags + [
    f"--{k}={v}" for k, v in jaxhop.COMPILER_OPTIONS.items() if f"--{k}={v}" not in _flags])

# Start JAX's backend now, with its default devices: a test that calls the command line's
# `main` in this process first would otherwise expose every core as a device for the rest
# of the worker (`jaxhop sweep` does, before its first computation), and every later test
# would compile its programs once per device.
jax.devices()


# The test files, slowest first (seconds on the 2-core CPU, most of it compiling SLIP
# programs), which pytest-xdist deals to its workers in this order (`--dist loadfile
# --no-loadscope-reorder` in pyproject.toml): the long files start at once and the short
# ones fill the end, so the workers finish together. Files not named follow in their
# collection order.
SLOWEST_FIRST = [
    "test_parkour.py", "test_slip_plan.py", "test_slip.py", "test_slip_table.py",
    "test_notebooks.py", "test_reference.py", "test_reference_slip.py", "test_adaptive.py",
    "test_plan.py", "test_mppc_disturbed.py", "test_regions.py", "test_checkpoint.py",
    "test_devices.py", "test_parkour_recovery.py", "test_properties.py", "test_fixed_loops.py",
    "test_explore.py", "test_mppc_plan.py", "test_malformed.py", "test_cli.py",
    "test_foothold.py", "test_api.py", "test_goals.py", "test_mujoco.py", "test_flight.py",
    "test_repro.py", "test_pool.py", "test_plot.py", "test_distributed.py",
]


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker more than there are cores (`--maxprocesses` caps it). Most of a
    test's time is tracing and compiling, on one core each, and a worker also waits for
    the processes and notebook kernels its tests start: a third worker keeps 2 cores busy
    (docs/development.md, "Tests")."""
    cores = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
             else os.cpu_count() or 1)
    return cores + 1


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: file order kept
