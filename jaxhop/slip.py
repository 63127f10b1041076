"""The SLIP model's pieces: strides, the deadbeat solvers and the apex table they start from.

Each is a pure function of one sample (vmap it for batches) unless its name is plural:

- `slip_stride`, `slip_apex_map`, `flat_touchdown`: one stride of the spring-mass model
  (eqs 5-11), on a terrain or over a flat foothold; `slip_strides`: a batch of them.
- `deadbeat_slip`: the controls `(th_td, kc, kd)` that take an apex to a goal (eqs 12-16),
  by Gauss-Newton through diffrax or by nested bracketing (`DeadbeatSearch` picks the
  solver and its settings); `deadbeat_slips`: a batch, started from the apex table.
- `slip_table` (cached on disk) and `build_table`: that table over `TableGrid`'s
  dimensionless grid; `DEFAULT_GRID`.
- `decide_slip`: the reactive controller's SLIP decision at one apex.
- the control limits `KAPPA_LO, KAPPA_HI` (`kc rho0 / (m g)`) and `RATIO_LO, RATIO_HI`
  (`kd / kc`), and the solvers' `Tolerances` (`STRIDE_TOL`, `SEARCH_TOL`, `DECISION_TOL`,
  `FIXED_DECISION_TOL`; `decision_tol` picks a decision's by the backend).

`docs/slip.md` describes the model and the solvers.
"""

from ._control.decisions import decide_slip as decide_slip
from ._models.slip.deadbeat import DeadbeatSearch as DeadbeatSearch
from ._models.slip.deadbeat import deadbeat_slip as deadbeat_slip
from ._models.slip.kernels import DECISION_TOL as DECISION_TOL
from ._models.slip.kernels import FIXED_DECISION_TOL as FIXED_DECISION_TOL
from ._models.slip.kernels import KAPPA_HI as KAPPA_HI
from ._models.slip.kernels import KAPPA_LO as KAPPA_LO
from ._models.slip.kernels import RATIO_HI as RATIO_HI
from ._models.slip.kernels import RATIO_LO as RATIO_LO
from ._models.slip.kernels import SEARCH_TOL as SEARCH_TOL
from ._models.slip.kernels import decision_tol as decision_tol
from ._models.slip.stride import STRIDE_TOL as STRIDE_TOL
from ._models.slip.stride import Tolerances as Tolerances
from ._models.slip.stride import flat_touchdown as flat_touchdown
from ._models.slip.stride import slip_apex_map as slip_apex_map
from ._models.slip.stride import slip_stride as slip_stride
from ._models.slip.stride import slip_strides as slip_strides
from ._models.slip.table import DEFAULT_GRID as DEFAULT_GRID
from ._models.slip.table import SlipTable as SlipTable
from ._models.slip.table import TableGrid as TableGrid
from ._models.slip.table import build_table as build_table
from ._models.slip.table import deadbeat_slips as deadbeat_slips
from ._models.slip.table import slip_table as slip_table
