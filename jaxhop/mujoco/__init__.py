"""The reactive planner on a MuJoCo hopper (the optional extra `jaxhop[mujoco]`).

Model: `Mechanics` (leg and foot masses, friction, servoes, contact), `IDEAL` (the SLIP's
idealisation), `hopper_xml` (the MJCF of a hopper over a terrain). Simulation:
`Simulator` (one stride at a time). Closed-loop runs under jaxhop's reactive controller:
`Controller`, `run_many` (over processes) and `run_recorded` (one run with its
trajectory), with `Job` / `job_for` and `summarize_runs`. `docs/mujoco.md` describes the
model and its decisions.
"""

from .._core.errors import InputError as _InputError


class MissingExtra(_InputError, ImportError):
    """The `mujoco` package is not installed: an `ImportError` for Python, a one-line
    input error (exit status 2) for the command line."""


try:
    import mujoco as _mujoco  # noqa: F401
except ImportError:
    raise MissingExtra("the MuJoCo simulator needs the optional extra: pip install "
                       "'jaxhop[mujoco]'") from None

from ._model import DEFAULT as DEFAULT
from ._model import IDEAL as IDEAL
from ._model import Mechanics as Mechanics
from ._model import hopper_xml as hopper_xml
from ._plot import animate_trajectory as animate_trajectory
from ._plot import trajectory_figure as trajectory_figure
from ._run import Controller as Controller
from ._run import Job as Job
from ._run import job_for as job_for
from ._run import run_many as run_many
from ._run import run_recorded as run_recorded
from ._run import summarize_runs as summarize_runs
from ._sim import Simulator as Simulator
from ._sim import Stride as Stride
