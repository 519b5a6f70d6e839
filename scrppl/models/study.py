"""Fit every detector x target and check the diagnostics: ``scrppl fit`` as library functions.

The command line only parses arguments, calls :func:`fit_study`, prints and draws the figures
(:func:`scrppl.plotting.models.save_fit_figures`); a notebook calls the same functions and gets the
same files and numbers for the same key.

* :func:`select_names` -- check requested detectors or targets against the response table;
* :func:`figure_targets` -- the targets drawn in Figs. 2 and 3;
* :func:`fit_pair` -- the paper's Gaussian and the hierarchical model of one detector x target, reusing
  saved fits that are current;
* :func:`fit_study` -- every pair, ``models/diagnostics.json`` and the held-out ``models/heldout.csv``;
* :func:`failed_fits` -- the fits that fail their MCMC diagnostics.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import xarray as xr
from tqdm.auto import tqdm

from scrppl._io import CorruptFileError, atomic_path, read_json
from scrppl.models.data import ViewData, extract_view_data
from scrppl.models.diagnostics import THRESHOLDS
from scrppl.models.evaluate import evaluate_models
from scrppl.models.fit import fit_hierarchical
from scrppl.models.gaussian import fit_gaussian
from scrppl.models.io import (
    is_current_version,
    load_posterior,
    load_response_model,
    model_path,
    save_gaussian,
    save_posterior,
)
from scrppl.models.mcmc import SamplerConfig
from scrppl.models.predictive import azimuth_sd, to_response_model
from scrppl.models.response import ResponseModel
from scrppl.responses import load_response_table

if TYPE_CHECKING:
    from scrppl.parallel import Executor

__all__ = [
    "PAPER_TARGETS",
    "select_names",
    "figure_targets",
    "FittedPair",
    "FitStudy",
    "fit_pair",
    "fit_study",
    "failed_fits",
    "AZIMUTH_EFFECT_CHOICES",
    "wants_azimuth_effect",
]

#: Targets drawn in Figs. 2 and 3 when present (the paper's choice).
PAPER_TARGETS = ("bicycle", "car", "monitor")


def select_names(requested: Sequence[str] | None, available: Iterable[str], axis: str) -> list[str]:
    """The detectors (or targets) to fit: all of ``available``, or ``requested`` after checking it.

    Parameters
    ----------
    requested
        Names asked for; ``None`` means all.
    available
        Names in the response table.
    axis
        ``"detector"`` or ``"target"``, for the error message.

    Returns
    -------
    The names, in the order requested (or of the table).

    Raises
    ------
    ValueError
        If a requested name is not in the table.
    """
    available = list(available)
    if requested is None:
        return available
    missing = [x for x in requested if x not in available]
    if missing:
        raise ValueError(f"{axis}s {missing} are not in the response table ({available})")
    return list(requested)


def figure_targets(targets: Sequence[str]) -> list[str]:
    """Targets drawn in Figs. 2 and 3: those of :data:`PAPER_TARGETS` present, else the first three."""
    chosen = [t for t in PAPER_TARGETS if t in targets]
    return chosen or list(targets[:3])


class FittedPair(NamedTuple):
    """Both viewpoint models of one detector x target.

    Attributes
    ----------
    gaussian
        The paper's Gaussian as a :class:`~scrppl.models.response.ResponseModel`.
    hierarchical
        The hierarchical model's posterior predictive as a ``ResponseModel``.
    posterior
        The hierarchical fit (``DataTree`` of :func:`~scrppl.models.fit.fit_hierarchical`).
    transform
        The response transform both models work on (``"identity"``, ``"anscombe"``, ...).
    """

    gaussian: ResponseModel
    hierarchical: ResponseModel
    posterior: xr.DataTree
    transform: str


class FitStudy(NamedTuple):
    """What :func:`fit_study` fitted and measured.

    Attributes
    ----------
    detectors, targets
        The detectors and targets fitted (:func:`select_names`).
    fits
        ``{(detector, target): FittedPair}`` in fitting order.
    diagnostics
        ``{"detector/target": report}`` as written to ``diagnostics.json`` (without ``thresholds``; it
        keeps the reports of earlier runs for pairs not fitted now). Each report is
        :func:`~scrppl.models.diagnostics.diagnose`'s with ``noncentered`` and ``attempts`` added.
    heldout
        Held-out scores of :func:`~scrppl.models.evaluate.evaluate_models` for every pair, or ``None``
        when the table has no ``test`` instances.
    failed
        :func:`failed_fits` of the pairs fitted now.
    """

    detectors: list[str]
    targets: list[str]
    fits: dict[tuple[str, str], FittedPair]
    diagnostics: dict[str, dict]
    heldout: pd.DataFrame | None
    failed: dict[str, list[str]]


def _is_current(path: Path, stamp: float | None) -> bool:
    return stamp is not None and path.exists() and path.stat().st_mtime >= stamp


#: Values of the ``azimuth_effect`` setting of :func:`fit_pair` and ``scrppl fit --azimuth-effect``.
AZIMUTH_EFFECT_CHOICES = ("off", "on", "auto")


def wants_azimuth_effect(setting: bool | str, data: ViewData) -> bool:
    """Whether a fit of ``data`` gets the instance x azimuth effect under ``setting``.

    ``True``/``"on"`` and ``False``/``"off"`` say so; ``"auto"`` gives it to a grid with more than one
    ring (elevations x scales > 1), where two views of one object from one azimuth exist and the effect is
    identified, and not to a single ring, where ``v_ia`` is one more draw of noise per view.
    """
    if isinstance(setting, str):
        if setting not in AZIMUTH_EFFECT_CHOICES:
            raise ValueError(
                f"azimuth_effect must be one of {AZIMUTH_EFFECT_CHOICES} or a bool, got {setting!r}"
            )
        if setting == "auto":
            _, n_elev, n_scale = data.grid_shape
            return n_elev * n_scale > 1
        return setting == "on"
    return bool(setting)


def fit_pair(
    key: jax.Array,
    table: xr.Dataset,
    models_dir: str | Path,
    detector: str,
    target: str,
    config: SamplerConfig,
    *,
    reuse_since: float | None = None,
    progress: bool = True,
    split: str = "fit",
    azimuth_effect: bool | str = "auto",
) -> tuple[FittedPair, dict]:
    """Fit (or load) the Gaussian and the hierarchical model of one detector x target.

    Both are saved under ``models_dir`` (:func:`~scrppl.models.io.model_path`). A saved fit newer than
    ``reuse_since`` is loaded instead -- the hierarchical one only if it was fitted by this
    :data:`~scrppl.models.io.MODEL_VERSION`, with the ``azimuth_effect`` asked for, and passed its
    diagnostics.

    Parameters
    ----------
    key
        PRNG key of the hierarchical fit.
    table
        The response table (:mod:`scrppl.responses`); its ``split`` is fitted.
    models_dir
        Folder of the saved models.
    detector, target
        Which pair.
    config
        NUTS settings.
    reuse_since
        Modification time (seconds since the epoch) a saved fit must not predate to be reused;
        ``None`` refits always.
    progress
        Show the sampler's progress bar.
    split
        The split fitted: ``"fit"`` (the experiment's models), or ``"test"`` for the oracle models of
        :func:`scrppl.sim.decomposition.fit_oracle` (fitted on the held-out instances themselves).
    azimuth_effect
        Fit the hierarchical model with an instance x azimuth effect (``fit_hierarchical(...,
        azimuth_effect=True)``): ``True``, ``False``, or ``"auto"`` (the default and the pipeline's
        model; :func:`wants_azimuth_effect`: only where the grid has more than one ring, the one place
        the effect can be told from the noise).

    Returns
    -------
    pair
        The fitted models.
    report
        The hierarchical fit's diagnostics, with its ``noncentered`` sites and retry ``attempts``.
    """
    models_dir = Path(models_dir)
    data, meta = extract_view_data(table, detector, target, split=split)
    gpath = model_path(models_dir, "gaussian", detector, target)
    hpath = model_path(models_dir, "hierarchical", detector, target)
    if not _is_current(gpath, reuse_since):
        g, n_obs = fit_gaussian(data)
        save_gaussian(gpath, g, n_obs, meta)
    with_effect = wants_azimuth_effect(azimuth_effect, data)
    tree = load_posterior(hpath) if _is_current(hpath, reuse_since) else None
    if tree is not None and not is_current_version(tree):
        tree = None  # fitted by another version of the model
    if (
        tree is not None
        and bool(json.loads(tree.attrs["meta"]).get("azimuth_effect")) != with_effect
    ):
        tree = None  # fitted with (without) the instance x azimuth effect, asked for without (with)
    if tree is not None and not json.loads(tree.attrs.get("diagnostics", "{}")).get("ok", False):
        tree = None  # failed its diagnostics: refit (a changed retry ladder may pass it now)
    if tree is None:
        # diagnostics are reported by the caller (fit_study collects them), hence warn=False
        tree = fit_hierarchical(
            key, data, meta, config, progress=progress, warn=False, azimuth_effect=with_effect
        )
        save_posterior(hpath, tree)
    report = json.loads(tree.attrs["diagnostics"])
    fit_meta = json.loads(tree.attrs["meta"])
    report["noncentered"] = fit_meta.get("noncentered")
    report["attempts"] = fit_meta.get("attempts", [])
    report["azimuth_effect"] = bool(fit_meta.get("azimuth_effect", False))
    gauss = load_response_model(models_dir, "gaussian", detector, target).response_model
    pair = FittedPair(gauss, to_response_model(tree), tree, meta["transform"])
    return pair, report


def _fit_task(
    job: tuple[int, tuple[str, str]],
    raw_key: np.ndarray,
    impl: str | None,
    table: xr.Dataset,
    models_dir: Path,
    config: SamplerConfig,
    stamp: float | None,
    azimuth_effect: bool | str = "auto",
) -> tuple[FittedPair, dict, pd.DataFrame | None]:
    """One cluster task of :func:`fit_study`: :func:`fit_pair` of pair ``j`` and its held-out scores.

    Pair ``j`` is fitted with ``fold_in(key, j)`` and scored by :func:`_heldout_scores`. The key
    arrives as its raw data (``impl`` names a typed key's implementation), so that the task
    reaches the worker without JAX (:mod:`scrppl.parallel` sets the worker's JAX flags first).
    """
    j, (det, tgt) = job
    key = jnp.asarray(raw_key) if impl is None else jax.random.wrap_key_data(raw_key, impl=impl)
    pair, report = fit_pair(
        jax.random.fold_in(key, j), table, models_dir, det, tgt, config,
        reuse_since=stamp, progress=False, azimuth_effect=azimuth_effect,
    )  # fmt: skip
    # scored held out on the worker too: beside the other fits rather than after all of them
    return pair, report, _heldout_scores(table, det, tgt, pair)


def _heldout_scores(table: xr.Dataset, det: str, tgt: str, pair: FittedPair) -> pd.DataFrame | None:
    """:func:`evaluate_models` of both fits of a pair on the table's ``test`` instances (``None``: none)."""
    if not (table["split"].values.astype(str) == "test").any():
        return None
    test, _ = extract_view_data(table, det, tgt, split="test")
    models = {"gaussian": pair.gaussian, "hierarchical": pair.hierarchical}
    omega = azimuth_sd(pair.posterior)  # the draws to_response_model kept (all of them)
    return evaluate_models(
        models,
        test,
        {"detector": det, "target": tgt},
        None if omega is None else {"hierarchical": omega},
    )


def failed_fits(
    diagnostics: Mapping[str, dict], detectors: Sequence[str], targets: Sequence[str]
) -> dict[str, list[str]]:
    """``{"detector/target": failures}`` of the listed pairs whose diagnostics are not ``ok``."""
    return {
        k: v["failures"]
        for k, v in diagnostics.items()
        if k.split("/")[0] in detectors and k.split("/")[1] in targets and not v["ok"]
    }


def fit_study(
    key: jax.Array,
    responses: str | Path,
    models_dir: str | Path,
    config: SamplerConfig,
    *,
    detectors: Sequence[str] | None = None,
    targets: Sequence[str] | None = None,
    force: bool = False,
    progress: bool = True,
    executor: Executor | None = None,
    azimuth_effect: bool | str = "auto",
) -> FitStudy:
    """Fit both viewpoint models of every detector x target, check them and score them held out.

    Pair ``j`` (detectors outer, targets inner) is fitted with ``jax.random.fold_in(key, j)``. Saved fits
    newer than ``responses`` are reused unless ``force``. Writes under ``models_dir`` the models,
    ``diagnostics.json`` (``thresholds`` and one report per pair, merged into an existing file) and,
    when the table has ``test`` instances, ``heldout.csv``.

    Parameters
    ----------
    key
        PRNG key.
    responses
        Path of the response table (``responses.nc``).
    models_dir
        Output folder (``<out>/models``).
    config
        NUTS settings.
    detectors, targets
        Subsets to fit (default: all of the table); checked by :func:`select_names`.
    force
        Refit even current models.
    progress
        Show progress bars.
    executor
        A Dask executor (:func:`scrppl.parallel.executor`): fit the pairs on a cluster, one task per
        detector x target, with the same keys and so the same draws; each task saves its fits (the
        workers must see ``models_dir``), so a rerun reuses the pairs already fitted. ``None`` fits here.
    azimuth_effect
        The instance x azimuth effect of every hierarchical fit (:func:`fit_pair`): ``"auto"`` (the
        default and the pipeline's model: with the effect where the grid has more than one ring),
        ``True`` or ``False``. The held-out joint density (``heldout.csv``) of a fit
        with the effect shares ``v_ia`` among the views of an instance from one azimuth, as the model does.

    Returns
    -------
    :class:`FitStudy`
    """
    responses, models_dir = Path(responses), Path(models_dir)
    table = load_response_table(responses)
    detectors = select_names(detectors, [str(d) for d in table["detector"].values], "detector")
    targets = select_names(targets, [str(t) for t in table["target"].values], "target")
    stamp = None if force else responses.stat().st_mtime
    diag_path = models_dir / "diagnostics.json"
    try:
        diagnostics = read_json(diag_path, "MCMC diagnostics") if diag_path.exists() else {}
    except CorruptFileError:
        diagnostics = {}  # unreadable: every fit's report is collected again and the file rewritten
    diagnostics = {k: v for k, v in diagnostics.items() if k != "thresholds"}
    heldout, fits = [], {}
    jobs = [(d, t) for d in detectors for t in targets]
    if executor is not None and executor.distributed:
        # one task per pair; the key travels as its raw data (see _fit_task)
        raw = np.asarray(jax.random.key_data(key))
        impl = (
            str(jax.random.key_impl(key))
            if jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
            else None
        )
        done = executor.map(
            _fit_task, list(enumerate(jobs)), raw, impl, table, models_dir, config, stamp,
            azimuth_effect, desc="scrppl fit", progress=progress,
        )  # fmt: skip
    else:

        def here(job: int, det: str, tgt: str):
            pair, report = fit_pair(
                jax.random.fold_in(key, job),
                table,
                models_dir,
                det,
                tgt,
                config,
                reuse_since=stamp,
                progress=progress,
                azimuth_effect=azimuth_effect,
            )
            return pair, report, _heldout_scores(table, det, tgt, pair)

        done = (
            here(job, det, tgt)
            for job, (det, tgt) in enumerate(tqdm(jobs, desc="scrppl fit", disable=not progress))
        )
    for (det, tgt), (pair, report, scores) in zip(jobs, done, strict=True):
        diagnostics[f"{det}/{tgt}"] = report
        fits[(det, tgt)] = pair
        if scores is not None:
            heldout.append(scores)
    with atomic_path(diag_path) as tmp:
        tmp.write_text(json.dumps({"thresholds": THRESHOLDS, **diagnostics}, indent=1))
    frame = None
    if heldout:
        frame = pd.concat(heldout, ignore_index=True)
        with atomic_path(models_dir / "heldout.csv") as tmp:
            frame.to_csv(tmp, index=False)
    return FitStudy(
        detectors, targets, fits, diagnostics, frame, failed_fits(diagnostics, detectors, targets)
    )
