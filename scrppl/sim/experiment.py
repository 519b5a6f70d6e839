"""The paper's simulated experiment (Meger et al. 2010, Sec. IV-A): planners compared on paired trials.

:func:`run_experiment` runs every (method, planner) pair on the *same* trials -- same instances, poses,
start views and keys -- and returns an ``xarray.Dataset`` with the per-step metrics of
:mod:`scrppl.sim.metrics`, dims ``(method, planner, trial, step)``. A *method* is a response model with a
filter (e.g. the paper's Gaussian with naive Bayes, the hierarchical model with the instance-aware filter)
and the trials transformed for it; a *planner* is a :class:`scrppl.planning.PlannerConfig`.
:func:`summarise` adds means and bootstrap intervals, :func:`compare_planners` the paired comparison of
an entropy planner against the random baseline, and :func:`calibration` the expected calibration error
of ``p(o | F)``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np
import xarray as xr

from scrppl._io import read_netcdf, write_netcdf
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig, check_planner_config
from scrppl.sim import metrics as M
from scrppl.sim.runner import run_trials
from scrppl.sim.simulator import Trials

__all__ = [
    "Method",
    "run_experiment",
    "summarise",
    "compare_planners",
    "calibration",
    "save_trials",
    "load_trials",
    "planner_configs",
    "STEP_METRICS",
    "PAPER_PLANNERS",
]

#: The paper's comparison (Sec. IV-A): entropy planning (eq. 5, ``M = 256``) against a random unseen view.
PAPER_PLANNERS = {"sampled": PlannerConfig("sampled"), "random": PlannerConfig("random")}

#: Per-step metrics stored in the experiment dataset.
STEP_METRICS = ("class_entropy", "p_true", "p_present", "correct", "pose_error", "response_sum")


class Method(NamedTuple):
    """A belief filter with its response model and the trials as that model sees them.

    Attributes
    ----------
    model
        The response model.
    filter
        ``"naive_bayes"`` or ``"instance"``.
    trials
        Trials whose responses went through *this* model's transform (same instances, poses and start
        views for every method).
    """

    model: ResponseModel
    filter: str
    trials: Trials


def planner_configs(
    planners: Mapping[str, PlannerConfig] | Sequence[PlannerConfig],
) -> dict[str, PlannerConfig]:
    """Name -> checked :class:`~scrppl.planning.PlannerConfig`, the planners of :func:`run_experiment`.

    A mapping keeps its names; a sequence is named by each config's ``planner`` field (the names must
    then differ: give a mapping to compare, e.g., two sample sizes of the same planner).

    Raises
    ------
    ValueError
        If there is no planner, two share a name, or a config is malformed
        (:func:`scrppl.planning.check_planner_config`).
    """
    if isinstance(planners, PlannerConfig | str):
        raise ValueError(
            f"planners must be a mapping name -> PlannerConfig or a sequence of PlannerConfig, got "
            f"{planners!r}"
        )
    if isinstance(planners, Mapping):
        items = [(str(name), config) for name, config in planners.items()]
    else:
        items = [(getattr(c, "planner", None), c) for c in planners]
    names = [name for name, _ in items]
    if not items:
        raise ValueError("run_experiment needs at least one planner")
    if len(set(names)) != len(names):
        raise ValueError(
            f"planners must have distinct names, got {names}; pass a mapping name -> PlannerConfig"
        )
    return {name: check_planner_config(config) for name, config in items}


def run_experiment(
    key: jax.Array,
    methods: Mapping[str, Method],
    planners: Mapping[str, PlannerConfig] | Sequence[PlannerConfig] = PAPER_PLANNERS,
    *,
    category_names: Sequence[str] | None = None,
    keep_beliefs: bool = False,
    progress: bool = False,
    **run_options,
) -> xr.Dataset:
    """Run every planner with every method on the same trials.

    Parameters
    ----------
    key
        JAX PRNG key shared by every (method, planner): paired trials.
    methods
        Name -> :class:`Method`. All methods' trials must share labels, poses and start views.
    planners
        The planners to compare: a mapping name -> :class:`~scrppl.planning.PlannerConfig`, or a
        sequence of configs named by their ``planner`` field (:func:`planner_configs`). Default: the
        paper's :data:`PAPER_PLANNERS`, ``{"sampled": PlannerConfig("sampled"), "random":
        PlannerConfig("random")}``.
    category_names
        Names of the table's categories (to label trials); indices are stored if omitted.
    keep_beliefs
        Also store the joint belief after each step, ``log_belief (method, planner, trial, step, o,
        theta)``.
    progress
        Show progress bars.
    **run_options
        Passed to :func:`scrppl.sim.run_trials` (``n_steps``, ``chunk_size``, ``batch_size``,
        ``devices``); the planner settings travel in ``planners``.

    Returns
    -------
    xarray.Dataset
        Per-step metrics with dims ``(method, planner, trial, step)``, ``views_to_confidence``
        ``(method, planner, trial)`` and the trials' truth as coordinates along ``trial``. The
        dimension ``method`` is labelled by the method names, ``filter_kind`` gives each method's
        filter, ``planner`` the planner names; the attribute ``planner_configs`` holds each planner's
        settings (JSON). Select a method with ``ds.sel({"method": name})``: ``method`` is also a
        keyword argument of xarray's ``sel``, so ``ds.sel(method=name)`` selects nothing.
    """
    if not methods:
        raise ValueError("run_experiment needs at least one method")
    misplaced = sorted(set(run_options) & set(PlannerConfig._fields))
    if misplaced:
        raise ValueError(
            f"{', '.join(misplaced)}: planner settings travel in the planners' PlannerConfig, e.g. "
            f"planners=[PlannerConfig('sampled', {misplaced[0]}=...), PlannerConfig('random')]"
        )
    configs = planner_configs(planners)
    names = list(methods)
    ref = methods[names[0]].trials
    for name in names[1:]:
        t = methods[name].trials
        for field in ("label", "pose", "start", "category", "instance"):
            if not np.array_equal(np.asarray(getattr(t, field)), np.asarray(getattr(ref, field))):
                raise ValueError(
                    f"method {name!r} has different trials ({field}) than {names[0]!r}"
                )
    results: dict[str, list] = {}
    for name in names:
        meth = methods[name]
        per_planner = []
        for config in configs.values():
            rec = run_trials(
                key,
                meth.model,
                meth.trials,
                config,
                filter=meth.filter,
                progress=progress,
                **run_options,
            )
            met = M.trial_metrics(rec.log_belief, rec.responses, rec.observed, ref.label, ref.pose)
            met["response"] = np.asarray(rec.responses)
            met["azimuth"] = np.asarray(rec.views[..., 0])
            met["observed"] = np.asarray(rec.observed)
            if keep_beliefs:
                met["log_belief"] = np.asarray(rec.log_belief)
            per_planner.append(met)
        results[name] = per_planner
    n_t, n_k = results[names[0]][0]["class_entropy"].shape
    dims4 = ("method", "planner", "trial", "step")
    data = {}
    for var in (*STEP_METRICS, "response", "azimuth", "observed"):
        data[var] = (dims4, np.stack([np.stack([m[var] for m in results[n]]) for n in names]))
    data["views_to_confidence"] = (
        dims4[:3],
        np.stack([np.stack([m["views_to_confidence"] for m in results[n]]) for n in names]),
    )
    if keep_beliefs:
        data["log_belief"] = (
            (*dims4, "o", "theta"),
            np.stack([np.stack([m["log_belief"] for m in results[n]]) for n in names]),
        )
    cat = np.asarray(ref.category)
    start = np.asarray(ref.start)
    coords = {
        "method": names,
        "planner": list(configs),
        "trial": np.arange(n_t),
        "step": np.arange(1, n_k + 1),
        "filter_kind": ("method", [methods[n].filter for n in names]),
        "label": ("trial", np.asarray(ref.label)),
        "pose": ("trial", np.asarray(ref.pose)),
        "category": (
            "trial",
            [category_names[c] for c in cat] if category_names is not None else cat,
        ),
        "instance": ("trial", np.asarray(ref.instance)),
        "start_azimuth": ("trial", start[:, 0]),
        "elevation": ("trial", start[:, 1]),
        "scale": ("trial", start[:, 2]),
    }
    options = {k: (float(v) if isinstance(v, float) else v) for k, v in run_options.items()}
    attrs = {
        "planner_configs": json.dumps({name: c._asdict() for name, c in configs.items()}),
        "run_options": json.dumps(options),
        "confidence_threshold": M.CONFIDENCE,
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def summarise(ds: xr.Dataset, seed: int = 0, n_boot: int = 1000) -> xr.Dataset:
    """Means over trials with bootstrap 95% intervals, per (method, planner, step).

    Returns a Dataset with ``<metric>`` (mean), ``<metric>_lo``, ``<metric>_hi`` for every per-step
    metric, ``tp_minus_tn`` (:func:`scrppl.sim.metrics.tp_minus_tn`) with its interval, and
    ``views_to_confidence`` per (method, planner).
    """
    label = ds["label"].values
    out = {}
    dims = ("method", "planner", "step")
    for var in (*STEP_METRICS, "tp_minus_tn", "views_to_confidence"):
        shape = (ds.sizes["method"], ds.sizes["planner"]) + (
            () if var == "views_to_confidence" else (ds.sizes["step"],)
        )
        vals = {s: np.empty(shape) for s in ("", "_lo", "_hi")}
        for i in range(ds.sizes["method"]):
            for j in range(ds.sizes["planner"]):
                if var == "tp_minus_tn":
                    x = ds["response_sum"].values[i, j]
                    res = M.bootstrap_tp_minus_tn(seed, x, label, n_boot)
                else:
                    res = M.bootstrap_mean(seed, ds[var].values[i, j].astype(float), n_boot)
                for s, r in zip(("", "_lo", "_hi"), res, strict=True):
                    vals[s][i, j] = r
        d = dims[:2] if var == "views_to_confidence" else dims
        for s, v in vals.items():
            out[var + s] = (d, v)
    return xr.Dataset(out, coords={k: ds[k] for k in ("method", "planner", "step")})


def compare_planners(
    ds: xr.Dataset,
    planner: str = "sampled",
    baseline: str = "random",
    seed: int = 0,
    n_boot: int = 2000,
) -> dict:
    """Paired comparison of an entropy planner against the baseline on the same trials, per method.

    Returns
    -------
    dict
        For each method: mean views to confidence of both planners, their paired difference
        (``planner - baseline``; negative = the planner is faster) with a bootstrap 95% interval, the
        paired difference in class-marginal entropy per step with intervals, and the fraction of trials
        that reached confidence.
    """
    for p in (planner, baseline):
        if p not in ds["planner"].values.tolist():
            raise ValueError(
                f"planner {p!r} is not in the experiment ({ds['planner'].values.tolist()})"
            )
    out = {}
    for method in ds["method"].values.tolist():
        sub = ds.sel({"method": method})
        a = sub["views_to_confidence"].sel(planner=planner).values.astype(float)
        b = sub["views_to_confidence"].sel(planner=baseline).values.astype(float)
        d, lo, hi = M.paired_bootstrap_difference(seed, a, b, n_boot)
        ea = sub["class_entropy"].sel(planner=planner).values
        eb = sub["class_entropy"].sel(planner=baseline).values
        de, elo, ehi = M.paired_bootstrap_difference(seed, ea, eb, n_boot)
        n_k = ds.sizes["step"]
        out[method] = {
            "views_to_confidence": {planner: float(a.mean()), baseline: float(b.mean())},
            "reached_confidence": {
                planner: float((a <= n_k).mean()),
                baseline: float((b <= n_k).mean()),
            },
            "views_to_confidence_difference": {"mean": float(d), "lo": float(lo), "hi": float(hi)},
            "class_entropy_difference": {
                "mean": de.tolist(),
                "lo": elo.tolist(),
                "hi": ehi.tolist(),
            },
        }
    return out


def calibration(ds: xr.Dataset, n_bins: int = 10) -> dict:
    """Expected calibration error of ``p(o = 1 | F)`` per method, pooled over planners, trials, steps.

    Returns
    -------
    dict
        For each method: ``ece`` and the reliability-diagram bins (``mean_p``, ``frac``, ``count``).
    """
    out = {}
    label = ds["label"].values
    for method in ds["method"].values.tolist():
        p = ds["p_present"].sel({"method": method}).values  # (planner, trial, step)
        y = np.broadcast_to(label[None, :, None], p.shape)
        mean_p, frac, count = M.reliability(p, y, n_bins)
        out[method] = {
            "ece": M.expected_calibration_error(p, y, n_bins),
            "mean_p": [None if np.isnan(v) else float(v) for v in mean_p],
            "frac": [None if np.isnan(v) else float(v) for v in frac],
            "count": count.astype(int).tolist(),
        }
    return out


def save_trials(ds: xr.Dataset, path: str | Path) -> Path:
    """Write an experiment dataset to netCDF atomically."""
    return write_netcdf(ds, path)


def load_trials(path: str | Path) -> xr.Dataset:
    """The trial results written by :func:`save_trials` (``trials.nc``), as :func:`run_experiment` made them.

    An ``xarray.Dataset`` of per-trial, per-step metrics with dims ``(method, planner, trial, step)``
    (and ``target`` first for a study's file), not the trial *inputs* of :func:`scrppl.sim.make_trials`.
    Files written before the methods' dimension was named ``method`` (it was ``filter``) are renamed on
    load, so older results open unchanged.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If the file holds no trial results (no ``method``/``filter``, ``planner`` and ``trial``
        dimensions), naming the file.
    """
    ds = read_netcdf(path, "trials file", remedy="rerun `scrppl simulate` to regenerate it")
    if "method" not in ds.dims and "filter" in ds.dims:
        ds = ds.rename({"filter": "method"})
    missing = [d for d in ("method", "planner", "trial") if d not in ds.dims]
    if missing:
        raise ValueError(
            f"{path} holds no trial results (no {', '.join(missing)} dimension; it has "
            f"{dict(ds.sizes)}); load trials written by scrppl.sim.save_trials or `scrppl simulate`"
        )
    return ds
