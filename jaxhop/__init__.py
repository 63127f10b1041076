"""jaxhop: reactive footstep planning for spring-mass hopping on rough terrain, in JAX.

The pipeline, in order: terrain -> models (BHop, SLIP) -> policy regions -> plan (policies,
prepares graph, deployment) -> control (decisions, run loop) -> batches and sweeps ->
figures and the command line. Everything public is re-exported here; `jaxhop.slip` holds
the SLIP model's solvers and tables, `jaxhop.mppc`, `jaxhop.parkour` and `jaxhop.mujoco`
the parkour planners and the MuJoCo hopper.

Importing jaxhop sets three things, because every number it computes depends on them:

- `jax_enable_x64`: planning and simulation run in float64;
- `EQX_ON_ERROR=nan` (unless already set): a failed solve inside a batch gives NaN and a
  result code, never an exception that ends the whole batch (`docs/decisions.md`,
  "Errors inside solves");
- JAX's compilation cache directory, unless one is set already: `$JAXHOP_CACHE/xla`
  (default `~/.cache/jaxhop/xla`), so a second process loads compiled programs instead of
  compiling them again. That cache keeps every program, the small ones too, unless
  `JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS` is set (JAX alone keeps only those that
  took a second to compile; `docs/development.md`, "Compilation").

Its programs compile with `COMPILER_OPTIONS` (`jaxhop.jit`: `jax.jit` with them), which
spare the SLIP model's nested solver loops most of their compilation time
(`docs/development.md`, "Compilation").
"""

import os as _os

_os.environ.setdefault("EQX_ON_ERROR", "nan")

import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)

from ._cli.main import main as main
from ._control.decisions import BHOP as BHOP
from ._control.decisions import SLIP as SLIP
from ._control.decisions import Model as Model
from ._control.decisions import bhop_stride as bhop_stride
from ._control.decisions import decide as decide
from ._control.decisions import first_match as first_match
from ._control.decisions import in_global_domain as in_global_domain
from ._control.decisions import model_for as model_for
from ._control.runloop import CONTROLLERS as CONTROLLERS
from ._core.batching import chunked_map as chunked_map
from ._core.errors import InputError as InputError
from ._core.params import Disturbance as Disturbance
from ._core.params import Hopper as Hopper
from ._core.params import disturbance_for as disturbance_for
from ._core.paths import cache_dir as cache_dir
from ._core.programs import COMPILER_OPTIONS as COMPILER_OPTIONS
from ._core.programs import jit as jit
from ._core.result import RESULT_NAMES as RESULT_NAMES
from ._core.result import Result as Result
from ._core.terrain import SEGMENT_LENGTH as SEGMENT_LENGTH
from ._core.terrain import Terrain as Terrain
from ._core.terrain import builtin_terrain as builtin_terrain
from ._core.terrain import load_terrain as load_terrain
from ._core.terrain import make_terrain as make_terrain
from ._core.terrain import random_terrain as random_terrain
from ._core.terrain import save_terrain as save_terrain
from ._core.terrain import segments as segments
from ._core.version import VERSION as __version__  # noqa: F401
from ._execution.batches import run_batch as run_batch
from ._execution.batches import sweep as sweep
from ._execution.batches import sweep_grid as sweep_grid
from ._execution.batches import sweep_initial as sweep_initial
from ._execution.settings import ExecSettings as ExecSettings
from ._execution.settings import RunSettings as RunSettings
from ._execution.settings import SweepGrid as SweepGrid
from ._models.bhop import bhop_apex_map as bhop_apex_map
from ._models.bhop import deadbeat_bhop as deadbeat_bhop
from ._models.flight import touchdown as touchdown
from ._models.slip.deadbeat import deadbeat_slip as deadbeat_slip
from ._models.slip.stride import slip_apex_map as slip_apex_map
from ._models.slip.stride import slip_stride as slip_stride
from ._planning.cache import get_plan as get_plan
from ._planning.deploy import PICKBEST as PICKBEST
from ._planning.deploy import check_order as check_order
from ._planning.deploy import deploy as deploy
from ._planning.graph import prepares_matrix as prepares_matrix
from ._planning.plan import Plan as Plan
from ._planning.plan import build_plan as build_plan
from ._planning.plan import templates_for as templates_for
from ._planning.policies import PairGrid as PairGrid
from ._planning.regions import feasible_goal_contains as feasible_goal_contains
from ._planning.regions import feasible_goal_contains_brute as feasible_goal_contains_brute
from ._planning.regions import goal_height_bounds as goal_height_bounds
from ._planning.regions import template_domain_contains as template_domain_contains
from ._planning.templates import Templates as Templates
from ._planning.templates import dimensionless_templates as dimensionless_templates
from ._planning.templates import make_templates as make_templates
from ._planning.templates import paper_templates as paper_templates
from ._planning.templates import scaled_templates as scaled_templates
from ._viz.explore import Explorer as Explorer
from ._viz.explore import explore as explore
from ._viz.explore import explore_stride as explore_stride

if _jax.config.jax_compilation_cache_dir is None:
    _jax.config.update("jax_compilation_cache_dir", _os.path.join(cache_dir(), "xla"))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in _os.environ:
        _jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
