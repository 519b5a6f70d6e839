"""Every figure of scrppl (the only subpackage that imports matplotlib).

* :mod:`scrppl.plotting.dataset` -- contact sheets, the view sphere, images with their mask, box and window;
* :mod:`scrppl.plotting.detectors` -- Fig. 1 (response over azimuth with detections) and response summaries;
* :mod:`scrppl.plotting.models` -- Figs. 2-3 (polar viewpoint detection functions), MCMC trace, forest and
  rank plots, instance effects, prior and posterior predictive checks;
* :mod:`scrppl.plotting.belief` -- Fig. 4 (posterior evolution, also animated for an offline page), Fig. 5
  (planner comparison), calibration, repeated views, expected entropy per candidate view and the sampling
  error of eq. 5;
* :mod:`scrppl.plotting.kway` -- K-way recognition: accuracy against views, confusion matrices;
* :mod:`scrppl.plotting.sweep` -- the difficulty sweep: views saved by planning against detector quality;
* :mod:`scrppl.plotting.decomposition` -- views saved by each planner beside the clairvoyant room, and the
  information each relative azimuth gives.
"""

from scrppl.plotting._save import save_figure
from scrppl.plotting.belief import (
    animate_posterior_evolution,
    animation_html,
    plot_calibration,
    plot_expected_entropies,
    plot_planner_comparison,
    plot_posterior_evolution,
    plot_repeated_view,
    plot_sampling_error,
    plot_step_comparison,
)
from scrppl.plotting.dataset import (
    contact_sheet,
    show_image,
    show_images,
    view_sphere,
)
from scrppl.plotting.decomposition import (
    plot_decomposition,
    plot_model_optimal,
    plot_view_information,
)
from scrppl.plotting.detectors import plot_mean_response_by_azimuth, plot_response_over_azimuth
from scrppl.plotting.kway import (
    plot_kway_accuracy,
    plot_kway_confusion,
    plot_kway_confusions,
    plot_kway_metric,
)
from scrppl.plotting.models import (
    plot_fit_forest,
    plot_fit_rank,
    plot_fit_trace,
    plot_instance_effects,
    plot_predictive_densities,
    plot_predictive_sample_check,
    plot_prior_predictive,
    plot_viewpoint_functions,
)
from scrppl.plotting.sweep import plot_difficulty_sweep

__all__ = [
    "contact_sheet",
    "view_sphere",
    "show_image",
    "show_images",
    "save_figure",
    "plot_decomposition",
    "plot_model_optimal",
    "plot_view_information",
    "plot_response_over_azimuth",
    "plot_mean_response_by_azimuth",
    "plot_viewpoint_functions",
    "plot_fit_trace",
    "plot_fit_forest",
    "plot_fit_rank",
    "plot_instance_effects",
    "plot_prior_predictive",
    "plot_predictive_densities",
    "plot_predictive_sample_check",
    "plot_posterior_evolution",
    "animate_posterior_evolution",
    "animation_html",
    "plot_planner_comparison",
    "plot_calibration",
    "plot_repeated_view",
    "plot_expected_entropies",
    "plot_sampling_error",
    "plot_step_comparison",
    "plot_kway_metric",
    "plot_kway_accuracy",
    "plot_kway_confusion",
    "plot_kway_confusions",
    "plot_difficulty_sweep",
]
