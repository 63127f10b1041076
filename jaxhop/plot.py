"""Figures of plans, runs and sweeps (matplotlib), as the demo and the notebooks draw them.

Each function returns a `matplotlib.figure.Figure`; `animate_run` writes a GIF or MP4.
"""

from ._viz.animate import animate_run as animate_run
from ._viz.draw import RunStyle as RunStyle
from ._viz.plot import disturbance_figure as disturbance_figure
from ._viz.plot import doa_figure as doa_figure
from ._viz.plot import global_domain_figure as global_domain_figure
from ._viz.plot import goal_coverage_figure as goal_coverage_figure
from ._viz.plot import long_run_figure as long_run_figure
from ._viz.plot import prepares_figure as prepares_figure
from ._viz.plot import runs_figure as runs_figure
from ._viz.plot import slip_runs_figure as slip_runs_figure
from ._viz.plot import template_regions_figure as template_regions_figure
