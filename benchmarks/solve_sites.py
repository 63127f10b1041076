"""Stance-phase solves in the SLIP lane pool's step, counted in its jaxpr.

A SLIP stance phase is one call of `_phase` (`jaxhop/_models/slip/stride.py`): an adaptive
diffrax `diffeqsolve` (a `while` loop of Tsit5 steps with an event), or on the fixed-shape
path a `lax.scan` of equal Tsit5 steps (no `diffeqsolve`). This script traces the pool step
of the `reference` SLIP sweep (adaptive controller) once with the CPU's decision settings
and once with an accelerator's (`decision_tol`), and counts in each jaxpr:

- `phases`: `_phase` calls, and of them `adaptive` (holding a `while`: a `diffeqsolve`) and
  `fixed` (holding none);
- `while`: every `while` loop of the step; `decision_while`: those of the decision alone.

    python benchmarks/solve_sites.py [--json PATH]

Tracing takes about half a minute per path on the 2-core CPU; nothing is compiled.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import jax
import jax.numpy as jnp

import jaxhop
from jaxhop._control.decisions import decide_slip
from jaxhop._control.runloop import run_init
from jaxhop._execution import pool
from jaxhop._execution.settings import RunSettings
from jaxhop._models.slip import kernels
from jaxhop._planning.plan import bucketed


def _subjaxprs(eqn):
    for v in eqn.params.values():
        for x in v if isinstance(v, (list, tuple)) else (v,):
            if isinstance(x, jax.extend.core.ClosedJaxpr):
                yield x.jaxpr
            elif isinstance(x, jax.extend.core.Jaxpr):
                yield x


def count(jaxpr) -> dict:
    """`phases`, `adaptive`, `fixed` and `while` in `jaxpr`, nested ones included."""
    out = {"phases": 0, "adaptive": 0, "fixed": 0, "while": 0}
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "while":
            out["while"] += 1
        if eqn.primitive.name in ("pjit", "jit") and eqn.params.get("name") == "_phase":
            inner = count(eqn.params["jaxpr"].jaxpr)
            out["phases"] += 1
            out["adaptive" if inner["while"] else "fixed"] += 1
        for sub in _subjaxprs(eqn):
            for k, v in count(sub).items():
                out[k] += v
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", default=None, help="write the counts here")
    args = p.parse_args(argv)
    terrain = jaxhop.builtin_terrain("reference")
    plan = jaxhop.get_plan(terrain, progress=False)
    tables = plan.tables(slip=True)
    config = RunSettings(model="slip").config(plan.goal)
    consts = (*bucketed(tables, terrain), plan.hopper, jaxhop.Disturbance(), config)
    lanes = pool.POOL_LANES
    carry = jax.vmap(lambda a: run_init(a, config))(jnp.zeros((lanes, 3)))
    args0 = (carry, jnp.zeros(lanes, bool), jnp.zeros((lanes, 3)), jnp.arange(lanes),
             jax.random.key(0), *consts[:-1])
    apex = jnp.array([0.6, 1.6, 0.5])
    result = {"device": "none (traced, not run)", "jax": jax.__version__}
    original = kernels.decision_tol
    for name, tol in (("cpu", kernels.DECISION_TOL), ("accelerator", kernels.FIXED_DECISION_TOL)):
        kernels.decision_tol = lambda platform=None, t=tol: t
        try:
            step = count(jax.make_jaxpr(lambda *a: pool._pool_step(*a, config))(*args0).jaxpr)
            decision = count(jax.make_jaxpr(
                lambda z, tb: decide_slip(z, tb, plan.hopper, recover=True))(apex, consts[0]).jaxpr)
        finally:
            kernels.decision_tol = original
        result[name] = {**step, "decision_while": decision["while"],
                        "decision_phases": decision["phases"]}
        print(f"{name}: {step['phases']} stance phases in the pool step "
              f"({step['adaptive']} diffeqsolve, {step['fixed']} fixed-shape), "
              f"{step['while']} while loops; the decision: {decision['phases']} phases, "
              f"{decision['while']} while loops", flush=True)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
