"""Plan, deployment and execution on the small `flat` terrain."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp

import jaxhop
from jaxhop._control.decisions import first_match
from jaxhop._control.runloop import run_one
from jaxhop._core.batching import pad_terrain
from jaxhop._core.params import Disturbance, disturbance_for
from jaxhop._core.terrain import builtin_terrain, make_terrain, segments
from jaxhop._execution.batches import run_batch, sweep
from jaxhop._models.flight import OK, SUCCESS, touchdown
from jaxhop._planning.cache import get_plan
from jaxhop._planning.deploy import check_order
from jaxhop._planning.plan import bucketed, build_plan
from jaxhop._planning.regions import template_domain_contains


@pytest.fixture(scope="module")
def plan():
    return build_plan(builtin_terrain("flat"), progress=False)


def test_counts(plan):
    s = plan.stats
    assert s["n_segments"] == 20 and s["n_situated"] == 400
    assert s["n_goal_policies"] >= 1 and s["n_dropped"] == 0
    assert s["n_deployed"] == s["n_instantiated"] > 1000
    assert plan.order.size == np.unique(plan.order).size


def _domain_brute(z, plan):
    """Every situated domain containing z: simulate the descent, then the template test."""
    terrain, t = plan.terrain, plan.templates
    segs = segments(terrain)
    code, block, _, y_foot, _ = touchdown(jnp.asarray(z), jnp.array([0.0, -1.0]), terrain,
                                          plan.hopper)
    out = set()
    if int(code) != OK:
        return out
    for j, (py, h) in enumerate(np.asarray(segs.centre)):
        if int(segs.block[j]) != int(block) or abs(float(y_foot) - py) > 0.075 + 1e-12:
            continue
        for k in range(t.n):
            rel = jnp.array([z[0] - py, z[1] - h - 1.0, z[2]])
            if bool(template_domain_contains(rel, t.row(k), plan.hopper)):
                out.add(j * t.n + k)
    return out


@pytest.mark.slow
def test_prepares_relation_against_brute_force(plan):
    rng = np.random.default_rng(0)
    p = plan.prepares.tocsr()
    for a in rng.choice(plan.situated.size, 60, replace=False):
        row = set(p.indices[p.indptr[a]:p.indptr[a + 1]].tolist())
        assert row == _domain_brute(plan.goals[a], plan)
        if not plan.is_goal[a]:
            assert plan.target[a] in row  # the goal lies in the domain it was chosen for


@pytest.mark.slow
def test_deployment_invariant(plan):
    assert check_order(plan.order, plan.prepares, plan.situated, plan.is_goal)
    # Independent of the stored relation: every non-goal policy's goal lies in the domain of
    # a policy deployed earlier.
    seen = set()
    rng = np.random.default_rng(1)
    checks = set(rng.choice(plan.order.size, 80, replace=False).tolist())
    for pos, a in enumerate(plan.order):
        if pos in checks and not plan.is_goal[a]:
            assert _domain_brute(plan.goals[a], plan) & seen
        seen.add(int(plan.situated[a]))


def test_deployment_invariant_breaks_when_order_is_shuffled(plan):
    order = plan.order[::-1].copy()
    assert not check_order(order, plan.prepares, plan.situated, plan.is_goal)


def test_nominal_sweep_is_correct_by_construction(plan):
    summary, initial, result = sweep(plan, jaxhop.RunSettings(controller="paper"),
                                     initial=jaxhop.SweepGrid(dy=0.1, dz=0.1))
    assert summary["n_initial_conditions"] > 200
    assert summary["success_rate"] == 1.0 and summary["failures"]["solver"] == 0


@pytest.mark.slow
def test_run_jit_vmap_and_seed_reproducibility(plan):
    tables = plan.tables()
    starts = np.array([[0.4, 1.6, 0.5], [1.2, 1.9, 0.5], [2.0, 1.4, 0.5]])
    from jaxhop._control.runloop import RunConfig

    cfg = RunConfig(goal=jnp.asarray(plan.goal), max_steps=12)
    dist = disturbance_for("sensor")
    keys = [jax.random.fold_in(jax.random.key(7), i) for i in range(3)]
    with jax.disable_jit():
        eager = [run_one(jnp.asarray(s), k, tables, plan.terrain, plan.hopper, dist, cfg)
                 for s, k in zip(starts[:1], keys[:1])]
    batched = run_batch(plan, starts, jaxhop.RunSettings(max_steps=12, controller="paper"),
                        key=jax.random.key(7), disturbance=dist)
    # Run 0 alone equals run 0 in the batch (keys do not depend on the batch).
    loop = [run_batch(plan, starts[i:i + 1], jaxhop.RunSettings(max_steps=12, controller="paper"),
                      key=jax.random.key(7), disturbance=dist) for i in range(1)]
    assert int(eager[0][0]) == int(batched["code"][0]) == int(loop[0]["code"][0])
    np.testing.assert_array_equal(loop[0]["apexes"][0], batched["apexes"][0])
    np.testing.assert_allclose(np.asarray(eager[0][2]), batched["apexes"][0], atol=1e-12)
    again = run_batch(plan, starts, jaxhop.RunSettings(max_steps=12, controller="paper"),
                      key=jax.random.key(7), disturbance=dist)
    np.testing.assert_array_equal(again["apexes"], batched["apexes"])
    other = run_batch(plan, starts, jaxhop.RunSettings(max_steps=12, controller="paper"),
                      key=jax.random.key(8), disturbance=dist)
    assert not np.array_equal(other["apexes"], batched["apexes"])


@pytest.mark.slow
def test_vmap_equals_loop_for_first_match(plan):
    tables = plan.tables()
    rng = np.random.default_rng(3)
    z = np.stack([rng.uniform(0, 3, 40), rng.uniform(1.1, 2.4, 40), rng.uniform(-2, 2, 40)], 1)
    fm = jax.jit(lambda a: first_match(a, tables, plan.hopper))
    batched = jax.vmap(lambda a: first_match(a, tables, plan.hopper))(jnp.asarray(z))
    for i in range(40):
        single = fm(jnp.asarray(z[i]))
        assert all(int(x) == int(y[i]) for x, y in zip(single, batched))


def test_first_match_is_first_in_order(plan):
    tables = plan.tables()
    rank = np.empty(plan.order.size, int)
    rank[plan.order] = np.arange(plan.order.size)
    rng = np.random.default_rng(4)
    for _ in range(20):
        z = np.array([rng.uniform(0.3, 2.7), rng.uniform(1.15, 2.3), rng.uniform(-1.5, 1.5)])
        found, s, a = (int(v) for v in first_match(jnp.asarray(z), tables, plan.hopper))
        inside = _domain_brute(z, plan)
        deployed = [x for x in plan.order if int(plan.situated[x]) in inside]
        assert bool(found) == bool(deployed)
        if deployed:
            assert a == deployed[0]


def test_goal_reached_exactly_without_noise(plan):
    r = run_batch(plan, np.array([[0.5, 1.6, 0.5]]), jaxhop.RunSettings(controller="paper"),
                  disturbance=Disturbance())
    assert int(r["code"][0]) == SUCCESS
    last = r["apexes"][0][int(r["steps"][0])]
    np.testing.assert_allclose(last, plan.goal, atol=1e-9)


def test_cache_round_trip_and_corruption(tmp_path, monkeypatch, plan):
    monkeypatch.setenv("JAXHOP_CACHE", str(tmp_path))
    terrain = builtin_terrain("flat")
    first = get_plan(terrain, progress=False)
    assert first.stats["from_cache"] is False
    again = get_plan(terrain, progress=False)
    assert again.stats["from_cache"] is True
    np.testing.assert_array_equal(again.order, first.order)
    np.testing.assert_array_equal(again.goals, first.goals)
    assert (again.prepares != first.prepares).nnz == 0
    (path,) = list(tmp_path.glob("plan-*.npz"))
    path.write_bytes(path.read_bytes()[:1000])
    messages = []
    rebuilt = get_plan(terrain, progress=False, log=messages.append)
    assert len(messages) == 1 and "corrupt" in messages[0]
    np.testing.assert_array_equal(rebuilt.order, first.order)


@pytest.mark.slow
def test_padded_tables_match_as_the_plans_own_and_share_one_shape(plan):
    # Padding for one compiled controller must never match: first matches through the
    # bucketed tables are the brute-force ones, recovery picks what the plan's own tables
    # pick, and a foot landing exactly on the map's end (where the zero-length padded
    # blocks begin) lands on the last real block.
    tables, true = bucketed(plan.tables(), plan.terrain)
    assert tables.goals.shape[0] > plan.goals.shape[0] and true.n_blocks > 1
    rng = np.random.default_rng(5)
    match = jax.jit(lambda z, tb: first_match(z, tb, plan.hopper, recover=True))
    for _ in range(20):
        z = np.array([rng.uniform(-0.2, 3.2), rng.uniform(1.15, 2.3), rng.uniform(-1.5, 1.5)])
        padded = [int(x) for x in match(jnp.asarray(z), tables)]
        inside = _domain_brute(z, plan)
        deployed = [x for x in plan.order if int(plan.situated[x]) in inside]
        found, _, a, recovered = padded
        assert (found and not recovered) == bool(deployed)
        assert not deployed or a == deployed[0]
        assert padded == [int(x) for x in match(jnp.asarray(z), plan.tables())]
    end = float(plan.terrain.ends[-1])
    for terrain in (plan.terrain, pad_terrain(plan.terrain, 4)):
        code, block, *_ = touchdown(jnp.array([end, 1.5, 0.0]), jnp.array([0.0, -1.0]),
                                    terrain, plan.hopper)
        assert (int(code), int(block)) == (OK, plan.terrain.n_blocks - 1)
    # A plan on another map of about the same size (a step in it, another number of
    # policies, another name) pads to the same shapes, so both run on one compiled program.
    other = build_plan(make_terrain([(0.0, 1.5, 0.0), (1.5, 3.0, 0.1)], (2.5, 1.4, 0.0)),
                       progress=False)
    assert other.goals.shape != plan.goals.shape
    shapes = [jax.tree.map(jnp.shape, bucketed(p.tables(), p.terrain)) for p in (plan, other)]
    assert jax.tree.structure(shapes[0]) == jax.tree.structure(shapes[1])
    assert jax.tree.leaves(shapes[0]) == jax.tree.leaves(shapes[1])


@pytest.mark.slow
def test_shipped_template_boxes_are_the_ones_computed_op_by_op():
    """The built-in templates' boxes that ship with jaxhop (read instead of computed) are
    the boxes computed anew, and a plan reads them (bit for bit on the machine that wrote
    them; within 1e-9 where XLA's transcendental functions round otherwise)."""
    from jaxhop._planning.plan import templates_for
    from jaxhop._planning.stages import SHIPPED_BOXES, box_key, computed_boxes, relative_boxes

    hopper = jaxhop.Hopper()
    with np.load(SHIPPED_BOXES) as shipped:
        assert len(shipped.files) == 2
        for model in ("bhop", "slip"):
            templates = templates_for(model)
            boxes = shipped[box_key(templates, hopper)]
            np.testing.assert_allclose(boxes, computed_boxes(templates, hopper), rtol=0,
                                       atol=1e-9)
            read = relative_boxes(templates, hopper)
            assert np.array_equal(read[0], boxes[0]) and np.array_equal(read[1], boxes[1])
    # Another hopper has other boxes, and is not among the shipped ones.
    assert box_key(templates_for("bhop"), jaxhop.Hopper(rho0=0.5)) not in shipped.files


def test_plan_does_not_depend_on_chunk_sizes(plan, monkeypatch):
    # Chunks of 48 pairs (192 screened) and 80 goals: the flat plan's stages run in many
    # chunks, each last one padded by repeating its last item, where the default sizes
    # hold each stage in one or two chunks. Every policy, goal, score, prepares edge and
    # the deployment order must come out the same, bit for bit.
    from jaxhop._planning import stages

    monkeypatch.setattr(stages, "PAIR_CHUNK", 48)
    monkeypatch.setattr(stages, "SCREEN_CHUNK", 192)
    monkeypatch.setattr(stages, "ROW_CHUNK", 80)
    small = build_plan(builtin_terrain("flat"), progress=False)
    for name in ("situated", "target", "goals", "safety", "margin", "is_goal", "robustness",
                 "order"):
        np.testing.assert_array_equal(getattr(small, name), getattr(plan, name), err_msg=name)
    assert (small.prepares != plan.prepares).nnz == 0
    assert plan.stats["n_screened_pairs"] > 4 * 192 and plan.stats["n_instantiated"] > 4 * 80


def test_candidate_pairs_are_every_overlapping_pair_in_order():
    # Against the definition, every pair of boxes tested: 700 `Gf` boxes in segment order
    # (chunks of 256 rows) and 500 domains, with edges on a 0.05 grid so that many boxes
    # touch exactly (touching boxes overlap), some wide domains, and a domain with
    # an infinite extent in ydot.
    from jaxhop._planning.policies import candidate_pairs

    rng = np.random.default_rng(3)

    def boxes(n, y_width):
        lo = np.sort(np.round(rng.uniform(0, 30, n) / 0.05) * 0.05)
        w = np.round(rng.uniform(0.05, y_width, n) / 0.05) * 0.05
        z = np.round(rng.uniform(1, 2, (n, 1)) / 0.05) * 0.05
        v = np.round(rng.uniform(-2, 2, (n, 1)) / 0.05) * 0.05
        return np.stack([np.stack([lo, lo + w], -1), np.concatenate([z, z + 0.3], 1),
                         np.concatenate([v, v + 1.0], 1)], 1)

    gf, d = boxes(700, 1.0), boxes(500, 3.0)
    d = d[rng.permutation(500)]  # domains in any order
    d[7, 2] = [-np.inf, np.inf]
    rows, cols = candidate_pairs(gf, d)
    every = np.all((gf[:, None, :, 0] <= d[None, :, :, 1])
                   & (d[None, :, :, 0] <= gf[:, None, :, 1]), axis=2)
    r, c = np.nonzero(every)
    assert r.size > 1000
    np.testing.assert_array_equal(rows, r)
    np.testing.assert_array_equal(cols, c)


@pytest.mark.parametrize("seed", range(8))
def test_deploy_equals_the_twins_queue_on_random_graphs(seed):
    # `deploy` computes the queue's order in bulk; the twin pops a heap of `(key, policy)`
    # tuples one by one. Random graphs where the bulk shortcuts can go wrong: many policies
    # per situated policy, goals sharing a situated policy with cheaper preparers, robustness
    # in a few classes (a policy that joins later jumps ahead of queued ones), keys that
    # tie exactly, policies never reached, and enough of them that the expansions are
    # tried hundreds at a time.
    from jaxhop import reference as R
    from jaxhop._planning.deploy import PICKBEST, deploy

    rng = np.random.default_rng(seed)
    n_sit = int(rng.integers(5, 400))
    n = int(rng.integers(1, 12)) * n_sit
    situated = rng.integers(0, n_sit, n)
    per_row = rng.integers(0, 4, n)
    rows = np.repeat(np.arange(n), per_row)
    cols = rng.integers(0, n_sit, rows.size)
    p = sp.csr_matrix((np.ones(rows.size, bool), (rows, cols)), shape=(n, n_sit))
    p.sum_duplicates()
    is_goal = rng.random(n) < 3.0 / n
    is_goal[rng.integers(n)] = True
    safety = np.round(rng.random(n), int(rng.integers(1, 4)))
    robustness = rng.integers(0, 4, n) / 3
    for pick, key in PICKBEST.items():
        order = deploy(p, situated, safety, is_goal, robustness, key)
        assert np.array_equal(order, R.deploy(p, situated, safety, is_goal, robustness, key)), pick
    assert check_order(order, p, situated, is_goal)
