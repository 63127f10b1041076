"""Checks of the `jaxhop` command line's arguments, all before any plan is built or run.

Numbers are checked while the arguments are parsed (argparse `type=` functions built on
`jaxhop._core.validate`); what needs the terrain (a goal over the map, the size of a sweep grid,
an apex above the ground) or the file system (output paths) is checked here right after.
Every failure is an `InputError`: one line, exit status 2.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from .._core import validate as v
from .._core.errors import InputError

MAX_CHUNK = 65_536
MAX_STEPS = 10_000
MAX_SPEED = 100.0  # |ydot| of an apex (m/s)
MAX_POSITION = 1.0e4  # |y|, |z| of an apex (m)
MAX_WIND = 100.0  # |horizontal acceleration| (m/s^2)
MAX_TOLERANCE = 100.0
#: `--noise` of `sweep` and `run`: one kind or several joined by `+` (`wind+sensor`).
NOISE_KINDS = ("none", "wind", "sensor", "ground")


class Parser(argparse.ArgumentParser):
    """An argparse parser whose errors are `InputError`s (`--dy: must be positive, got 0`)."""

    def error(self, message):
        raise InputError(message.removeprefix("argument "))

    def parse_known_args(self, args=None, namespace=None):
        # argparse drops a value of "--" (`--seed=--`) and would hand on an empty list
        for arg in sys.argv[1:] if args is None else args:
            option, eq, value = str(arg).partition("=")
            if eq and option.startswith("-") and value == "--":
                raise InputError(f"{option}: expected a value, got '--'")
        return super().parse_known_args(args, namespace)


def _apex(text: str, field: str) -> list[float]:
    apex = v.numbers(text, field, 3)
    v.bounded(apex[:2], field, MAX_POSITION)
    v.bounded(apex[2:], field, MAX_SPEED)
    return apex


def _noise(text: str, field: str) -> str:
    from .._core.params import check_noise

    return check_noise(text, NOISE_KINDS, field)


def _tolerance(text: str, field: str) -> list[float]:
    tol = v.bounded(v.numbers(text, field, 3), field, MAX_TOLERANCE)
    if min(tol) < 0:
        raise InputError(f"{field}: must be non-negative")
    return tol


# argparse `type=` functions of the options that take numbers.
SEED = v.arg_type(v.seed, "--seed")
MAX_STEPS_ARG = v.arg_type(v.count, "--max-steps", MAX_STEPS)
TOLERANCE = v.arg_type(_tolerance, "--tolerance")
NOISE = v.arg_type(_noise, "--noise")
GOAL = v.arg_type(v.numbers, "--goal", 3)
APEX = v.arg_type(_apex, "--apex")
CONTROLS = v.arg_type(v.numbers, "--controls", 3)
WIND = v.arg_type(v.real, "--wind", MAX_WIND)
DY = v.arg_type(v.positive, "--dy")
DZ = v.arg_type(v.positive, "--dz")
YDOT0 = v.arg_type(v.real, "--ydot0", MAX_SPEED)
CHUNK = v.arg_type(v.count, "--chunk", MAX_CHUNK)
RUNS = v.arg_type(v.count, "--runs", MAX_CHUNK * 32)
#: `--noise` kinds a MuJoCo run has (no landing error: its landings are simulated).
MUJOCO_NOISE = ("none", "wind", "sensor", "ground")


def check_sim(args):
    """`--sim mujoco`: the extra installed, the SLIP controller, the noise kinds it has and
    none of the options of jaxhop's batched runs; resolves `--model`'s default."""
    sim = getattr(args, "sim", "jaxhop")
    if getattr(args, "model", "") is None:
        args.model = "slip" if sim == "mujoco" else "bhop"
    if sim != "mujoco":
        return
    try:
        import jaxhop.mujoco  # noqa: F401
    except ImportError as err:  # without mujoco: one line naming the extra
        raise InputError(f"--sim mujoco: {err}") from None
    if args.model != "slip":
        raise InputError(f"--sim mujoco: the MuJoCo hopper runs the SLIP controller "
                         f"(--model slip), got --model {args.model}")
    bad = [k for k in args.noise.split("+") if k not in MUJOCO_NOISE]
    if bad:
        raise InputError(f"--sim mujoco: noise {bad[0]!r} is not simulated in MuJoCo "
                         f"(choose from {', '.join(MUJOCO_NOISE)})")
    for flag in ("checkpoint", "chunk"):
        if getattr(args, flag, None) is not None:
            raise InputError(f"--{flag}: not available with --sim mujoco")
    if getattr(args, "distributed", False):
        raise InputError("--distributed: not available with --sim mujoco")


def terrain_and_goal(args):
    """The terrain of `--terrain` and the goal of `--goal` (None: the terrain's own)."""
    from .._core.terrain import check_goal, load_terrain

    terrain = load_terrain(args.terrain)
    goal = list(check_goal(terrain, args.goal, "--goal")) if args.goal is not None else None
    if goal is None and terrain.goal is None:
        raise InputError(f"terrain {terrain.name!r} has no default goal: pass --goal y,z,ydot")
    return terrain, goal


def check_sweep_args(args):
    """The terrain, the goal and the size of the sweep grid, before any plan is built."""
    from .._execution.batches import MAX_GRID

    terrain, _ = terrain_and_goal(args)
    (y0, y1), h = terrain.y_range, [b[2] for b in terrain.blocks()]
    n = ((math.floor((y1 - y0) / args.dy) + 1)
         * (math.floor((max(h) - min(h) + 1.6) / args.dz) + 1))
    if n > MAX_GRID:
        raise InputError(f"--dy/--dz: the grid would have about {n:.3g} initial states, at "
                         f"most {MAX_GRID} allowed")


def check_step_args(args):
    """`jaxhop step`: controls of the model's range, an apex in the air over the map.

    **Returns:** the terrain (flat ground at height 0 without `--terrain`).
    """
    from .._core.terrain import load_terrain, make_terrain

    apex, u = args.apex, args.controls
    if args.model == "slip":
        if not abs(u[0]) < math.pi / 2:
            raise InputError(f"--controls: th_td must lie in (-pi/2, pi/2), got {u[0]}")
        if u[1] <= 0 or u[2] <= 0:
            raise InputError("--controls: stiffnesses kc and kd must be positive")
        v.bounded(u[1:], "--controls", 1.0e8)
    else:
        if u[2] <= -1:
            raise InputError(f"--controls: k must be > -1, got {u[2]}")
        if not abs(u[0]) <= 1.0:
            raise InputError(f"--controls: |dy| must be at most the leg length 1 m, got {u[0]}")
        if not abs(u[1]) < math.pi / 2:
            raise InputError(f"--controls: th must lie in (-pi/2, pi/2), got {u[1]}")
        if u[2] > 100:
            raise InputError(f"--controls: k must be at most 100, got {u[2]}")
    if args.terrain is None:
        terrain = make_terrain([(apex[0] - 20.0, apex[0] + 20.0, 0.0)], name="flat-ground")
    else:
        terrain = load_terrain(args.terrain)
    y, z, _ = apex
    y0, y1 = terrain.y_range
    if not y0 <= y <= y1:
        raise InputError(f"--apex: y = {y:g} lies off the map [{y0:g}, {y1:g}]")
    foot_y, foot_z, at = foot_at_apex(apex, u, args.model)
    under = [h for s, e, h in terrain.blocks() if s <= foot_y <= e]
    if under and not foot_z > max(under):
        raise InputError(f"--apex: z = {z:g} puts the foot{at} at height {foot_z:.4g}, not "
                         f"above the ground under it ({max(under):g} at y = {foot_y:.4g})")
    return terrain


def foot_at_apex(apex, u, model: str, rho0: float = 1.0):
    """`(y, z, words)`: where the foot hangs at the apex, as the stride's descent starts.

    SLIP: at `COM + rho0 (sin th_td, -cos th_td)` (`slip_stride`). BHop: straight
    below the COM, `rho0` down (its controls act in stance only, `bhop_stride`).
    """
    y, z, _ = apex
    if model == "slip":
        th = u[0]
        return (y + rho0 * math.sin(th), z - rho0 * math.cos(th),
                f" (leg {rho0:g} m at th_td = {th:g} rad)")
    return y, z - rho0, f" (leg {rho0:g} m straight down)"


def check_animate(path: str):
    """`--animate`: a known format with its encoder at hand, in a folder that exists."""
    from .._viz.animate import animation_writer

    try:  # a bad name or a missing encoder fails before any work
        animation_writer(path, 25)
    except InputError as err:
        raise InputError(f"--animate: {err}") from None
    if not os.path.isdir(os.path.dirname(os.path.abspath(path))):
        raise InputError(f"--animate: cannot write {path!r} (no such folder)")


def check_outputs(args):
    """Output paths that cannot be written fail now, not after minutes of work."""
    for flag in ("json", "plot"):
        path = getattr(args, flag, None)
        if path is None:
            continue
        folder = os.path.dirname(os.path.abspath(path)) if path else ""
        if not path or os.path.isdir(path) or not os.path.isdir(folder):
            raise InputError(f"--{flag}: cannot write {path!r} (no such folder, or a folder)")
    out = getattr(args, "out", None)
    if out is not None and (not out or os.path.exists(out) and not os.path.isdir(out)):
        raise InputError(f"--out: {out!r} is not a folder")
    ck = getattr(args, "checkpoint", None)
    if ck is not None and (not ck or os.path.exists(ck) and not os.path.isdir(ck)):
        raise InputError(f"--checkpoint: {ck!r} is not a folder")


def init_distributed(args):
    """`jax.distributed.initialize()` from the environment, before JAX starts its backend.

    `JAX_COORDINATOR_ADDRESS` (host:port of process 0), `JAX_NUM_PROCESSES` and
    `JAX_PROCESS_ID`; where the last two are unset JAX detects them (SLURM, Open MPI, ...).
    Only process 0 writes `--json` and `--plot`.
    """
    import jax

    kwargs = {}
    for name, env in (("num_processes", "JAX_NUM_PROCESSES"), ("process_id", "JAX_PROCESS_ID")):
        text = os.environ.get(env)
        if text is not None:
            try:
                kwargs[name] = int(text)
            except ValueError:
                raise InputError(f"{env}: expected a whole number, got {text!r}") from None
    if "num_processes" in kwargs and not 1 <= kwargs["num_processes"] <= 100_000:
        raise InputError(f"JAX_NUM_PROCESSES: must be >= 1, got {kwargs['num_processes']}")
    if "process_id" in kwargs and not 0 <= kwargs["process_id"] < kwargs.get(
            "num_processes", 100_000):
        raise InputError(f"JAX_PROCESS_ID: must lie in [0, JAX_NUM_PROCESSES), got "
                         f"{kwargs['process_id']}")
    try:
        jax.distributed.initialize(**kwargs)
    except (ValueError, TypeError, RuntimeError) as err:
        raise InputError(f"--distributed: cannot initialize jax.distributed "
                         f"({' '.join(str(err).split())[:200]})") from None
    if jax.process_index() != 0:
        args.json = args.plot = None


def use_all_cores():
    """Expose every CPU core as a JAX device (sweeps put one chunk on each).

    Must run before JAX starts its backend; `JAXHOP_CPU_DEVICES` overrides the count.
    """
    import jax

    n = os.environ.get("JAXHOP_CPU_DEVICES") or str(os.cpu_count() or 1)
    try:
        jax.config.update("jax_num_cpu_devices", max(int(n), 1))
    except (RuntimeError, ValueError, AttributeError):
        pass  # backend already started, or an older JAX: keep its default
