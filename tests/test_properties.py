"""Property-based tests (hypothesis): loaders fail only with InputError; model invariants."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import jaxhop
from jaxhop import InputError
from jaxhop._cli.main import main
from jaxhop._core.params import Hopper
from jaxhop._core.terrain import terrain_from_dict
from jaxhop._models.bhop import bhop_apex_map, deadbeat_bhop, stance

HOP = Hopper()

numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64),
                    st.integers(-10, 10), st.text(max_size=3), st.booleans(), st.none())
block = st.one_of(
    st.fixed_dictionaries({"start": numbers, "end": numbers, "height": numbers}),
    st.dictionaries(st.sampled_from(["start", "end", "height", "x"]), numbers, max_size=4),
    numbers, st.lists(numbers, max_size=3))
terrain_json = st.one_of(
    st.dictionaries(st.sampled_from(["name", "blocks", "goal", "extra"]),
                    st.one_of(st.lists(block, max_size=6), numbers,
                              st.lists(numbers, max_size=4)), max_size=4),
    st.lists(block, max_size=3), numbers)


@settings(max_examples=400, deadline=None)
@given(terrain_json)
def test_terrain_loader_accepts_or_raises_input_error(data):
    try:
        t = terrain_from_dict(data)
    except InputError as err:
        assert "\n" not in str(err) and str(err)
        return
    blocks = t.blocks()
    assert blocks and all(math.isfinite(v) for b in blocks for v in b)
    assert all(s < e for s, e, _ in blocks)
    assert all(blocks[i][1] <= blocks[i + 1][0] + 1e-12 for i in range(len(blocks) - 1))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.function_scoped_fixture])
@given(terrain_json)
def test_cli_malformed_terrain_file_exits_2(tmp_path_factory, capsys, data):
    path = tmp_path_factory.mktemp("t") / "t.json"
    path.write_text(json.dumps(data, allow_nan=True))
    capsys.readouterr()
    try:
        terrain_from_dict(data)
        valid = True
    except InputError:
        valid = False
    # A valid terrain would start planning, not what this test is about: hypothesis draws
    # again (and fails the test as unsatisfiable if it finds too few invalid files).
    assume(not valid)
    assert main(["plan", "--terrain", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxhop: error:") and len(err.splitlines()) == 1


finite = st.floats(-2.4, 2.4)


@settings(max_examples=200, deadline=None)
@given(h=st.floats(-0.5, 0.5), zr0=st.floats(0.02, 1.4), zr1=st.floats(0.02, 1.4),
       y0=st.floats(-3, 3), dy=st.floats(-1, 1), v0=finite, v1=finite)
def test_deadbeat_round_trip_property(h, zr0, zr1, y0, dy, v0, v1):
    apex = jnp.array([y0, h + 1.0 + zr0, v0])
    goal = jnp.array([y0 + dy, h + 1.0 + zr1, v1])
    u = deadbeat_bhop(apex, goal, h, HOP)
    if not np.all(np.isfinite(np.asarray(u))):
        return  # unreachable target (k = inf): no control exists
    np.testing.assert_allclose(np.asarray(bhop_apex_map(apex, u, h, HOP)), np.asarray(goal),
                               atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(vy=finite, vz=st.floats(-6, -0.01), th=st.floats(-1.5, 1.5), k=st.floats(0.5, 1.5))
def test_stance_energy_scales_with_k_squared_along_the_leg(vy, vz, th, k):
    v = jnp.array([vy, vz])
    _, v_lo = stance(0.0, v, jnp.array([0.0, th, k]))
    n = np.array([-np.sin(th), np.cos(th)])
    t = np.array([np.cos(th), np.sin(th)])
    vt, vn = float(v @ t), float(v @ n)
    assert float(v_lo @ t) == pytest.approx(vt, abs=1e-12)
    assert float(v_lo @ n) == pytest.approx(-k * vn, abs=1e-12)


@pytest.mark.slow
@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1))
def test_deployment_invariant_and_nominal_success_on_random_terrains(seed):
    import jax

    from jaxhop._core.terrain import random_terrain
    from jaxhop._execution.batches import sweep
    from jaxhop._planning.deploy import check_order
    from jaxhop._planning.plan import build_plan

    terrain = random_terrain(jax.random.key(seed), 5.0)
    plan = build_plan(terrain, progress=False)
    assert check_order(plan.order, plan.prepares, plan.situated, plan.is_goal)
    summary, _, _ = sweep(plan, jaxhop.RunSettings(controller="paper"),
                          initial=jaxhop.SweepGrid(dy=0.15, dz=0.15))
    assert summary["n_initial_conditions"] > 0
    assert summary["success_rate"] == 1.0 and summary["failures"]["solver"] == 0


bad_number = st.one_of(st.sampled_from(["nan", "inf", "-inf", "", "1e400", "x", "0x10", "--"]),
                       st.text(alphabet="abc,;: ", min_size=1, max_size=5))
triple_bad = st.one_of(bad_number,
                       st.lists(st.floats(-5, 5), min_size=1, max_size=5)
                       .filter(lambda v: len(v) != 3).map(lambda v: ",".join(map(str, v))),
                       st.tuples(st.floats(-5, 5), st.floats(-5, 5), bad_number)
                       .map(lambda t: f"{t[0]},{t[1]},{t[2]}"))
positive_bad = st.one_of(bad_number, st.floats(-10, 0).map(str))


@settings(max_examples=600, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(
    st.tuples(st.sampled_from(["sweep", "run"]), st.sampled_from(["--goal", "--tolerance"]),
              triple_bad),
    st.tuples(st.just("run"), st.just("--apex"), triple_bad),
    st.tuples(st.just("sweep"), st.sampled_from(["--dy", "--dz", "--chunk", "--max-steps"]),
              positive_bad),
    st.tuples(st.sampled_from(["sweep", "run"]), st.just("--seed"),
              st.one_of(bad_number, st.integers(-10**6, -1).map(str),
                        st.just(str(2**63))))))
def test_cli_rejects_bad_numbers_with_exit_2(capsys, case):
    command, option, value = case
    capsys.readouterr()  # examples share the fixture: start from empty streams
    if option == "--tolerance" and value.count(",") == 2:
        parts = value.split(",")
        try:
            assume(not all(math.isfinite(float(p)) and float(p) >= 0 for p in parts))
        except ValueError:
            pass
    assert main([command, "--terrain", "flat", f"{option}={value}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxhop: error:") and len(err.splitlines()) == 1
