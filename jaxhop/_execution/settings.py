"""The settings of a batch of runs: what the runs do (`RunSettings`), how they are executed
(`ExecSettings`) and, for a sweep, which initial states it starts from (`SweepGrid`).

Outcomes depend on `RunSettings` (and on the key, the disturbance and the true map), never
on `ExecSettings`: the same runs give the same codes, strides and policies whatever the
chunking, lanes or devices (`docs/scaling.md`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from .._control.decisions import Model
from .._control.runloop import RunConfig, check_controller, run_config


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """What every run of a batch does.

    Attributes:
        model: `"bhop"` (the ball hopper, instantaneous stance) or `"slip"` (the
            spring-mass model on the plan's SLIP adjustments), or a `Model`.
        controller: `"adaptive"` (the default, as on the command line: disturbance
            observer, wind-aware deadbeat, recovery outside the domains;
            `docs/decisions.md`, "Adaptive controller") or `"paper"` (the paper's
            reactive controller, Fig. 8).
        tolerance: the goal tolerance per axis `(y, z, ydot)` (default 0.05 each).
        goal: the global goal `(y, z, ydot)` (default: the plan's).
        max_steps: strides before a run ends as `max_steps`.
        energy_feedback: SLIP strides that correct the stance energy toward the prediction.
    """

    model: str | Model = "bhop"
    controller: str = "adaptive"
    tolerance: Sequence[float] | None = None
    goal: Sequence[float] | None = None
    max_steps: int = 60
    energy_feedback: bool = False

    def __post_init__(self):
        check_controller(self.controller)

    def config(self, plan_goal) -> RunConfig:
        """The run loop's `RunConfig`, with `plan_goal` where no goal is set."""
        return run_config(plan_goal if self.goal is None else self.goal, self.tolerance,
                          self.max_steps, self.model, self.controller, self.energy_feedback)


@dataclasses.dataclass(frozen=True)
class ExecSettings:
    """How a batch is executed; none of this changes an outcome.

    Attributes:
        chunk: runs per chunk (default: the model's, 256 BHop runs or 32 SLIP runs; for
            smaller batches the next power of two, at least 32). Chunks are what is
            checkpointed and what each `jax.distributed` process runs.
        lanes: SLIP lane-pool lanes per device (default 32 on a CPU, 4 096 on an
            accelerator, or `$JAXHOP_POOL_LANES`).
        pool: run through the lane pool (default: for SLIP) instead of vmapped chunks.
        checkpoint: a directory where finished chunks are saved; a rerun resumes there.
        progress: a progress bar on stderr (one line when stderr is not a terminal).
        devices: the JAX devices to use (default: every local device).
    """

    chunk: int | None = None
    lanes: int | None = None
    pool: bool | None = None
    checkpoint: str | None = None
    progress: bool = False
    devices: Sequence | None = None


@dataclasses.dataclass(frozen=True)
class SweepGrid:
    """The initial states of a sweep: apexes on a `(y, z)` grid over the terrain at speed
    `ydot0`, spaced `dy` and `dz`, those in the plan's global domain (`docs/decisions.md`,
    "Sweeps").

    Attributes:
        runs: only that many of them, evenly spaced (default: all).
        verify: only those in the plan's SLIP domain, where the SLIP's first stride ends in
            the global domain again (default: for the SLIP model; `docs/decisions.md`,
            "SLIP domain of a sweep").
    """

    ydot0: float = 0.5
    dy: float = 0.05
    dz: float = 0.05
    runs: int | None = None
    verify: bool | None = None
