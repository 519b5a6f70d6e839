"""When does looking pay off? The sequential-recognition experiment swept over imaging difficulty.

For a finished run (its trained detectors under ``<out>/detectors/`` and its dataset configuration and
seed), :func:`run_sweep` repeats the paper's paired experiment -- entropy planning (eq. 5) against a
random unseen view -- at several difficulty levels of the imaging domain
(:func:`scrppl.datasets.synthetic.domain.domain_at_level`: 0 no nuisance, 1 the ``robot`` preset, 2 the
``hard`` preset) and for several detector families, and relates the views it saves to the detector's
held-out average precision. Per level:

1. **render** the ``fit`` and ``test`` instances of the run's dataset at one ring of views (the run's first
   elevation and scale, every azimuth) in the level's robot domain -- the same seed, categories,
   instances and splits as the run, so the held-out instances are the run's held-out instances; the
   train split is not rendered (the run's detectors, trained on its catalogue images, serve every level);
2. **score** them with the run's detectors of the swept families and targets (resumable table
   ``<out>/sweep/<level>/responses.nc``);

(a level whose configuration is the run's own -- a one-ring run such as ``book`` at its preset's level --
takes the run's ``responses.nc`` instead: the same images scored by the same detectors,
:func:`reuse_run_table`; the rule is :func:`run_observed_level`);

and per (level, family, target):

3. **fit** the hierarchical viewpoint model on the fit split as ``scrppl fit`` does
   (:func:`scrppl.models.study.fit_pair`; fully non-centred, with the sweep's chain lengths and
   retries, the diagnostics recorded);
4. **simulate** ``n_trials`` paired trials on the test split: the hierarchical model with the
   instance-aware filter, the entropy planner and a random unseen view on the same trials and keys.

:func:`summarise_point` reduces one experiment to the numbers of the sweep: mean views to
``p(true class) > 0.95`` of both planners, the views saved (random minus planning) with a paired
bootstrap 95 % interval, the share of trials that reached confidence, and accuracy and ``p(true)`` after
1 and 2 views. The held-out AP is :func:`scrppl.detectors.evaluation.detector_ap` of the test split.

Keys: point (level, family, target) uses ``fold_in(key(seed), crc32("<level>/<family>/<target>"))``,
split into the keys of the fit, the trials and the planners, so a point's numbers do not depend on which
other points are swept. Each finished point is cached atomically in
``<out>/sweep/<level>/points/<family>-<target>.json`` with its settings; a rerun with the same settings
loads it (and an interrupted run resumes there).
"""

from __future__ import annotations

import dataclasses
import json
import time
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from scrppl._io import atomic_path, default_cache_dir
from scrppl.sim import metrics as M

__all__ = [
    "SweepSettings",
    "level_label",
    "level_config",
    "render_level",
    "score_level",
    "run_observed_level",
    "reuse_run_table",
    "point_key",
    "summarise_point",
    "run_point",
    "run_sweep",
    "save_sweep",
]

#: Per-point numbers of :func:`summarise_point` that have one value per planner.
PLANNER_VARS = (
    "views_to_confidence",
    "reached_confidence",
    "p_true_1",
    "p_true_2",
    "accuracy_1",
    "accuracy_2",
)
#: Per-point scalar numbers of the sweep dataset.
POINT_VARS = (
    "ap",
    "views_saved",
    "views_saved_lo",
    "views_saved_hi",
    "fit_ok",
    "rhat_max",
    "ess_bulk_min",
    "divergences",
)


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """How each point of the sweep is fitted and simulated.

    Attributes
    ----------
    n_trials
        Paired trials per point.
    num_warmup, num_samples, num_chains
        NUTS settings of the hierarchical fits (diagnostics recorded).
    n_samples
        Samples ``M`` per planning decision of the entropy planner.
    max_draws
        Posterior draws kept (evenly thinned) for filtering and planning.
    n_boot
        Bootstrap resamples of the paired interval.
    retry_longer
        A fit that fails its diagnostics is refitted as ``scrppl fit`` refits it (it starts fully
        non-centred, so without the switch of parameterisation): at the acceptance target
        :data:`~scrppl.models.fit.RETRY_ACCEPT`, then with this many times the warm-up and draws. ``1``:
        no retry at all (a failure is recorded either way).
    half_width
        Precision aimed for, in views: a point's trials run in blocks of ``block_trials`` until the
        paired 95 % interval of the views saved is at most this wide on either side of its estimate, or
        until ``n_trials`` (rounded up to whole blocks) have run. ``0``: exactly ``n_trials`` trials, in
        one batch. A point whose planner and baseline rarely differ needs a few hundred trials for an
        interval of +-0.05 views, one on a weak detector several thousand: the blocks spend the trials
        where the question needs them. (Stopping on the interval's own width is a fixed-width sequential
        rule, whose coverage approaches the nominal 95 % as the width shrinks: Chow & Robbins, 1965.)
    block_trials
        Trials per block when ``half_width > 0`` (block ``b`` draws its trials and planner keys from
        ``fold_in`` of the point's keys with ``b``, so a block's trials do not depend on how many
        blocks run).
    """

    n_trials: int = 10000
    num_warmup: int = 300
    num_samples: int = 300
    num_chains: int = 2
    n_samples: int = 128
    max_draws: int = 8
    n_boot: int = 2000
    retry_longer: int = 1
    half_width: float = 0.0
    block_trials: int = 2048

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "half_width":
                if not (np.isfinite(v) and v >= 0):
                    raise ValueError(
                        f"SweepSettings.half_width must be a finite number >= 0, got {v!r}"
                    )
            elif int(v) != v or v < (2 if f.name in ("n_trials", "block_trials") else 1):
                raise ValueError(f"SweepSettings.{f.name} must be a positive integer, got {v!r}")

    @property
    def max_blocks(self) -> int:
        """Blocks of ``block_trials`` at most (``n_trials`` rounded up to whole blocks)."""
        return -(-self.n_trials // self.block_trials)


def level_label(level: float) -> str:
    """Folder and label of a level: ``"level-1"``, ``"level-0p5"``."""
    return "level-" + f"{float(level):g}".replace(".", "p")


def level_config(config, level: float):
    """The run's dataset configuration at one ring of views (first elevation and scale) and ``level``.

    Categories, instances, split proportions, image size and jitter are the run's, so with the run's seed
    the instances and their splits are the run's.
    """
    from scrppl.datasets.synthetic.domain import domain_at_level
    from scrppl.views import ViewGrid

    grid = config.grid
    ring = ViewGrid(grid.n_azimuth, (grid.elevations[0],), (grid.scales[0],))
    return dataclasses.replace(config, grid=ring, domain=domain_at_level(level))


def _config_tag(config) -> str:
    """A short hash of the configuration without its domain (names the rendering cache folders)."""
    d = config.to_dict()
    d.pop("domain", None)
    return f"{zlib.crc32(json.dumps(d, sort_keys=True).encode()):08x}"


def render_level(
    config,
    seed: int,
    level: float,
    *,
    cache_dir: str | Path | None = None,
    workers: int | None = None,
    progress: bool = False,
):
    """Render (or load) the fit and test instances of ``config`` at one ring and ``level``.

    The images go to ``<cache_dir>/sweep-<hash of the configuration>-<level>-seed<seed>`` (default cache
    folder: :func:`scrppl._io.default_cache_dir`); a complete folder is loaded, an interrupted one
    resumed (:func:`scrppl.datasets.synthetic.make_synthetic` with ``splits=("fit", "test")``).
    """
    from scrppl.datasets.synthetic import make_synthetic

    cfg = level_config(config, level)
    root = Path(cache_dir or default_cache_dir())
    root = root / f"sweep-{_config_tag(cfg)}-{level_label(level)}-seed{int(seed)}"
    return make_synthetic(
        root, cfg, seed, workers=workers, progress=progress, splits=("fit", "test")
    )


def load_run_detectors(
    run_dir: str | Path, families: Sequence[str], targets: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """The run's trained detectors ``{family: {target: Detector}}`` from ``<run_dir>/detectors/``.

    Raises
    ------
    FileNotFoundError
        Naming the missing file and the command that makes it.
    """
    from scrppl.detectors.base import load_detector
    from scrppl.detectors.train import detector_path

    out: dict[str, dict[str, Any]] = {}
    for fam in families:
        out[fam] = {}
        for t in targets:
            path = detector_path(run_dir, fam, t)
            if not path.exists():
                raise FileNotFoundError(
                    f"no trained {fam} detector for {t!r} at {path}; run `scrppl detect --families "
                    f"{fam}` on this run folder first"
                )
            out[fam][t] = load_detector(path)
    return out


def score_level(dataset, detectors, path: str | Path, *, workers: int = 1, progress: bool = False):
    """The response table of ``dataset`` with ``detectors`` at ``path`` (resumable; reused when current)."""
    from scrppl.detectors.scoring import score_dataset

    return score_dataset(dataset, detectors, path=path, progress=progress, workers=workers)


def run_observed_level(config, level: float) -> bool:
    """Whether the run's own fit and test images are a level's: the reuse rule of :func:`reuse_run_table`.

    True exactly when the robot nuisances of the run's domain (``config.domain.robot``) equal those of
    the level's domain (:func:`~scrppl.datasets.synthetic.domain.domain_at_level`), compared field by
    field -- not by the domains' names, which a custom domain may share with a preset. The held-out
    images depend on the robot nuisances only: the ``catalogue`` flag changes the train split alone,
    which the sweep does not use. So a ``robot`` run observed level 1, a ``paper`` run level 1.4, a
    ``hard`` run level 2, a ``clean`` run level 0 (no nuisance), and none of them any other level.
    """
    return level_config(config, level).domain.robot == config.domain.robot


def reuse_run_table(run_dir: str | Path, config, level: float, detectors) -> xr.Dataset | None:
    """The run's own response table for ``level``, when the run already observed that level.

    That is when the run's dataset is in the level's domain (e.g. a run of the ``robot`` preset at level
    1) and ``<run_dir>/responses.nc`` was scored by the same detectors. For a one-ring run (``book``) its
    fit and test images are the images :func:`render_level` renders, byte for byte; for a run on more
    rings (``full``) the sweep takes the run's first ring (first elevation and scale) -- the run's own
    held-out images there, in the same domain. Returns the table of the swept families and targets at
    that ring with the train split blanked (as a rendered level has it), or ``None``.
    """
    from scrppl.responses import load_response_table

    path = Path(run_dir) / "responses.nc"
    if not run_observed_level(config, level) or not path.exists():
        return None
    table = load_response_table(path)
    families = list(detectors)
    targets = sorted({t for by in detectors.values() for t in by})
    if not set(families) <= set(table["detector"].values.tolist()):
        return None
    if not set(targets) <= set(table["target"].values.tolist()):
        return None
    try:
        saved = json.loads(table.attrs.get("detectors", "{}"))
    except json.JSONDecodeError:
        return None
    for fam, by in detectors.items():
        for t, det in by.items():
            mine = json.loads(json.dumps(det.fingerprint(), sort_keys=True, default=str))
            if saved.get(f"{fam}/{t}") != mine:
                return None
    # the first ring: the run's first elevation and scale (all of a one-ring run)
    table = table.sel(detector=families, target=targets).isel(elevation=[0], scale=[0])
    table = table.copy(deep=True)
    ring = level_config(config, level).grid
    table.attrs["grid"] = json.dumps(ring.to_dict())
    train = table["split"] == "train"
    table["score"] = table["score"].where(~train)
    table["split"] = table["split"].where(~train, "")
    table.attrs["families"] = json.dumps(families)
    return table


def point_key(seed: int, level: float, family: str, target: str):
    """The PRNG key of one point: ``fold_in(key(seed), crc32("<level>/<family>/<target>"))``."""
    import jax

    tag = f"{float(level):g}/{family}/{target}".encode()
    return jax.random.fold_in(jax.random.key(int(seed)), zlib.crc32(tag) & 0x7FFFFFFF)


def summarise_point(
    ds: xr.Dataset,
    planner: str = "sampled",
    baseline: str = "random",
    *,
    seed: int = 0,
    n_boot: int = 2000,
) -> dict[str, Any]:
    """The sweep's numbers of one paired experiment (:func:`scrppl.sim.run_experiment`, one method).

    Returns
    -------
    dict
        ``views_to_confidence``, ``reached_confidence``, ``p_true_1``/``_2`` and ``accuracy_1``/``_2``
        (after 1 and 2 views) as ``{planner: value}``; ``views_saved`` (mean of ``random - planning``
        views to confidence over the paired trials; censored trials count ``K + 1``) with the bootstrap
        interval ``views_saved_lo``/``_hi`` (:func:`scrppl.sim.metrics.paired_bootstrap_difference`).
    """
    if ds.sizes.get("method", 1) != 1:
        raise ValueError(f"summarise_point takes one method, got {ds['method'].values.tolist()}")
    sub = ds.isel(method=0) if "method" in ds.dims else ds
    n_k = ds.sizes["step"]
    out: dict[str, Any] = {v: {} for v in PLANNER_VARS}
    for p in (planner, baseline):
        v = sub["views_to_confidence"].sel(planner=p).values.astype(float)
        out["views_to_confidence"][p] = float(v.mean())
        out["reached_confidence"][p] = float((v <= n_k).mean())
        for k in (1, 2):
            if k <= n_k:
                out[f"p_true_{k}"][p] = float(sub["p_true"].sel(planner=p, step=k).mean())
                out[f"accuracy_{k}"][p] = float(sub["correct"].sel(planner=p, step=k).mean())
            else:
                out[f"p_true_{k}"][p] = out[f"accuracy_{k}"][p] = float("nan")
    a = sub["views_to_confidence"].sel(planner=baseline).values.astype(float)
    b = sub["views_to_confidence"].sel(planner=planner).values.astype(float)
    d, lo, hi = M.paired_bootstrap_difference(seed, a, b, n_boot)
    out.update(views_saved=float(d), views_saved_lo=float(lo), views_saved_hi=float(hi))
    out["n_trials"] = int(ds.sizes["trial"])
    out["n_steps"] = int(n_k)
    return out


def run_point(
    key,
    table: xr.Dataset,
    models_dir: str | Path,
    family: str,
    target: str,
    settings: SweepSettings,
    *,
    seed: int = 0,
    progress: bool = False,
) -> tuple[dict[str, Any], xr.Dataset]:
    """Fit and simulate one (family, target) of one level's response table.

    ``key`` is split into the keys of the fit, the trials and the planners (the same planner key for
    both planners: paired trials). The hierarchical model is fitted on the fit split as
    :func:`scrppl.models.study.fit_pair` fits it, fully non-centred and with at most three retries
    (``settings.retry_longer``; a fit failing its diagnostics after them is recorded, not rerun), with
    the instance x azimuth effect where the level's grid has more than one ring, and
    saved in ``models_dir``; it is always fitted anew: the point, not the fit,
    is the unit :func:`run_sweep` caches. The trials are ``settings.n_trials`` paired trials, or, with
    ``settings.half_width``, blocks of ``settings.block_trials`` until the interval of the views saved
    is that narrow (the summary's ``n_trials`` says how many ran).

    Returns
    -------
    summary
        :func:`summarise_point` plus ``ap`` (held-out AP), the fit's diagnostics (``fit_ok``,
        ``rhat_max``, ``ess_bulk_min``, ``divergences``), the ``filter`` used and ``seconds``
        (``fit``, ``simulate``).
    experiment
        The experiment dataset (dims ``method``, ``planner``, ``trial``, ``step``).
    """
    import jax

    from scrppl.detectors.evaluation import detector_ap
    from scrppl.models import transforms
    from scrppl.models.data import extract_view_data
    from scrppl.models.fit import RETRY_ACCEPT, RETRY_NONCENTERED, fit_hierarchical
    from scrppl.models.io import model_path, save_posterior
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.study import wants_azimuth_effect
    from scrppl.planning import PlannerConfig
    from scrppl.sim.experiment import run_experiment
    from scrppl.sim.simulator import make_trials
    from scrppl.sim.study import load_methods, study_planners

    k_fit, k_trials, k_run = jax.random.split(key, 3)
    sampler = SamplerConfig(
        num_warmup=settings.num_warmup,
        num_samples=settings.num_samples,
        num_chains=settings.num_chains,
        chunk=max(settings.num_warmup, settings.num_samples),
    )
    t0 = time.perf_counter()
    data, meta = extract_view_data(table, family, target, split="fit")
    # every azimuth coefficient non-centred from the start (one ring leaves a few responses per cell,
    # where choose_noncentered picks it too); a fit that fails gets fit_hierarchical's retries: 0.99
    # (the divergences of strong detectors' fits), then longer chains (R-hat and ESS near their gates)
    retry = settings.retry_longer > 1
    tree = fit_hierarchical(
        k_fit,
        data,
        meta,
        sampler,
        noncentered=RETRY_NONCENTERED,
        retry_accept=RETRY_ACCEPT if retry else None,
        retry_longer=settings.retry_longer if retry else None,
        progress=progress,
        warn=False,
        # the pipeline's model: the instance x azimuth effect where the grid has more than one ring
        azimuth_effect=wants_azimuth_effect("auto", data),
    )
    attempts = json.loads(tree.attrs["meta"])["attempts"]
    save_posterior(model_path(models_dir, "hierarchical", family, target), tree)
    report = json.loads(tree.attrs["diagnostics"])
    t1 = time.perf_counter()
    planners = study_planners(PlannerConfig("sampled", "joint", n_samples=settings.n_samples))

    loaded = {}

    def experiment(k_t, k_r, n):
        if not loaded:  # the model is read once per point; each block draws its own trials
            methods, used = load_methods(
                k_t, models_dir, table, family, target, n,
                kinds=("hierarchical",), max_draws=settings.max_draws,
            )  # fmt: skip
            name = (
                "hierarchical+instance"
                if "hierarchical+instance" in methods
                else next(iter(methods))
            )
            loaded.update(name=name, method=methods[name], transform=used["hierarchical"])
        else:
            trials = make_trials(
                k_t, table, family, target, n,
                transform=lambda raw: transforms.apply(loaded["transform"], raw),
            )  # fmt: skip
            loaded["method"] = loaded["method"]._replace(trials=trials)
        ds = run_experiment(
            k_r,
            {loaded["name"]: loaded["method"]},
            planners,
            category_names=table["category"].values.tolist(),
            progress=progress,
            chunk_size=2048,
        )
        return ds, loaded["method"].filter

    if settings.half_width > 0:
        # blocks until the paired interval is narrow enough (see SweepSettings.half_width)
        blocks = []
        for b in range(settings.max_blocks):
            part, filter_name = experiment(
                jax.random.fold_in(k_trials, b), jax.random.fold_in(k_run, b), settings.block_trials
            )
            blocks.append(part)
            ds = xr.concat(blocks, dim="trial") if len(blocks) > 1 else part
            summary = summarise_point(ds, "sampled", "random", seed=seed, n_boot=settings.n_boot)
            width = max(
                summary["views_saved_hi"] - summary["views_saved"],
                summary["views_saved"] - summary["views_saved_lo"],
            )
            if width <= settings.half_width:
                break
        if "trial" in ds.coords:
            ds = ds.assign_coords(trial=np.arange(ds.sizes["trial"]))
    else:
        ds, filter_name = experiment(k_trials, k_run, settings.n_trials)
        summary = summarise_point(ds, "sampled", "random", seed=seed, n_boot=settings.n_boot)
    t2 = time.perf_counter()
    ap = detector_ap(table, "test").sel(detector=family, target=target)
    summary.update(
        ap=float(ap),
        filter=filter_name,
        fit_ok=bool(report["ok"]),
        rhat_max=float(np.max(list(report["rhat_max"].values()))),
        ess_bulk_min=float(np.min(list(report["ess_bulk_min"].values()))),
        divergences=int(report["divergences"]),
        fit_failures=list(report.get("failures", [])),
        fit_attempts=len(attempts),
        seconds={"fit": round(t1 - t0, 2), "simulate": round(t2 - t1, 2)},
    )
    return summary, ds


def _point_path(out: Path, level: float, family: str, target: str) -> Path:
    return out / "sweep" / level_label(level) / "points" / f"{family}-{target}.json"


def run_sweep(
    seed: int,
    run_dir: str | Path,
    config,
    levels: Sequence[float],
    families: Sequence[str],
    targets: Sequence[str],
    settings: SweepSettings = SweepSettings(),
    *,
    cache_dir: str | Path | None = None,
    workers: int = 2,
    force: bool = False,
    progress: bool = False,
    log: Callable[[str], None] = lambda msg: None,
) -> tuple[xr.Dataset, dict[str, Any]]:
    """The experiment at every level x family x target of a finished run (see the module docstring).

    Parameters
    ----------
    seed
        The run's seed: of its dataset (instances, splits, images) and of the sweep's keys.
    run_dir
        The run folder (``--out``): its ``detectors/<family>-<target>.npz`` are used; the sweep writes
        under ``<run_dir>/sweep/``.
    config
        The run's dataset configuration (:class:`~scrppl.datasets.synthetic.SyntheticConfig`).
    levels, families, targets
        What to sweep.
    settings
        Trials, sampler and planner settings (:class:`SweepSettings`).
    cache_dir
        Where the rendered images go (default: the user cache, :func:`scrppl._io.default_cache_dir`).
    workers
        Processes rendering and scoring the images.
    force
        Recompute every point even if a cached result with the same settings exists (images and
        response tables are still reused: they are identical).
    progress, log
        Progress bars (tqdm) and where to report each step.

    Returns
    -------
    sweep
        ``xarray.Dataset`` with dims ``(level, family, target)`` (and ``planner`` for the numbers of
        each planner): :data:`POINT_VARS` and :data:`PLANNER_VARS`.
    summary
        JSON-ready: settings, every point's numbers, and the seconds this call spent on each part
        (``render``, ``score``, ``fit``, ``simulate``; a cached point costs none) in all and per level,
        with the images rendered and scored; ``points_computed`` counts the points not taken from the
        cache.
    """
    from tqdm.auto import tqdm

    run_dir = Path(run_dir)
    levels = [float(x) for x in levels]
    families, targets = list(families), list(targets)
    if not levels or not families or not targets:
        raise ValueError("run_sweep needs at least one level, one family and one target")
    if len(set(levels)) != len(levels):
        raise ValueError(f"levels repeat: {levels}")
    for level in levels:
        level_config(config, level)  # ValueError naming a level outside [0, 2]
    detectors = load_run_detectors(run_dir, families, targets)
    from scrppl.models.io import MODEL_VERSION

    fingerprint = {
        "seed": int(seed),
        # a point fitted by another version of the viewpoint model is recomputed
        "model_version": MODEL_VERSION,
        "settings": dataclasses.asdict(settings),
        "config": {k: v for k, v in config.to_dict().items() if k != "domain"},
        "detectors": {
            f"{fam}/{t}": det.fingerprint()
            for fam, by in detectors.items()
            for t, det in by.items()
        },
    }
    fingerprint = json.loads(json.dumps(fingerprint, default=str))
    seconds = {"render": 0.0, "score": 0.0, "fit": 0.0, "simulate": 0.0}
    per_level: dict[str, Any] = {}
    points: dict[str, dict[str, dict[str, Any]]] = {}
    n_points = len(levels) * len(families) * len(targets)
    bar = tqdm(total=n_points, desc="sweep", unit="point", disable=not progress)
    try:
        for level in levels:
            label = level_label(level)
            lvl: dict[str, Any] = {"render": 0.0, "score": 0.0, "fit": 0.0, "simulate": 0.0}
            mark = {**fingerprint, "domain": level_config(config, level).domain.to_dict()}
            mark = json.loads(json.dumps(mark, default=str))
            cached = {}
            for fam in families:
                for t in targets:
                    path = _point_path(run_dir, level, fam, t)
                    if path.exists() and not force:
                        try:
                            saved = json.loads(path.read_text())
                        except json.JSONDecodeError:
                            saved = None
                        if saved is not None and saved.get("fingerprint") == mark:
                            cached[(fam, t)] = saved["summary"]
            table = None
            if len(cached) < len(families) * len(targets):
                table = reuse_run_table(run_dir, config, level, detectors)
                lvl["source"] = "rendered" if table is None else "run"
            if table is not None:
                log(f"[sweep] {label}: the run's own images and responses (responses.nc)")
                lvl["images"] = 0
            elif len(cached) < len(families) * len(targets):
                log(f"[sweep] {label}: rendering the fit and test instances")
                t0 = time.perf_counter()
                dataset = render_level(
                    config,
                    seed,
                    level,
                    cache_dir=cache_dir,
                    workers=workers,
                    progress=progress,
                )
                t1 = time.perf_counter()
                log(f"[sweep] {label}: scoring {len(dataset)} images")
                resp_path = run_dir / "sweep" / label / "responses.nc"
                table = score_level(
                    dataset, detectors, resp_path, workers=workers, progress=progress
                )
                t2 = time.perf_counter()
                lvl.update(render=round(t1 - t0, 2), score=round(t2 - t1, 2))
                lvl["images"] = len(dataset)
            for fam in families:
                for t in targets:
                    if (fam, t) in cached:
                        summary = cached[(fam, t)]
                        summary = {**summary, "seconds": {"fit": 0.0, "simulate": 0.0}}
                        summary["cached"] = True
                    else:
                        bar.set_postfix_str(f"{label} {fam}/{t}")
                        most = settings.max_blocks * settings.block_trials
                        upto = f"up to {most}" if settings.half_width > 0 else settings.n_trials
                        log(f"[sweep] {label}: {fam}/{t}: fit and {upto} trials")
                        summary, _ = run_point(
                            point_key(seed, level, fam, t),
                            table,
                            run_dir / "sweep" / label / "models",
                            fam,
                            t,
                            settings,
                            seed=seed,
                        )
                        path = _point_path(run_dir, level, fam, t)
                        with atomic_path(path) as tmp:
                            tmp.write_text(json.dumps({"fingerprint": mark, "summary": summary}))
                    for part in ("fit", "simulate"):
                        lvl[part] = round(lvl[part] + summary["seconds"][part], 2)
                    points.setdefault(label, {})[f"{fam}/{t}"] = summary
                    bar.update(1)
            for part in seconds:
                seconds[part] = round(seconds[part] + lvl[part], 2)
            per_level[label] = lvl
    finally:
        bar.close()
    ds = _to_dataset(levels, families, targets, points)
    ds.attrs.update(
        seed=int(seed),
        settings=json.dumps(dataclasses.asdict(settings)),
        confidence_threshold=M.CONFIDENCE,
        planners=json.dumps(["sampled", "random"]),
        views_saved="mean over paired trials of random minus planning views to p(true) > "
        f"{M.CONFIDENCE}; a trial that never gets there counts n_steps + 1",
    )
    n_fit = sum(1 for lv in points.values() for p in lv.values() if not p.get("cached"))
    summary = {
        "seed": int(seed),
        "levels": levels,
        "families": families,
        "targets": targets,
        "settings": dataclasses.asdict(settings),
        "domains": {level_label(x): level_config(config, x).domain.to_dict() for x in levels},
        "seconds": {**seconds, "total": round(sum(seconds.values()), 2)},
        "seconds_per_level": per_level,
        "points_computed": n_fit,
        "points": points,
    }
    return ds, summary


def _to_dataset(levels, families, targets, points) -> xr.Dataset:
    shape = (len(levels), len(families), len(targets))
    planners = ["sampled", "random"]
    data: dict[str, Any] = {}
    for var in POINT_VARS:
        arr = np.full(shape, np.nan)
        for i, lv in enumerate(levels):
            for j, fam in enumerate(families):
                for k, t in enumerate(targets):
                    arr[i, j, k] = float(points[level_label(lv)][f"{fam}/{t}"][var])
        data[var] = (("level", "family", "target"), arr)
    for var in PLANNER_VARS:
        arr = np.full((*shape, len(planners)), np.nan)
        for i, lv in enumerate(levels):
            for j, fam in enumerate(families):
                for k, t in enumerate(targets):
                    for p, name in enumerate(planners):
                        arr[i, j, k, p] = points[level_label(lv)][f"{fam}/{t}"][var][name]
        data[var] = (("level", "family", "target", "planner"), arr)
    coords = {"level": levels, "family": families, "target": targets, "planner": planners}
    steps = {int(p["n_steps"]) for lv in points.values() for p in lv.values()}
    attrs = {"n_steps": steps.pop()} if len(steps) == 1 else {}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def save_sweep(sweep: xr.Dataset, summary: dict[str, Any], out: str | Path) -> list[Path]:
    """Write ``<out>/sweep.nc`` and ``<out>/sweep-summary.json`` (atomically); returns their paths."""
    from scrppl._io import write_netcdf

    out = Path(out)
    nc = write_netcdf(sweep, out / "sweep.nc")
    js = out / "sweep-summary.json"
    with atomic_path(js) as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    return [Path(nc), js]
