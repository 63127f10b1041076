"""Goal policies for any goal over a landable block, and a clear refusal where there is none.

A global goal on the boundary between two segments lies on the edge of both neighbours'
feasible goal sets (`Gf`); rounding in `y - py` used to put it just outside each, so the
plan had no goal policy at all. The goal-policy test now has 1e-9 m of slack in `y`
(docs/decisions.md, "Goals on segment boundaries").
"""

import math

import jax
import numpy as np
import pytest

from jaxhop import reference as R
from jaxhop._core.errors import InputError
from jaxhop._core.params import Hopper
from jaxhop._core.terrain import make_terrain, segments
from jaxhop._planning import stages as S
from jaxhop._planning.plan import build_plan
from jaxhop._planning.templates import paper_templates
from jaxhop.reference._plan import goal_policies as ref_goal_policies

jax.config.update("jax_enable_x64", True)

# A random terrain of the kind `random_terrain(10, 9.6)` draws: the goal apex (8.85, 1.3, 0)
# lies 5 segment lengths into the flat block 8.1-9.6 m, on a segment boundary.
RANDOM_BLOCKS = [(0.0, 1.35, 0.0), (1.35, 2.85, -0.2), (2.85, 3.75, 0.2), (3.75, 4.65, 0.0),
                (4.65, 5.7, -0.05), (5.7, 7.2, 0.25), (7.2, 8.1, -0.2), (8.1, 9.6, 0.0)]
# One 1.5 m block of 10 segments; y = 0.6 is the boundary between its 4th and 5th.
HAND_BLOCKS = [(0.0, 1.5, 0.0)]


def _goal_set(terrain, goal):
    """Situated policies (ids) that reach `goal`, by the plan's own stage."""
    tm, hp = paper_templates(), Hopper()
    lay = S.Layout(terrain, segments(terrain, tm.seg_length), tm, hp)
    ok, margin = S.goal_policies(lay, np.asarray(goal, float), np.arange(lay.n_sit),
                                 chunk=None)
    assert np.all(np.isfinite(margin[ok])) and np.all(margin[ok] > 0)
    return set(np.nonzero(ok)[0].tolist())


def _on_boundary(terrain, y):
    centre = np.asarray(segments(terrain).centre)[:, 0]
    return np.min(np.abs(np.abs(centre - y) - 0.075)) < 1e-12


@pytest.mark.parametrize("blocks, y", [(RANDOM_BLOCKS, 8.85), (HAND_BLOCKS, 0.6)],
                         ids=["random-terrain", "hand-built"])
def test_goal_on_a_segment_boundary_gets_goal_policies(blocks, y):
    terrain = make_terrain(blocks)
    assert _on_boundary(terrain, y)
    on = _goal_set(terrain, (y, 1.3, 0.0))
    right = _goal_set(terrain, (y + 1e-6, 1.3, 0.0))
    left = _goal_set(terrain, (y - 1e-6, 1.3, 0.0))
    # Nudged either way the goal lies inside one neighbour's Gf (forward templates from the
    # segment on the left, backward ones from the right, by symmetry as many); on the
    # boundary it belongs to both.
    assert left and right and len(left) == len(right)
    assert on == left | right
    # The NumPy twin agrees.
    rt = R.Terrain.from_blocks(terrain.blocks(), None)
    sit = R.situate(rt, R.Templates(paper_templates().as_array(), 0.15), R.Hopper())
    ok, _ = ref_goal_policies(sit, np.array([y, 1.3, 0.0]))
    assert set(np.nonzero(ok)[0].tolist()) == on


def test_goal_off_a_boundary_is_unchanged():
    """Away from boundaries the slack changes nothing: 8.90 gives the 6 it always gave."""
    assert len(_goal_set(make_terrain(RANDOM_BLOCKS), (8.90, 1.3, 0.0))) == 6


@pytest.mark.parametrize("goal, needle", [
    ((3.0, 1.3, 0.0), "lies over the hole 2-4 m"),
    ((1.0, 5.0, 0.0), "height 4 m above the block under it (0-2 m, height 0 m)"),
    ((1.0, 1.3, 6.0), "holds the speed 6 m/s"),
    ((7.0, 1.3, 0.0), "off the map [0, 6]"),
])
def test_a_goal_without_goal_policy_is_refused_with_the_reason(goal, needle):
    terrain = make_terrain([(0.0, 2.0, 0.0), (4.0, 6.0, 0.0)])
    with pytest.raises(InputError) as err:
        build_plan(terrain, goal, progress=False)
    msg = str(err.value)
    assert "has no goal policy" in msg and needle in msg and "\n" not in msg


def test_the_refused_energy_is_outside_the_goal_heights():
    """The heights the message quotes bound the templates' `Gf` at that speed: a goal just
    inside them is planned (it has goal policies), one just outside is refused."""
    terrain = make_terrain([(0.0, 2.0, 0.0)])
    with pytest.raises(InputError) as err:
        build_plan(terrain, (1.0, 5.0, 0.0), progress=False)
    hi = float(str(err.value).rsplit("-", 1)[1].split(" ")[0])
    assert _goal_set(terrain, (1.0, 1.0 + hi - 0.01, 0.0))
    assert not _goal_set(terrain, (1.0, 1.0 + hi + 0.01, 0.0))


def test_cli_refuses_an_unreachable_goal_in_one_line(tmp_path, monkeypatch, capsys):
    from jaxhop._cli.main import main

    monkeypatch.setenv("JAXHOP_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "t.json"
    path.write_text('{"blocks": [{"start": 0, "end": 2, "height": 0}, '
                    '{"start": 4, "end": 6, "height": 0}]}')
    assert main(["sweep", "--terrain", str(path), "--goal", "3,1.3,0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "goal (3, 1.3, 0) has no goal policy" in err
    assert "hole" in err and "is the goal reachable" not in err


def test_boundary_goal_plan_has_goal_policies_and_deploys():
    """The small hand-built terrain with its goal on a boundary plans end to end."""
    plan = build_plan(make_terrain(HAND_BLOCKS), (0.6, 1.3, 0.0), progress=False)
    assert plan.stats["n_goal_policies"] == len(_goal_set(make_terrain(HAND_BLOCKS),
                                                          (0.6, 1.3, 0.0))) > 0
    assert plan.stats["n_deployed"] > plan.stats["n_goal_policies"]
    assert math.isfinite(plan.safety[plan.is_goal].min())
