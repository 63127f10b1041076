"""jaxhop: reactive footstep planning for spring-mass hopping on rough terrain, in JAX.

The pipeline, in order: terrain → models (BHop) → regions → policies / graph / deployment
→ execution / sweeps → plots / CLI. Everything public is re-exported here.
"""

import os as _os

# A failed solve is a result code, never an exception that ends a whole batch: equinox's
# runtime checks inside solves (e.g. a singular linear solve in an event's derivative)
# give NaN, which the solvers' guards and the result codes then handle
# (docs/decisions.md, "Errors inside solves"). Without a host callback in them the
# compiled programs can also be cached on disk.
_os.environ.setdefault("EQX_ON_ERROR", "nan")

import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)

__version__ = "0.2.0"

from ._bhop import bhop_apex_map as bhop_apex_map
from ._bhop import deadbeat_bhop as deadbeat_bhop
from ._cache import cache_dir as _cache_dir
from ._cache import get_plan as get_plan
from ._deploy import PICKBEST as PICKBEST
from ._deploy import check_order as check_order
from ._deploy import deploy as deploy
from ._errors import InputError as InputError
from ._execute import run_batch as run_batch
from ._execute import sweep as sweep
from ._execute import sweep_grid as sweep_grid
from ._flight import touchdown as touchdown
from ._graph import prepares_matrix as prepares_matrix
from ._models import BHOP as BHOP
from ._models import SLIP as SLIP
from ._models import Model as Model
from ._models import bhop_stride as bhop_stride
from ._models import first_match as first_match
from ._models import in_global_domain as in_global_domain
from ._models import model_for as model_for
from ._params import Disturbance as Disturbance
from ._params import Hopper as Hopper
from ._params import disturbance_for as disturbance_for
from ._plan import Plan as Plan
from ._plan import build_plan as build_plan
from ._regions import feasible_goal_contains as feasible_goal_contains
from ._regions import feasible_goal_contains_brute as feasible_goal_contains_brute
from ._regions import goal_height_bounds as goal_height_bounds
from ._regions import template_domain_contains as template_domain_contains
from ._result import RESULT_NAMES as RESULT_NAMES
from ._result import Result as Result
from ._templates import Templates as Templates
from ._templates import make_templates as make_templates
from ._templates import paper_templates as paper_templates
from ._terrain import Terrain as Terrain
from ._terrain import builtin_terrain as builtin_terrain
from ._terrain import load_terrain as load_terrain
from ._terrain import make_terrain as make_terrain
from ._terrain import random_terrain as random_terrain
from ._terrain import save_terrain as save_terrain
from ._terrain import segments as segments

_LAZY = {"slip_stride": "._slip", "slip_apex_map": "._slip",
         "deadbeat_slip": "._slip_deadbeat"}


def __getattr__(name):
    # The SLIP model pulls in diffrax; import it only when it is used.
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module 'jaxhop' has no attribute {name!r}")

# Compiled programs are kept on disk beside the plans, so a second process does not
# compile them again (unless JAX is told to cache elsewhere, or not at all).
if _jax.config.jax_compilation_cache_dir is None:
    _jax.config.update("jax_compilation_cache_dir", _os.path.join(_cache_dir(), "xla"))
