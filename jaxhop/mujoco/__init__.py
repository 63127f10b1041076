"""The reactive planner on a MuJoCo hopper (the optional extra `jaxhop[mujoco]`).

Model: `Mechanics` (leg and foot masses, friction, servoes, contact), `IDEAL` (the SLIP's
idealisation), `hopper_xml` (the MJCF of a hopper over a terrain). Simulation:
`Simulator` (one stride at a time). `docs/mujoco.md` describes the model and its decisions.
"""

from .._errors import InputError as _InputError

try:
    import mujoco as _mujoco  # noqa: F401
except ImportError:
    raise _InputError("the MuJoCo simulator needs the optional extra: pip install "
                      "'jaxhop[mujoco]'") from None

from ._model import IDEAL as IDEAL
from ._model import Mechanics as Mechanics
from ._model import hopper_xml as hopper_xml
from ._sim import Simulator as Simulator
from ._sim import Stride as Stride
