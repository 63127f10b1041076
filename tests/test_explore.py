"""The explorers draw what `run_batch`, `slip_stride` and `deadbeat_slip` compute when called
directly with the same inputs, and a value change compiles nothing."""

import contextlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhop

pytest.importorskip("ipywidgets")

EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/backend_compile_duration")


@contextlib.contextmanager
def compilations():
    """The functions traced or compiled inside the block."""
    seen = []

    def listen(event, duration, **kwargs):
        if event in EVENTS:
            seen.append((event.rsplit("/", 1)[1], kwargs.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield seen
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)


def _finite(rows):
    rows = np.asarray(rows)
    return rows[np.all(np.isfinite(rows), axis=1)]


def _xy(line):
    return np.asarray(line.get_xydata(), float)


@pytest.mark.slow
def test_explore_draws_the_runs_and_policies_of_run_batch():
    plan = jaxhop.get_plan(jaxhop.builtin_terrain("flat"), progress=False)
    ex = jaxhop.explore(plan, [0.4, 1.6, 0.5])
    apex = [0.55, 1.65, 0.55]
    nominal = jaxhop.run_batch(plan, [apex])
    windy = jaxhop.run_batch(plan, [apex], jaxhop.RunSettings(controller="paper"),
                             key=jax.random.key(3), disturbance=jaxhop.disturbance_for("wind"))
    assert nominal["code"][0] == jaxhop.Result.SUCCESS and nominal["steps"][0] >= 2
    first, second = (int(p) for p in nominal["policies"][0][:2])
    position = int(np.nonzero(plan.order == first)[0][0])
    with compilations() as seen:
        ex.set(y=apex[0], z=apex[1], ydot=apex[2])
        drawn = {k: _xy(ex.artists[k]) for k in ("apexes", "footholds", "path", "start")}
        title = ex.artists["run_title"].get_text()
        ex.controls["policy"].value = position
        domain = ex.artists["domain"].get_path()
        goal_region = ex.artists["goal_region"].get_path()
        goal = _xy(ex.artists["goal"])
        prepared = _xy(ex.artists["prepared"])
        ex.set(noise="wind", seed=3, controller="paper")
        windy_drawn = _xy(ex.artists["apexes"])
        windy_status = ex.status.value
    assert not seen, f"a value change traced or compiled: {seen}"

    np.testing.assert_allclose(drawn["apexes"], _finite(nominal["apexes"][0])[:, :2])
    feet = _finite(nominal["footholds"][0])
    np.testing.assert_allclose(drawn["footholds"], feet)
    np.testing.assert_allclose(drawn["start"], [apex[:2]])
    # The BHop path passes over each foothold with the leg uncompressed.
    path = drawn["path"][np.all(np.isfinite(drawn["path"]), axis=1)]
    for yf, h in feet:
        assert np.min(np.hypot(path[:, 0] - yf, path[:, 1] - h - float(plan.hopper.rho0))) < 1e-9
    steps = int(nominal["steps"][0])
    assert f"success in {steps} strides" in title
    assert ", ".join(str(int(p)) for p in nominal["policies"][0][:steps]) in title

    # The run's first policy: its domain holds the apex, its feasible goal its goal, and the
    # policy the run takes next is situated on a segment it prepares (Fig. 9-10).
    assert domain.contains_point(apex[:2])
    np.testing.assert_allclose(goal, [plan.goals[first][:2]])
    assert goal_region.contains_point(plan.goals[first][:2])
    mids = 0.5 * (prepared[0::3, 0] + prepared[1::3, 0])
    centre = np.asarray(plan.table().centre)[plan.situated[second] // plan.templates.n]
    assert np.min(np.abs(mids - centre[0])) < 1e-9
    np.testing.assert_allclose(prepared[0::3, 1], prepared[1::3, 1])

    np.testing.assert_allclose(windy_drawn, _finite(windy["apexes"][0])[:, :2])
    name = jaxhop.RESULT_NAMES[int(windy["code"][0])]
    assert f"paper controller, wind, seed 3: {name} in {int(windy['steps'][0])}" in windy_status


@pytest.mark.slow
def test_explore_stride_draws_slip_stride_and_deadbeat_slip():
    hop = jaxhop.Hopper()
    st = jaxhop.explore_stride(hop, (0.0, 1.3, 1.0))
    floor = jaxhop.make_terrain([(-10.0, 10.0, 0.0)])
    stride = jaxhop.jit(jaxhop.slip_stride)
    apex, u = jnp.array([0.1, 1.35, 1.1]), jnp.array([0.12, 22_000.0, 25_000.0])
    target = jnp.array([0.8, 1.3, 0.9])
    nxt, code, foot = (np.asarray(x) for x in stride(apex, u, floor, hop))
    u_db, ok_db = jaxhop.jit(jaxhop.deadbeat_slip)(apex, target, 0.0, hop)
    reached = np.asarray(stride(apex, u_db, floor, hop)[0])
    assert int(code) == jaxhop.Result.SUCCESS and bool(ok_db)
    with compilations() as seen:
        st.set(y=0.1, z=1.35, ydot=1.1, th=0.12, kc=22_000.0, kd=25_000.0)
        drawn = {k: _xy(st.artists[k]) for k in ("next_apex", "foot", "path")}
        status = st.status.value
        st.set(target_y=0.8, target_z=1.3, target_ydot=0.9)
        st.controls["deadbeat"].click()
        controls = [st.controls[k].value for k in ("th", "kc", "kd")]
        solved = st.result
    assert not seen, f"a value change traced or compiled: {seen}"

    np.testing.assert_allclose(drawn["next_apex"], [nxt[:2]], atol=1e-12)
    np.testing.assert_allclose(drawn["foot"], [foot], atol=1e-12)
    assert "success" in status and f"{nxt[2]:.4f}" in status
    path = _finite(drawn["path"])
    np.testing.assert_allclose(path[0], apex[:2], atol=1e-12)
    np.testing.assert_allclose(path[-1], nxt[:2], atol=1e-7)  # the rise ends at the apex
    legs = np.hypot(*(path - foot).T)
    assert legs.min() < 0.99 * float(hop.rho0)  # the stance compresses the leg

    np.testing.assert_allclose(controls, np.asarray(u_db), rtol=1e-12)
    np.testing.assert_allclose(solved["next_apex"], reached, atol=1e-9)
    error = float(np.max(np.abs(reached - np.asarray(target))))
    assert solved["deadbeat"]["ok"] and error < 1e-6
    assert solved["deadbeat"]["error"] == pytest.approx(error, abs=1e-9)


def test_explorers_name_the_extra_without_ipywidgets(monkeypatch):
    monkeypatch.setitem(sys.modules, "ipywidgets", None)
    with pytest.raises(ImportError, match=r"jaxhop\[notebook\]"):
        jaxhop.explore_stride()
