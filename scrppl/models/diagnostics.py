"""MCMC diagnostics, computed on every fit and never ignored.

A fit passes when, on every free parameter, the rank-normalised split R-hat is at most 1.01 and the bulk
effective sample size at least 400, no transition diverged, and the energy Bayesian fraction of missing
information (E-BFMI) of every chain is at least 0.3 (the thresholds of Vehtari et al. 2021 and Betancourt
2017). A failing fit emits a :class:`DiagnosticsWarning` that names the failing parameters.
"""

from __future__ import annotations

import warnings

import numpy as np
import xarray as xr

__all__ = ["THRESHOLDS", "DiagnosticsWarning", "diagnose", "warn_if_failed"]

#: Pass/fail thresholds.
THRESHOLDS = {"rhat_max": 1.01, "ess_bulk_min": 400.0, "divergences": 0, "ebfmi_min": 0.3}


class DiagnosticsWarning(UserWarning):
    """An MCMC fit failed its convergence diagnostics."""


def _per_variable(ds: xr.Dataset, reduce) -> dict[str, float]:
    return {name: float(reduce(np.asarray(ds[name].values))) for name in ds.data_vars}


def diagnose(posterior: xr.DataTree, var_names: list[str] | None = None) -> dict:
    """R-hat, bulk and tail ESS, divergences and E-BFMI of a fit.

    Parameters
    ----------
    posterior
        ArviZ ``DataTree`` with ``posterior`` and ``sample_stats`` (``diverging``, ``energy``) groups.
    var_names
        Parameters to check (default: every posterior variable).

    Returns
    -------
    dict with ``rhat_max``, ``ess_bulk_min``, ``ess_tail_min`` (per parameter: the worst element; NaN if
    any element's is NaN, as R-hat is for an element constant in every chain, and NaN fails its gate),
    ``divergences`` (count), ``ebfmi`` (per chain), ``n_draws`` (chains x draws), ``failures`` (list of
    readable strings) and ``ok`` (bool).
    """
    import arviz as az

    post = posterior["posterior"].to_dataset()
    if var_names is None:
        var_names = list(post.data_vars)
    var_names = [v for v in var_names if v in post.data_vars]
    # a parameter constant in every chain has R-hat 0/0 = NaN (a chain of constant energy E-BFMI NaN):
    # reported below as a failure, so NumPy's warning about the division adds nothing
    with np.errstate(divide="ignore", invalid="ignore"):
        rhat = az.rhat(posterior, var_names=var_names).to_dataset()
        ess_bulk = az.ess(posterior, var_names=var_names, method="bulk").to_dataset()
        ess_tail = az.ess(posterior, var_names=var_names, method="tail").to_dataset()
        ebfmi = np.asarray(az.bfmi(posterior).to_dataset()["energy"].values, dtype=float).ravel()
    stats = posterior["sample_stats"].to_dataset()
    n_div = int(np.asarray(stats["diverging"].values).sum())
    # np.max, not np.nanmax: one NaN element (a coordinate stuck at one value) makes its parameter NaN,
    # which the gates below fail (``not v <= 1.01``)
    report = {
        "rhat_max": _per_variable(rhat, np.max),
        "ess_bulk_min": _per_variable(ess_bulk, np.min),
        "ess_tail_min": _per_variable(ess_tail, np.min),
        "divergences": n_div,
        "ebfmi": [float(x) for x in ebfmi],
        "n_draws": int(post.sizes["chain"] * post.sizes["draw"]),
    }
    failures = []
    bad = [
        f"{k} ({v:.3f})" for k, v in report["rhat_max"].items() if not v <= THRESHOLDS["rhat_max"]
    ]
    if bad:
        failures.append(f"R-hat > {THRESHOLDS['rhat_max']}: " + ", ".join(bad))
    bad = [
        f"{k} ({v:.0f})"
        for k, v in report["ess_bulk_min"].items()
        if not v >= THRESHOLDS["ess_bulk_min"]
    ]
    if bad:
        failures.append(f"bulk ESS < {THRESHOLDS['ess_bulk_min']:.0f}: " + ", ".join(bad))
    if n_div > THRESHOLDS["divergences"]:
        failures.append(f"{n_div} divergent transitions")
    low = ~(ebfmi >= THRESHOLDS["ebfmi_min"])  # NaN (a chain whose energy never moved) fails too
    if low.any():
        failures.append(
            f"E-BFMI < {THRESHOLDS['ebfmi_min']} in chains {np.flatnonzero(low).tolist()}"
        )
    report["failures"] = failures
    report["ok"] = not failures
    return report


def warn_if_failed(report: dict, label: str) -> None:
    """Emit a :class:`DiagnosticsWarning` naming the failing parameters of ``label``'s fit, if any."""
    if not report["ok"]:
        warnings.warn(
            f"MCMC diagnostics failed for {label}: " + "; ".join(report["failures"]),
            DiagnosticsWarning,
            stacklevel=2,
        )
