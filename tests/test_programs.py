"""Programs kept on disk (`jaxhop._core.programs`): loaded instead of traced, keyed by what they
were traced from, and never trusted when unreadable."""

import os
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhop._core import programs as _programs


class Spring(eqx.Module):
    k: jnp.ndarray
    power: int = eqx.field(static=True)


def _program(traces):
    def fn(x, spring, key):
        traces.append(1)  # runs only while tracing
        noise = jax.random.normal(key, x.shape)
        return {"force": spring.k * x**spring.power, "noisy": x + noise}, jnp.linalg.solve(
            jnp.eye(2) * spring.k, x[:2])

    return fn


def _expected(x, k, power, key):
    return k * x**power, x + np.asarray(jax.random.normal(key, x.shape)), x[:2] / k


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    """A program folder of its own, and a way to forget this process's loaded programs."""
    monkeypatch.setattr(_programs, "_folder", lambda: str(tmp_path / "programs"))
    monkeypatch.setattr(_programs, "_LOADED", {})
    return lambda: monkeypatch.setattr(_programs, "_LOADED", {})


def _call(program, args):
    return [np.asarray(v) for v in program(*jax.tree_util.tree_leaves(args))]


def test_a_saved_program_is_loaded_without_tracing(fresh, tmp_path):
    traces = []
    x, key = jnp.linspace(0.5, 2.0, 5), jax.random.key(3)
    args = (x, Spring(jnp.asarray(4.0), 3), key)
    first = _call(_programs.stored_program("spring", _program(traces), args), args)
    assert len(traces) == 1
    assert len(list((tmp_path / "programs").iterdir())) == 1
    fresh()  # as a new process: nothing loaded
    again = _programs.stored_program("spring", _program(traces), args)
    other = (2.0 * x, Spring(jnp.asarray(5.0), 3), jax.random.key(4))  # same shapes
    out = _call(again, other)
    assert len(traces) == 1  # loaded from disk, not traced
    for got, want in zip([out[0], out[1], out[2]], _expected(2.0 * np.asarray(x), 5.0, 3,
                                                             jax.random.key(4))):
        np.testing.assert_allclose(got, want, rtol=1e-12)
    for got, want in zip(first, _expected(np.asarray(x), 4.0, 3, key)):
        np.testing.assert_allclose(got, want, rtol=1e-12)


def test_static_fields_and_shapes_name_another_program(fresh, tmp_path):
    traces = []
    key = jax.random.key(0)
    for args in [(jnp.ones(4), Spring(jnp.asarray(2.0), 2), key),
                 (jnp.ones(4), Spring(jnp.asarray(2.0), 3), key),   # another static field
                 (jnp.ones(6), Spring(jnp.asarray(2.0), 2), key)]:  # another shape
        x = np.asarray(args[0]) * 1.5
        run = (jnp.asarray(x), args[1], key)
        out = _call(_programs.stored_program("spring", _program(traces), args), run)
        np.testing.assert_allclose(out[0], 2.0 * x ** args[1].power, rtol=1e-12)
    assert len(traces) == 3
    assert len(list((tmp_path / "programs").iterdir())) == 3


def test_an_unreadable_file_is_reported_and_replaced(fresh, tmp_path):
    traces, reports = [], []
    args = (jnp.arange(1.0, 4.0), Spring(jnp.asarray(2.0), 1), jax.random.key(1))
    _programs.stored_program("spring", _program(traces), args)
    (path,) = (tmp_path / "programs").iterdir()
    path.write_bytes(b"not a program")
    fresh()
    out = _call(_programs.stored_program("spring", _program(traces), args,
                                         log=reports.append), args)
    assert len(reports) == 1 and "unreadable" in reports[0]
    np.testing.assert_allclose(out[0], 2.0 * np.arange(1.0, 4.0), rtol=1e-12)
    fresh()
    _programs.stored_program("spring", _program(traces), args, log=reports.append)
    assert len(traces) == 2 and len(reports) == 1  # the replacement loads


def test_no_cache_folder_saves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(_programs, "_folder", lambda: None)
    monkeypatch.setattr(_programs, "_LOADED", {})
    traces = []
    args = (jnp.ones(3), Spring(jnp.asarray(3.0), 2), jax.random.key(2))
    out = _call(_programs.stored_program("spring", _program(traces), args), args)
    np.testing.assert_allclose(out[0], 3.0 * np.ones(3), rtol=1e-12)
    assert not any(tmp_path.iterdir())


def test_a_stored_array_is_computed_once_per_input_values(fresh, tmp_path):
    calls = []

    def compute(x):
        calls.append(1)
        return np.cumsum(np.asarray(x)) * 2.0

    x, key = jnp.linspace(0.0, 1.0, 6), jax.random.key(1)
    first = _programs.stored_array("sums", lambda: compute(x), (x, key))
    again = _programs.stored_array("sums", lambda: compute(x), (x, key))
    np.testing.assert_array_equal(again, np.cumsum(np.linspace(0.0, 1.0, 6)) * 2.0)
    np.testing.assert_array_equal(first, again)
    assert len(calls) == 1
    # Other values of the same shapes, another key: computed again.
    _programs.stored_array("sums", lambda: compute(x + 1.0), (x + 1.0, key))
    _programs.stored_array("sums", lambda: compute(x), (x, jax.random.key(2)))
    assert len(calls) == 3
    # An unreadable file is reported and computed again.
    for path in (tmp_path / "programs").iterdir():
        path.write_bytes(b"not an array")
    messages = []
    out = _programs.stored_array("sums", lambda: compute(x), (x, key), log=messages.append)
    assert len(calls) == 4 and messages and "unreadable" in messages[0]
    np.testing.assert_array_equal(out, first)


def test_a_saved_program_is_keyed_by_every_source_file_of_the_package():
    # A program traced from the old SLIP solver must not be loaded after the solver changes:
    # the key covers each module of every subpackage, not only its own folder's.
    import pathlib

    import jaxhop

    root = pathlib.Path(jaxhop.__file__).parent
    expected = sorted(str(p.relative_to(root)) for p in root.rglob("*.py"))
    assert sorted(_programs.source_files()) == expected
    assert "_models/slip/kernels.py" in expected and "parkour/_run.py" in expected


def test_every_run_setting_has_the_same_argument_types():
    # A compiled run program is chosen by its arguments' types, weak typing included (a
    # Python float is weakly typed, a NumPy scalar or a given tuple is not): every way of
    # writing a tolerance or a disturbance must give the same types, else each compiles a
    # program of its own (the default tolerance once did, beside every given one).
    from jaxhop._control.runloop import RunConfig, run_config
    from jaxhop._core.params import Disturbance, disturbance_for

    def types(tree):
        return [(x.dtype, x.shape, x.weak_type) for x in map(jax.typeof, jax.tree.leaves(tree))]

    goal = np.array([9.0, 1.5, 0.0])
    configs = [run_config(goal), run_config(goal, (0.05, 0.05, 0.15)),
               run_config(goal, np.array([0.1, 0.1, 0.1])), run_config(goal, [1, 1, 1]),
               RunConfig(list(goal), (0.05, 0.05, 0.05)), RunConfig(jnp.asarray(goal))]
    assert all(types(c) == types(configs[0]) for c in configs)
    worlds = [Disturbance(), Disturbance(wind=-0.2), Disturbance(wind=np.float64(-0.2)),
              Disturbance(wind=jnp.float32(1), landing=1, sensor=[0.1, 0.1, 0.1]),
              disturbance_for("wind+sensor+landing")]
    assert all(types(d) == types(worlds[0]) for d in worlds)
    assert float(worlds[2].wind) == -0.2 and worlds[0].sensor.shape == (3,)


def test_importing_jaxhop_caches_small_programs_only_in_its_own_cache(tmp_path):
    """jaxhop's own compilation cache keeps every program (JAX's default: those that took a
    second); a cache directory or a minimum the user set is left as it is."""
    probe = ("import jax, jaxhop; c = jax.config; "
             "print(c.jax_compilation_cache_dir, c.jax_persistent_cache_min_compile_time_secs)")
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS")}
    env["JAXHOP_CACHE"] = str(tmp_path / "own")
    cases = {
        "own": env,
        "user dir": {**env, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "user")},
        "user minimum": {**env, "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "2.5"},
    }
    procs = {name: subprocess.Popen([sys.executable, "-c", probe], env=e, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for name, e in cases.items()}
    out = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr
        folder, minimum = stdout.split()
        out[name] = (folder, float(minimum))
    assert out["own"] == (str(tmp_path / "own" / "xla"), 0.0)
    assert out["user dir"][0] == str(tmp_path / "user")
    assert out["user dir"][1] == 1.0  # JAX's own default, untouched
    assert out["user minimum"] == (str(tmp_path / "own" / "xla"), 2.5)


def test_a_plan_stage_runs_from_its_saved_program_in_a_new_process(fresh, tmp_path,
                                                                   monkeypatch):
    # The stages of a plan (here screening) are saved programs too: a new process loads
    # each shape's program instead of tracing it, and it computes what `jax.jit` does.
    from jaxhop._core.params import Hopper
    from jaxhop._core.terrain import builtin_terrain, segments
    from jaxhop._planning import stages as S
    from jaxhop._planning.policies import PairGrid
    from jaxhop._planning.templates import paper_templates

    traces = []
    screen = S._screen

    def counted(*args, **kw):
        traces.append(1)  # runs only while tracing
        return screen(*args, **kw)

    monkeypatch.setattr(S, "_screen", counted)
    terrain, tm, hop, grid = builtin_terrain("flat"), paper_templates(), Hopper(), PairGrid(4, 4)
    lay = S.Layout(terrain, segments(terrain, tm.seg_length), tm, hop)
    rows, cols = np.nonzero(np.ones((40, 40), bool))
    args = lay.pair_args(rows * 7, cols * 7)
    first = S.screen(lay, args, grid)
    assert len(traces) == 1
    assert [p.name.split("-")[1] for p in (tmp_path / "programs").iterdir()] == ["screen"]
    fresh()  # as a new process: nothing loaded
    again = S.screen(lay, args, grid)
    assert len(traces) == 1  # loaded from disk, not traced
    plain = jax.jit(screen, static_argnames=("grid",))(
        *(jnp.asarray(a) for a in args), lay.jtable, tm, hop, lay.limits(grid), grid=grid)
    assert first.any() and not first.all()
    np.testing.assert_array_equal(again, first)
    np.testing.assert_array_equal(again, np.asarray(plain))
