"""A plain NumPy/SciPy twin of jaxhop's BHop pipeline, for equivalence tests and benchmarks.

The SLIP model (stance with `scipy.integrate.solve_ivp`, stride on a terrain, deadbeat) is
in `jaxhop.reference._slip`; `run_one` / `run_batch` / `sweep` take `model="slip"`.

It imports neither jax nor the JAX modules of jaxhop. It computes the same things in the
same order of floating-point operations, but the way the paper's algorithm is written:
one candidate pair, one goal, one initial condition at a time, vectorised only within one
pair's 16 x 16 goal grid, one goal's 27 safety probes, or one stride's terrain blocks.

Inputs are plain data: `Terrain.from_blocks(blocks, goal)`, `Templates(rows, seg_length)`
(rows as in `jaxhop.Templates.as_array()`), `Hopper(m, g, rho0)`.
"""

from ._deadbeat import DeadbeatSearch as DeadbeatSearch
from ._deadbeat import deadbeat_slip as deadbeat_slip
from ._execute import Controller as Controller
from ._execute import in_global_domain as in_global_domain
from ._execute import run_batch as run_batch
from ._execute import run_one as run_one
from ._execute import summarize as summarize
from ._execute import sweep as sweep
from ._execute import sweep_grid as sweep_grid
from ._model import FAILURE_NAMES as FAILURE_NAMES
from ._model import Hopper as Hopper
from ._model import Templates as Templates
from ._model import Terrain as Terrain
from ._model import bhop_apex_map as bhop_apex_map
from ._model import bhop_stride as bhop_stride
from ._model import deadbeat_bhop as deadbeat_bhop
from ._model import paper_templates as paper_templates
from ._model import segments as segments
from ._model import touchdown as touchdown
from ._model import touchdown_one as touchdown_one
from ._plan import Plan as Plan
from ._plan import build_plan as build_plan
from ._plan import deploy as deploy
from ._plan import depth_key as depth_key
from ._plan import goal_policies as goal_policies
from ._plan import instantiate as instantiate
from ._plan import prepares_and_robustness as prepares_and_robustness
from ._plan import robust_key as robust_key
from ._plan import safety_key as safety_key
from ._plan import situate as situate
from ._policies import Situation as Situation
from ._policies import candidate_pairs as candidate_pairs
from ._policies import goal_policy_margin as goal_policy_margin
from ._policies import pair_box as pair_box
from ._policies import pair_goal as pair_goal
from ._policies import situate_goal as situate_goal
from ._policies import world_boxes as world_boxes
from ._regions import TemplateRegions as TemplateRegions
from ._regions import template_boxes as template_boxes
from ._slip import slip_apex_map as slip_apex_map
from ._slip import slip_stride as slip_stride
