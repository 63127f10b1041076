"""The 2012 reactive planner on MPPC parkour courses (docs/parkour_reactive.md).

Course -> terrain (`course_map`: obstacles as blocks, restricted floor and margin bands as
forbidden blocks), Froude-scaled templates for the MPPC leg (`leg_hopper`,
`leg_templates`; `jaxhop.scaled_templates`), plans built in full or updated
incrementally after a snapshot (`build_course_plan`), batched reactive runs with snapshot
replay (`course_plans`, `run_reactive`), and the `parkour --planner reactive` result
(`reactive_parkour`). `run_mppc_noisy` runs jaxhop's MPPC under the same disturbances.
"""

from ._api import CourseRuns as CourseRuns
from ._api import reactive_parkour as reactive_parkour
from ._build import CoursePlan as CoursePlan
from ._build import build_course_plan as build_course_plan
from ._build import build_shape as build_shape
from ._map import CourseMap as CourseMap
from ._map import course_map as course_map
from ._map import leg_hopper as leg_hopper
from ._map import leg_templates as leg_templates
from ._mppc_noise import run_mppc_noisy as run_mppc_noisy
from ._run import COURSE_GRID as COURSE_GRID
from ._run import course_plans as course_plans
from ._run import identical_plans as identical_plans
from ._run import initial_states as initial_states
from ._run import pad_plans as pad_plans
from ._run import run_reactive as run_reactive
from ._run import same_deployment as same_deployment
