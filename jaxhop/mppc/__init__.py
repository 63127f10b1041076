"""MPPC: receding-horizon parkour planning for the hopping leg (Albracht et al. 2024).

Courses: `load_course`, `list_courses`, `random_course`, `course_from_dict`, `Course`,
`Environment`, `reference_results`. Robot: `Robot`, `foot_offset`, `knee_offset` (eqs
1-4). Planning: `min_time_jump` (one pair, JAX), `MPPC` / `Settings` (one replan),
`Replanner` (the replans of one run), `run_course` (the receding-horizon loop) with `Jump`,
`Plan`, `ParkourResult`. Disturbances: `Observer` (wind estimate and landing room from
past landings). Checking: `check_jump` (independent NumPy checker). Figures: `plot_run`.
"""

from ._check import check_jump as check_jump
from ._course import Course as Course
from ._course import Environment as Environment
from ._course import course_from_dict as course_from_dict
from ._course import list_courses as list_courses
from ._course import load_course as load_course
from ._course import random_course as random_course
from ._course import reference_results as reference_results
from ._jump import min_time_jump as min_time_jump
from ._observe import Observer as Observer
from ._plan import MPPC as MPPC
from ._plan import EnvData as EnvData
from ._plan import Jump as Jump
from ._plan import Plan as Plan
from ._plan import Settings as Settings
from ._plot import plot_run as plot_run
from ._robot import Robot as Robot
from ._robot import foot_offset as foot_offset
from ._robot import knee_offset as knee_offset
from ._run import ParkourResult as ParkourResult
from ._run import Replanner as Replanner
from ._run import run_course as run_course
