"""Every figure of scrppl (the only subpackage that imports matplotlib).

* :mod:`scrppl.plotting.dataset` -- contact sheets, the view sphere, one image with its mask and box;
* :mod:`scrppl.plotting.detectors` -- Fig. 1 (response over azimuth with detections) and response summaries;
* :mod:`scrppl.plotting.models` -- Figs. 2-3 (polar viewpoint detection functions), MCMC trace and forest;
* :mod:`scrppl.plotting.belief` -- Fig. 4 (posterior evolution), Fig. 5 (planner comparison), calibration.
"""

from scrppl.plotting.belief import (
    plot_calibration,
    plot_planner_comparison,
    plot_posterior_evolution,
)
from scrppl.plotting.dataset import contact_sheet, save_figure, show_image, view_sphere
from scrppl.plotting.detectors import plot_mean_response_by_azimuth, plot_response_over_azimuth
from scrppl.plotting.models import plot_fit_forest, plot_fit_trace, plot_viewpoint_functions

__all__ = [
    "contact_sheet",
    "view_sphere",
    "show_image",
    "save_figure",
    "plot_response_over_azimuth",
    "plot_mean_response_by_azimuth",
    "plot_viewpoint_functions",
    "plot_fit_trace",
    "plot_fit_forest",
    "plot_posterior_evolution",
    "plot_planner_comparison",
    "plot_calibration",
]
