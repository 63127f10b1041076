"""The plan cache: a plan is saved under a key of everything it depends on, and reused.

A cached plan is an `.npz` in `cache_dir()` (`$JAXHOP_CACHE`, default `~/.cache/jaxhop`)
named by a SHA-256 of the package version, the file format, the terrain's blocks, the goal,
the templates, the hopper, the sampling grid and the safety-sampling probe.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import warnings
import zipfile

import numpy as np
import scipy.sparse as sp

from .._core.params import Hopper
from .._core.paths import atomic_write, cache_dir
from .._core.terrain import Terrain
from .._core.version import VERSION
from .plan import PROBE_HALF_WIDTH, Plan, build_plan, check_goal
from .policies import PairGrid
from .templates import Templates, paper_templates

_FORMAT = 4
_DEFAULT_GRID = PairGrid()


def plan_key(terrain: Terrain, goal, templates: Templates, hopper: Hopper,
             grid: PairGrid = _DEFAULT_GRID) -> str:
    """SHA-256 (hex) of everything a plan depends on, the package version and file format."""
    payload = {
        "version": VERSION,
        "format": _FORMAT,
        "blocks": terrain.blocks(),
        "goal": [float(g) for g in goal],
        "templates": templates.to_dict(),
        "hopper": [float(hopper.m), float(hopper.g), float(hopper.rho0)],
        "grid": [grid.n_v, grid.n_z],
        "probe": PROBE_HALF_WIDTH,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def save_plan(plan: Plan, path: str, key: str) -> None:
    """Write `plan` to `path` (through a temporary file, so a reader never sees half of it)."""
    p = plan.prepares.tocsr()
    atomic_write(path, lambda f: np.savez_compressed(
        f, key=np.asarray(key), situated=plan.situated, target=plan.target,
        goals=plan.goals, safety=plan.safety, margin=plan.margin, is_goal=plan.is_goal,
        robustness=plan.robustness,
        p_indptr=p.indptr, p_indices=p.indices, p_shape=np.asarray(p.shape),
        order=plan.order, stats=np.asarray(json.dumps(plan.stats))))


def load_plan(path: str, key: str, terrain: Terrain, goal, templates: Templates,
              hopper: Hopper) -> Plan:
    """Load a cached plan; raises `ValueError` if it is corrupt or was built for other inputs."""
    try:
        with np.load(path) as z:
            if str(z["key"]) != key:
                raise ValueError("stale cache (key mismatch)")
            n = int(z["situated"].shape[0])
            shape = tuple(int(s) for s in z["p_shape"])
            p = sp.csr_matrix((np.ones(z["p_indices"].size, bool), z["p_indices"],
                               z["p_indptr"]), shape=shape)
            plan = Plan(terrain, templates, hopper, np.asarray(goal, float), z["situated"],
                        z["target"], z["goals"], z["safety"], z["margin"], z["is_goal"],
                        z["robustness"], p,
                        z["order"], json.loads(str(z["stats"])))
    except (OSError, KeyError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as err:
        raise ValueError(f"corrupt cache ({err})") from None
    if plan.goals.shape != (n, 3) or shape[0] != n or plan.order.max(initial=-1) >= n:
        raise ValueError("corrupt cache (inconsistent shapes)")
    return plan


def get_plan(terrain: Terrain, goal=None, templates: Templates | None = None,
             hopper: Hopper | None = None, *, cache: bool = True, progress: bool = True,
             log=None) -> Plan:
    """The plan for these inputs: from the cache when a valid one exists, else built and saved.

    A corrupt or stale cache file is reported (one line through `log`, default a warning)
    and rebuilt, never trusted.
    """
    templates = paper_templates() if templates is None else templates
    hopper = Hopper() if hopper is None else hopper
    goal = check_goal(terrain if goal is None else goal)
    if not cache:
        return build_plan(terrain, goal, templates, hopper, progress=progress)
    key = plan_key(terrain, goal, templates, hopper)
    path = os.path.join(cache_dir(), f"plan-{key[:24]}.npz")
    if os.path.exists(path):
        try:
            t0 = time.perf_counter()
            plan = load_plan(path, key, terrain, goal, templates, hopper)
            plan.stats["loaded_seconds"] = round(time.perf_counter() - t0, 3)
            plan.stats["from_cache"] = True
            return plan
        except ValueError as err:
            msg = f"plan cache {path}: {err}; rebuilding"
            (log or (lambda m: warnings.warn(m, stacklevel=2)))(msg)
    plan = build_plan(terrain, goal, templates, hopper, progress=progress)
    plan.stats["from_cache"] = False
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        save_plan(plan, path, key)
    except OSError as err:
        (log or (lambda m: warnings.warn(m, stacklevel=2)))(f"cannot write plan cache: {err}")
    return plan
