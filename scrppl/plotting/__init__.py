"""Every figure of scrppl (the only subpackage that imports matplotlib).

Submodules: :mod:`scrppl.plotting.dataset` (contact sheets, the view sphere),
:mod:`scrppl.plotting.detectors` (Fig. 1, response summaries), :mod:`scrppl.plotting.models`
(Figs. 2-3, MCMC diagnostics), :mod:`scrppl.plotting.belief` (Figs. 4-5, calibration).
"""
