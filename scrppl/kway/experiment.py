"""The K-way experiment: which category is it, after 1, 2, ... views? (beyond Meger et al. 2010, IV-A).

Each trial shows a held-out (``test`` split) instance of one of the ``K`` categories -- categories in
equal shares, instances uniformly within them -- under a hidden pose ``theta*``, from a random start
azimuth on a ring (elevation, scale) where every target detector has a response from every azimuth. At
each view the ``T = K`` target detectors of one family respond; three methods see the same trials:

* ``planning`` -- the K-way filter (:mod:`scrppl.kway.filter`) choosing views by sampled expected
  entropy (:mod:`scrppl.kway.planning`), by default with the collapsed posterior update
  (:data:`DEFAULT_PLANNER`);
* ``random`` -- the same filter, random unseen views;
* ``one_vs_rest`` -- ``K`` separate binary filters (:mod:`scrppl.belief`, the binary viewpoint models of
  each target), each fed its own detector's response at the *same* random views as ``random``, the
  prediction the category whose ``p(present)`` is largest; its class probabilities are the ``p(present)``
  normalised over categories.

Per trial and step: the MAP category and whether it is right, ``p(true category)``, the class-marginal
entropy; per trial the views until ``p(true) > 0.95`` (``steps + 1`` if never). Trial ``i`` uses key
``fold_in(key, i)`` and its step ``j`` ``fold_in(fold_in(key, i), j)`` for every method (paired trials).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from jax.scipy.special import logsumexp
from tqdm.auto import tqdm

from scrppl import belief as B
from scrppl.kway import filter as KF
from scrppl.kway.models import KwayModel, check_kway_model
from scrppl.kway.planning import _check_config, _choose_view
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig, candidate_views
from scrppl.responses import table_grid, validate_response_table
from scrppl.sim import metrics as M
from scrppl.sim.simulator import robot_frame, transformed_scores

__all__ = [
    "METHODS",
    "ENTROPY_PLANNERS",
    "DEFAULT_PLANNER",
    "CORRELATED_PLANNER",
    "default_planner",
    "CONFUSION_STEPS",
    "KwayTrials",
    "make_kway_trials",
    "run_kway_experiment",
    "kway_trial_draws",
    "class_metrics",
    "categories_without_trials",
    "summarise_kway",
    "compare_kway",
    "confusion_matrices",
    "CALIBRATION_STEPS",
    "kway_calibration",
]

#: Methods of the experiment, in the order of its ``method`` dimension.
METHODS = ("planning", "random", "one_vs_rest")
#: Entropy planners the ``planning`` method may use (:mod:`scrppl.kway.planning`).
ENTROPY_PLANNERS = ("sampled", "collapsed", "equicorrelated")
#: The ``planning`` method's planner: ``"collapsed"``, the expected entropy with the moment-matched
#: posterior update (:mod:`scrppl.kway.planning`). Why: with eight posterior draws per target the exact
#: ``"sampled"`` planner needs 7-13 milliseconds per decision on two cores, the collapsed one under one
#: (``benchmarks/results/kway.json``, ``decisions``); on the beliefs of the book profile's trials its
#: expected entropies lie within about ``2e-4`` nats of the exact ones (``approximation``); and the book
#: profile's experiment run with each planner on the same trials gave the same accuracy after 1, 2, 4 and 8
#: views and the same views to confidence within the paired 95% intervals
#: (``experiment_collapsed_minus_sampled``; that experiment is near its ceiling, so the approximation
#: study is the sharper check). Pass ``planner="sampled"`` to :func:`run_kway_experiment` for the exact one.
DEFAULT_PLANNER = "collapsed"
#: The ``planning`` method's planner with the correlated filter: ``"equicorrelated"``
#: (:mod:`scrppl.kway.planning`), the collapsed planner with one correlation shared by every two
#: detectors instead of a ``T x T`` covariance per state. In the paper regime (DPM, ten categories, eight
#: draws, ``M = 256``), on the beliefs of 60 test trials after 1, 2 and 3 random views where the
#: candidates differ by at least 0.01 nats (84 of 180), its choices cost 0.0053 nats of expected class
#: entropy on average against 0.0033 for the full collapsed planner and 0.0034 for the exact one at the
#: same ``M`` (the reference: the exact planner with ``M = 2048``); on 3,200 paired trials the views to
#: confidence with planning differed by +0.008 [-0.026, +0.040], and the experiment took 29.7 s instead
#: of 44.3 (``benchmarks/results/kway-equicorrelated.json``, ``bench_kway_correlated.py --planner-study``).
CORRELATED_PLANNER = "equicorrelated"


def default_planner(filter: str) -> str:
    """The ``planning`` method's planner for a filter: :data:`CORRELATED_PLANNER` or :data:`DEFAULT_PLANNER`."""
    return CORRELATED_PLANNER if filter == "correlated" else DEFAULT_PLANNER


#: The experiment's default planner settings: minimise the class entropy H(k).
_CLASS_OBJECTIVE = PlannerConfig(objective="class")
#: Steps after which confusion matrices are reported.
CONFUSION_STEPS = (1, 2, 4)


class KwayTrials(NamedTuple):
    """A batch of K-way trials (leading axis ``R``: trials).

    Attributes
    ----------
    responses
        Transformed responses of every target detector in the object frame, ``(R, T, A, E, S)``; 0 where
        missing.
    available
        ``(R, A, E, S)``: every target detector has a response there.
    category
        True category index ``k*`` (into the table's categories), ``(R,)``.
    instance
        Instance index, ``(R,)``.
    pose
        Hidden pose ``theta*``, ``(R,)``.
    start
        Start robot view ``(phi0, e0, s0)``, ``(R, 3)``.
    """

    responses: jax.Array
    available: jax.Array
    category: jax.Array
    instance: jax.Array
    pose: jax.Array
    start: jax.Array


def make_kway_trials(
    key: jax.Array,
    table: xr.Dataset,
    detector: str,
    n_trials: int,
    *,
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
    split: str = "test",
) -> KwayTrials:
    """Draw ``n_trials`` K-way trials from the held-out instances (see the module docstring).

    Parameters
    ----------
    key
        JAX PRNG key: the same key gives the same trials.
    table
        The response table; every category must also be a target.
    detector
        The detector family.
    n_trials
        Number of trials ``R``; category ``r mod K`` of a random permutation, so shares differ by at most 1.
    transform
        Applied to the raw scores (the models' transform); ``None`` keeps them.
    split
        The instances' split.
    """
    validate_response_table(table)
    if detector not in table["detector"].values.tolist():
        raise ValueError(
            f"detector {detector!r} is not in the response table ({table['detector'].values.tolist()})"
        )
    if n_trials < 1:
        raise ValueError(f"n_trials must be positive, got {n_trials}")
    categories = [str(c) for c in table["category"].values]
    missing = [c for c in categories if c not in table["target"].values.tolist()]
    if missing:
        raise ValueError(
            f"K-way trials need a target detector for every category; none for {missing}"
        )
    score = np.stack([transformed_scores(table, detector, t, transform) for t in categories])
    present, complete, usable = _usable(score, table, split)
    for c, name in enumerate(categories):
        if not usable[c].any():
            raise ValueError(
                f"category {name!r} has no {split!r} instance with every target's response on a full "
                f"azimuth ring (detector {detector!r})"
            )
    n_k, n_a = len(categories), table_grid(table).n_azimuth
    k_cat, k_inst, k_ring, k_pose, k_phi = jax.random.split(key, 5)
    cat = np.asarray(jax.random.permutation(k_cat, np.arange(n_trials) % n_k)).astype(np.int32)
    u_inst = np.asarray(jax.random.uniform(k_inst, (n_trials,)))
    u_ring = np.asarray(jax.random.uniform(k_ring, (n_trials,)))
    inst = np.empty(n_trials, np.int32)
    ring = np.empty((n_trials, 2), np.int32)
    for r in range(n_trials):
        pool = np.flatnonzero(usable[cat[r]])
        inst[r] = pool[min(int(u_inst[r] * len(pool)), len(pool) - 1)]
        rings = np.argwhere(complete[cat[r], inst[r]])
        ring[r] = rings[min(int(u_ring[r] * len(rings)), len(rings) - 1)]
    pose = np.asarray(jax.random.randint(k_pose, (n_trials,), 0, n_a), np.int32)
    phi0 = np.asarray(jax.random.randint(k_phi, (n_trials,), 0, n_a), np.int32)
    resp = np.moveaxis(score[:, cat, inst], 0, 1)  # (R, T, A, E, S)
    avail = present[cat, inst]
    return KwayTrials(
        jnp.asarray(np.where(avail[:, None], resp, 0.0), jnp.float32),
        jnp.asarray(avail),
        jnp.asarray(cat),
        jnp.asarray(inst),
        jnp.asarray(pose),
        jnp.asarray(np.c_[phi0, ring].astype(np.int32)),
    )


def _usable(score, table, split):
    """Masks of ``score`` ``(T, C, I, A, E, S)``: where trials can come from.

    Every target responded ``(C, I, A, E, S)``; a full azimuth ring ``(C, I, E, S)``; the instances of
    ``split`` with at least one such ring ``(C, I)``.
    """
    present = ~np.isnan(score).any(axis=0)
    complete = present.all(axis=2)
    usable = (table["split"].values.astype(str) == split) & complete.any(axis=(2, 3))
    return present, complete, usable


def categories_without_trials(
    table: xr.Dataset, detector: str, *, transform=None, split: str = "test"
) -> list[str]:
    """The categories with no ``split`` instance :func:`make_kway_trials` can draw a trial from.

    Such an instance has every target's response on a full azimuth ring; empty when trials can be made.
    """
    categories = [str(c) for c in table["category"].values]
    score = np.stack([transformed_scores(table, detector, t, transform) for t in categories])
    usable = _usable(score, table, split)[2]
    return [name for c, name in enumerate(categories) if not usable[c].any()]


# ------------------------------------------------------------------------------------------------
# one trial, compiled


def _trial(
    key,
    model,
    binary,
    responses,
    available,
    pose,
    start,
    log_weight,
    *,
    filter,
    config,
    n_steps,
    ovr,
    draws_per_trial=None,
):
    """One trial: K-way filter + planner; with ``ovr`` also the ``K`` binary filters on the same views.

    ``draws_per_trial``: the trial reads its own draws of the models (:func:`kway_trial_draws`).

    ``log_weight`` (``None`` or ``(N,)``): the draws' log weights, for the instance-aware filter only
    (its starting log evidence, :func:`scrppl.models.tails.kway_weighted_init`; the updates and the
    planner are then unchanged).

    Returns per step the view ``(3,)``, whether it was observed, the K-way ``p(k | F)`` ``(K,)`` and the
    binary filters' ``log p(present | F)`` ``(T,)`` (zeros without ``ovr``).
    """
    model, binary, log_weight = kway_trial_draws(key, model, binary, log_weight, draws_per_trial)
    n_t = responses.shape[0]
    resp_r = jax.vmap(lambda r: robot_frame(r, available, pose)[0])(responses)  # (T, A, E, S)
    avail_r = robot_frame(responses[0], available, pose)[1]

    def binary_update(bb, f, view):
        return jax.vmap(lambda m, b, x: B.update(m, b, x, view[0], view[1], view[2]))(binary, bb, f)

    def observe(state, view, found):
        belief, bb, visited, current = state
        view = jnp.where(found, view, current)
        f = resp_r[:, view[0], view[1], view[2]]
        new = KF.update(model, belief, f, view[0], view[1], view[2])
        belief = jax.tree.map(lambda n, o: jnp.where(found, n, o), new, belief)
        if ovr:
            newb = binary_update(bb, f, view)
            bb = jax.tree.map(lambda n, o: jnp.where(found, n, o), newb, bb)
        visited = visited.at[view[0], view[1], view[2]].set(
            visited[view[0], view[1], view[2]] | found
        )
        # log p(present | F) of each binary filter (logs: all of them may be tiny)
        p_ovr = (
            jax.vmap(lambda b: logsumexp(B.joint_log_belief(b)[1]))(bb) if ovr else jnp.zeros(n_t)
        )
        out = (view, found, KF.class_marginal(belief), p_ovr)
        return (belief, bb, visited, view), out

    # one-vs-rest runs the binary filters; they have no cross-detector correlation to model
    binary_filter = "instance" if filter == "correlated" else filter
    bb0 = jax.vmap(lambda m: B.init_belief(binary_filter, m))(binary) if ovr else None
    if log_weight is None:
        belief0 = KF.init_belief(filter, model)
    else:
        from scrppl.models.tails import kway_weighted_init

        belief0 = kway_weighted_init(filter, model, log_weight)
    state0 = (belief0, bb0, jnp.zeros(avail_r.shape, bool), start)
    state, first = observe(state0, start, jnp.asarray(True))

    def step(state, j):
        belief, bb, visited, current = state
        view, found, _ = _choose_view(
            jax.random.fold_in(key, j), model, belief, current, visited, avail_r, config
        )
        return observe(state, view.astype(jnp.int32), found)

    n_a = avail_r.shape[0]
    if n_steps < n_a or config.mode != "azimuth" or n_steps < 2:
        _, rest = jax.lax.scan(step, state, jnp.arange(1, n_steps))
        return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)
    # The ring's last view: after A - 1 steps at most one azimuth of the ring is unvisited (none when
    # a step found no available view), so every planner takes it, or finds none; it is taken here
    # without scoring the ring (a seventh of the planner's work when A = 8; the same views).
    state, rest = jax.lax.scan(step, state, jnp.arange(1, n_steps - 1))
    belief, bb, visited, current = state
    views, valid = candidate_views(current, visited, avail_r, "azimuth")
    _, last = observe(state, views[jnp.argmax(valid)].astype(jnp.int32), valid.any())
    return jax.tree.map(lambda a, b, c: jnp.concatenate([a[None], b, c[None]]), first, rest, last)


#: The draw axis of each array of a K-way model (:class:`~scrppl.kway.models.KwayModel`,
#: :class:`~scrppl.kway.correlation.CorrelatedKwayModel`).
_DRAW_AXIS = {"mu": 1, "sigma": 1, "tau": 1, "view_corr": 0, "instance_corr": 0}


def kway_trial_draws(key, model, binary, log_weight, draws_per_trial: int | None):
    """The posterior draws one K-way trial reads: ``draws_per_trial`` of the ``N`` draws, by its key.

    The same draw indices (:func:`scrppl.sim.runner.trial_draw_index` of the trial's key) select the
    K-way model's draws (axis 1 of ``mu``, ``sigma``, ``tau``; axis 0 of a
    :class:`~scrppl.kway.correlation.CorrelatedKwayModel`'s correlation matrices, which are paired with
    them by index), the stacked binary models' (axis 1) and the draws' log weights, so the K-way filter,
    its planner and the one-vs-rest filters of a trial read the same draws of the same fits, and another
    trial other draws. ``None``, or at least ``N``, leaves everything as it is. Traceable.
    """
    from scrppl.sim.runner import trial_draw_index

    idx = trial_draw_index(key, model.mu.shape[1], draws_per_trial)
    if idx is None:
        return model, binary, log_weight
    fields = model._asdict()
    unknown = sorted(set(fields) - set(_DRAW_AXIS))
    if unknown:  # a new kind of model: its draw axes must be named here, not guessed
        raise ValueError(
            f"kway_trial_draws does not know the draw axis of {unknown} ({type(model).__name__})"
        )
    model = type(model)(**{n: jnp.take(x, idx, axis=_DRAW_AXIS[n]) for n, x in fields.items()})
    binary = None if binary is None else jax.tree.map(lambda x: jnp.take(x, idx, axis=1), binary)
    log_weight = None if log_weight is None else jnp.take(log_weight, idx, axis=0)
    return model, binary, log_weight


#: Trials vectorised together inside a chunk (``lax.map``'s ``batch_size``). One at a time: on a 2-core
#: AMD EPYC, 800 paper-regime trials (correlated filter, DPM, M = 256, planning and random views) took
#: 10.2-10.7 CPU-seconds against 12.4-13.0 in batches of 8, and with each trial's own draws
#: (``draws_per_trial``: the trials of a batch then have different models) 11.2-11.5 against 14.3-15.8.
_TRIAL_BATCH = 1


@lru_cache(maxsize=16)
def _runner(filter: str, config: PlannerConfig, n_steps: int, ovr: bool, draws_per_trial=None):
    options = dict(filter=filter, config=config, n_steps=n_steps, ovr=ovr)

    def chunk(key, first, model, binary, responses, available, pose, start, log_weight):
        index = first + jnp.arange(responses.shape[0])
        keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(index)

        def one(args):
            k, r, a, p, s = args
            return _trial(
                k, model, binary, r, a, p, s, log_weight, draws_per_trial=draws_per_trial, **options
            )

        return jax.lax.map(one, (keys, responses, available, pose, start), batch_size=_TRIAL_BATCH)

    return jax.jit(chunk)


def _run(
    key,
    model,
    binary,
    trials,
    filter,
    config,
    n_steps,
    ovr,
    chunk_size,
    progress,
    desc,
    log_weight,
    draws_per_trial=None,
):
    n = trials.category.shape[0]
    chunk = min(int(chunk_size), n)
    run = _runner(filter, config, int(n_steps), bool(ovr), draws_per_trial)
    host = [np.asarray(x) for x in (trials.responses, trials.available, trials.pose, trials.start)]

    def one_chunk(lo: int) -> list[np.ndarray]:
        sel = np.minimum(np.arange(lo, lo + chunk), n - 1)  # the last chunk padded with repeats
        out = run(key, np.int32(lo), model, binary, *(x[sel] for x in host), log_weight)
        keep = min(chunk, n - lo)
        return [np.asarray(x)[:keep] for x in out]

    starts = range(0, n, chunk)
    workers = min(_chunk_threads(), len(starts))
    bar = tqdm(total=len(starts), desc=desc, disable=not progress, leave=False)
    if workers <= 1:
        outs = []
        for lo in starts:
            outs.append(one_chunk(lo))
            bar.update()
    else:
        # each chunk's trials have their own keys (fold_in by trial index), so chunks are independent:
        # running them on several threads (XLA releases the GIL) gives the same arrays in the same order
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            outs = []
            for out in pool.map(one_chunk, starts):
                outs.append(out)
                bar.update()
    bar.close()
    return [np.concatenate(parts) for parts in zip(*outs, strict=True)]


def _chunk_threads() -> int:
    """Threads that run chunks of trials at once: one per core this process may use."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


# ------------------------------------------------------------------------------------------------
# the experiment


def class_metrics(p_class, category, threshold: float = M.CONFIDENCE) -> dict[str, np.ndarray]:
    """Per-step metrics from class probabilities ``(R, S, K)`` and true categories ``(R,)``.

    Returns ``predicted``, ``correct``, ``p_true``, ``class_entropy`` (``(R, S)``, nats) and
    ``views_to_confidence`` ``(R,)`` (first step with ``p_true > threshold``, ``S + 1`` if none).
    """
    p = np.asarray(p_class, np.float64)
    p = p / p.sum(-1, keepdims=True)
    category = np.asarray(category).astype(int)
    p_true = np.take_along_axis(p, category[:, None, None], axis=-1)[..., 0]
    predicted = p.argmax(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        plogp = np.where(p > 0, p * np.log(p), 0.0)
    confident = p_true > threshold
    n_s = p.shape[1]
    return {
        "predicted": predicted,
        "correct": predicted == category[:, None],
        "p_true": p_true,
        "class_entropy": -plogp.sum(-1),
        "views_to_confidence": np.where(confident.any(1), confident.argmax(1) + 1, n_s + 1),
    }


def run_kway_experiment(
    key: jax.Array,
    model: KwayModel,
    trials: KwayTrials,
    *,
    binary: ResponseModel | None = None,
    filter: str = "instance",
    config: PlannerConfig = _CLASS_OBJECTIVE,
    planner: str | None = None,
    n_steps: int | None = None,
    categories: Sequence[str] | None = None,
    keep_probabilities: bool = True,
    chunk_size: int = 160,
    progress: bool = False,
    log_weight=None,
    planned: bool = True,
    temperature: float = 1.0,
    draws_per_trial: int | None = None,
) -> xr.Dataset:
    """Run entropy planning, random views and (given ``binary``) the one-vs-rest baseline on ``trials``.

    Parameters
    ----------
    key
        JAX PRNG key shared by the methods (paired trials).
    model
        The :class:`~scrppl.kway.models.KwayModel` (``T = K`` targets, in category order).
    trials
        From :func:`make_kway_trials`, transformed with the models' transform.
    binary
        The ``T`` binary viewpoint models stacked (arrays with a leading target axis, ``mu (T, N, 2, A, E,
        S)``), for ``one_vs_rest``; omitted: that method is left out.
    filter
        ``"instance"`` or ``"naive_bayes"`` (used by every method), or ``"correlated"`` (a
        :class:`~scrppl.kway.correlation.CorrelatedKwayModel`; one-vs-rest then runs the instance-aware
        binary filters).
    config
        :class:`~scrppl.planning.PlannerConfig` of the entropy planner (its ``planner`` is ignored:
        ``planning`` uses ``planner``, the baselines ``"random"``).
    planner
        The ``planning`` method's planner, one of :data:`ENTROPY_PLANNERS` (default
        :func:`default_planner` of the filter: ``"equicorrelated"`` for the correlated filter,
        ``"collapsed"`` otherwise); recorded in the ``planner_config`` attribute.
    n_steps
        Views per trial (default ``A``).
    categories
        Category names for the coordinates (default: indices).
    keep_probabilities
        Also store ``p_class (method, trial, step, category)``.
    chunk_size
        Trials per compiled call.
    progress
        Progress bars.
    log_weight
        Optional ``(N,)`` log weights of the model's draws, shared by every target: a model with a
        Student-t instance effect, :func:`scrppl.models.tails.kway_student_t_expansion`. Only with the
        instance-aware filter, where the weights are its starting log evidence and its updates and the
        planner are unchanged. The one-vs-rest baseline keeps its Gaussian binary models.
    planned
        Run the ``planning`` method (default); ``False`` runs only random views (and one-vs-rest on
        them), e.g. for a model whose many draws make planning slow.
    temperature
        Report the K-way methods' class probabilities tempered, ``p^(1/T)`` normalised
        (:mod:`scrppl.kway.calibration`; ``T`` fitted on the ``fit`` instances by
        :func:`~scrppl.kway.calibration.fit_temperature`): their ``p_true``, entropy, views to confidence
        and ``p_class``. The predicted category, the filter and the planner are unchanged; one-vs-rest is
        not tempered. Recorded in the ``temperature`` attribute.
    draws_per_trial
        Each trial reads its own ``draws_per_trial`` of the models' ``N`` draws, chosen by its key
        (:func:`kway_trial_draws`: the same draws for the K-way model, its correlations, the binary models
        and ``log_weight``; every method of a trial the same), so the experiment's means average over
        draw sets and its trial intervals cover which draws were read; ``binary`` must then have the
        model's ``N`` draws, draw ``n`` of the same fits. ``None`` (default): every trial reads all ``N``.
        Recorded in the ``draws_per_trial`` attribute (0 for all).

    Returns
    -------
    xarray.Dataset
        ``predicted``, ``correct``, ``p_true``, ``class_entropy``, ``azimuth`` ``(method, trial, step)``,
        ``views_to_confidence`` ``(method, trial)``; the trials' truth along ``trial``.
    """
    check_kway_model(model)
    if filter not in KF.FILTERS:
        raise ValueError(f"unknown filter {filter!r}; expected one of {KF.FILTERS}")
    from scrppl.kway.calibration import _check_temperature, temper

    temperature = _check_temperature(temperature)
    n_t, _, n_k = model.mu.shape[:3]
    if n_t != n_k:
        raise ValueError(
            f"the experiment needs one target detector per category; got T={n_t}, K={n_k}"
        )
    if trials.responses.shape[1:] != (n_t,) + model.grid_shape:
        raise ValueError(
            f"trials have responses of shape {trials.responses.shape[1:]} (T, A, E, S) but the model "
            f"needs {(n_t,) + model.grid_shape}"
        )
    n_a = model.mu.shape[3]
    n_steps = n_a if n_steps is None else int(n_steps)
    if config.mode != "azimuth":
        raise ValueError(
            f"the K-way experiment moves in azimuth on its start ring (mode 'azimuth'), got "
            f"{config.mode!r}"
        )
    if not 1 <= n_steps <= n_a:
        raise ValueError(f"n_steps must lie in 1..{n_a}, got {n_steps}")
    planner = default_planner(filter) if planner is None else planner
    if planner == "equicorrelated" and filter != "correlated":
        raise ValueError(
            f"the equicorrelated planner needs filter 'correlated', got {filter!r} (scrppl.kway.planning)"
        )
    if planner not in ENTROPY_PLANNERS:
        raise ValueError(
            f"unknown planner {planner!r} for the K-way experiment's planning method; expected one of "
            f"{ENTROPY_PLANNERS} (scrppl.kway.experiment)"
        )
    plan = config._replace(planner=planner)
    rand = config._replace(planner="random")
    _check_config(plan)
    if binary is not None and (np.shape(binary.mu)[0] != n_t or np.shape(binary.mu)[2] != 2):
        raise ValueError(
            f"binary models must have shape (T={n_t}, N, 2, A, E, S), got {np.shape(binary.mu)}"
        )
    from scrppl.sim.runner import check_draws_per_trial

    draws_per_trial = check_draws_per_trial(draws_per_trial)
    if draws_per_trial is not None and draws_per_trial >= model.n_draws:
        draws_per_trial = None
    if (
        draws_per_trial is not None
        and binary is not None
        and np.shape(binary.mu)[1] != model.n_draws
    ):
        raise ValueError(
            f"draws_per_trial pairs the binary models' draws with the K-way model's by index: both need "
            f"the same number of draws, got {np.shape(binary.mu)[1]} and {model.n_draws}"
        )
    if log_weight is not None:
        if filter != "instance":
            raise ValueError(
                f"log_weight (weighted draws) needs the instance-aware filter, got filter {filter!r}; "
                f"for naive Bayes use scrppl.models.tails.kway_weighted_naive_bayes_update"
            )
        from scrppl.models.tails import _check_weights

        log_weight = _check_weights(model, log_weight, draw_axis=1)
    dummy = binary if binary is not None else ResponseModel(*(x[:, :, :2] for x in model[:3]))
    opts = dict(
        filter=filter,
        n_steps=n_steps,
        chunk_size=chunk_size,
        progress=progress,
        log_weight=log_weight,
        draws_per_trial=draws_per_trial,
    )
    runs = {}
    if planned:
        runs["planning"] = _run(
            key, model, dummy, trials, config=plan, ovr=False, desc="kway/planning", **opts
        )
    runs["random"] = _run(
        key, model, dummy, trials, config=rand, ovr=binary is not None, desc="kway/random", **opts
    )
    methods = (["planning"] if planned else []) + ["random"]
    methods += ["one_vs_rest"] if binary is not None else []
    cat = np.asarray(trials.category)
    per = {}
    for m in methods:
        views, observed, p_kway, p_ovr = runs["random" if m == "one_vs_rest" else m]
        if m == "one_vs_rest":  # p(present) of the K binary filters, normalised over categories
            p = np.exp(p_ovr - p_ovr.max(-1, keepdims=True))
        else:
            p = p_kway if temperature == 1.0 else temper(p_kway, temperature)
        met = class_metrics(p, cat)
        met["azimuth"] = views[..., 0]
        met["p_class"] = p / p.sum(-1, keepdims=True)
        per[m] = met
    dims = ("method", "trial", "step")
    data = {
        v: (dims, np.stack([per[m][v] for m in methods]))
        for v in ("predicted", "correct", "p_true", "class_entropy", "azimuth")
    }
    data["views_to_confidence"] = (
        dims[:2],
        np.stack([per[m]["views_to_confidence"] for m in methods]),
    )
    if keep_probabilities:
        data["p_class"] = (
            (*dims, "category"),
            np.stack([per[m]["p_class"] for m in methods]).astype(np.float32),
        )
    names = list(categories) if categories is not None else list(range(n_k))
    start = np.asarray(trials.start)
    coords = {
        "method": methods,
        "trial": np.arange(cat.shape[0]),
        "step": np.arange(1, n_steps + 1),
        "category": names,
        "true_category": ("trial", [names[c] for c in cat]),
        "category_index": ("trial", cat),
        "instance": ("trial", np.asarray(trials.instance)),
        "pose": ("trial", np.asarray(trials.pose)),
        "start_azimuth": ("trial", start[:, 0]),
    }
    attrs = {
        "filter": filter,
        "planner_config": json.dumps(plan._asdict()),
        "n_draws": int(model.n_draws),
        "weighted_draws": int(log_weight is not None),
        "draws_per_trial": int(draws_per_trial or 0),
        "confidence_threshold": M.CONFIDENCE,
        "temperature": temperature,
    }
    return xr.Dataset(data, coords=coords, attrs=attrs)


def summarise_kway(ds: xr.Dataset, seed: int = 0, n_boot: int = 1000) -> xr.Dataset:
    """Means over trials with percentile-bootstrap 95% intervals, per method and step.

    Returns ``accuracy``, ``p_true``, ``class_entropy`` ``(method, step)`` and ``views_to_confidence``
    ``(method,)``, each with ``_lo`` and ``_hi``.
    """
    out = {}
    for var, src in (
        ("accuracy", "correct"),
        ("p_true", "p_true"),
        ("class_entropy", "class_entropy"),
        ("views_to_confidence", "views_to_confidence"),
    ):
        res = [
            M.bootstrap_mean(seed, ds[src].sel({"method": m}).values.astype(float), n_boot)
            for m in ds["method"].values
        ]
        dims = ("method",) if var == "views_to_confidence" else ("method", "step")
        for i, suffix in enumerate(("", "_lo", "_hi")):
            out[var + suffix] = (dims, np.stack([r[i] for r in res]))
    return xr.Dataset(out, coords={"method": ds["method"], "step": ds["step"]})


def compare_kway(
    ds: xr.Dataset,
    method: str = "planning",
    baseline: str = "random",
    seed: int = 0,
    n_boot: int = 2000,
) -> dict:
    """Paired differences ``method - baseline`` on the same trials, with bootstrap 95% intervals.

    Returns ``{"accuracy": {"mean", "lo", "hi"} (lists over steps), "p_true": ..., "class_entropy": ...,
    "views_to_confidence": {"mean", "lo", "hi"} (floats)}``.
    """
    names = ds["method"].values.tolist()
    for m in (method, baseline):
        if m not in names:
            raise ValueError(f"method {m!r} is not in the experiment ({names})")
    out = {}
    for var, src in (
        ("accuracy", "correct"),
        ("p_true", "p_true"),
        ("class_entropy", "class_entropy"),
        ("views_to_confidence", "views_to_confidence"),
    ):
        a = ds[src].sel({"method": method}).values.astype(float)
        b = ds[src].sel({"method": baseline}).values.astype(float)
        d, lo, hi = M.paired_bootstrap_difference(seed, a, b, n_boot)
        conv = float if np.ndim(d) == 0 else (lambda x: np.asarray(x).tolist())
        out[var] = {"mean": conv(d), "lo": conv(lo), "hi": conv(hi)}
    return out


def confusion_matrices(ds: xr.Dataset, steps: Sequence[int] = CONFUSION_STEPS) -> xr.DataArray:
    """Row-normalised confusion matrices ``(method, step, true, predicted)`` after the given steps.

    Entry ``[m, j, a, b]`` is the fraction of trials of true category ``a`` that method ``m`` assigned to
    ``b`` after ``steps[j]`` views (NaN rows for a category without trials).
    """
    steps = [int(s) for s in steps if int(s) <= ds.sizes["step"]]
    n_k = ds.sizes["category"]
    truth = ds["category_index"].values
    out = np.zeros((ds.sizes["method"], len(steps), n_k, n_k))
    for i, m in enumerate(ds["method"].values):
        for j, s in enumerate(steps):
            pred = ds["predicted"].sel({"method": m, "step": s}).values
            np.add.at(out[i, j], (truth, pred), 1.0)
    with np.errstate(invalid="ignore"):
        out = out / out.sum(-1, keepdims=True)
    cats = ds["category"].values
    return xr.DataArray(
        out,
        dims=("method", "step", "true", "predicted"),
        coords={"method": ds["method"].values, "step": steps, "true": cats, "predicted": cats},
        name="confusion",
    )


#: Views after which :func:`kway_calibration` measures calibration by default.
CALIBRATION_STEPS = (1, 2, 4)


def kway_calibration(
    ds: xr.Dataset, steps: Sequence[int] = CALIBRATION_STEPS, n_bins: int = 10
) -> xr.Dataset:
    """Calibration of the class probabilities ``p_class`` after the given numbers of views.

    Two expected calibration errors over ``n_bins`` equal-width bins
    (:func:`~scrppl.sim.metrics.expected_calibration_error`), per method and step:

    * ``ece_top`` -- of the top-label probability ``max_k p(k)`` against whether that label is right
      (the reliability of the filter's confidence in its answer);
    * ``ece_classwise`` -- of all ``K`` probabilities of every trial against the one-hot truth.

    and the top-label reliability diagram: ``mean_p``, ``frac`` (NaN in an empty bin) and ``count``
    ``(method, step, bin)``.

    Raises
    ------
    ValueError
        If ``ds`` has no ``p_class`` (run the experiment with ``keep_probabilities=True``).
    """
    if "p_class" not in ds:
        raise ValueError(
            "the experiment kept no class probabilities (p_class); rerun it with keep_probabilities=True"
        )
    steps = [int(s) for s in steps if int(s) <= ds.sizes["step"]]
    methods = ds["method"].values
    truth = ds["category_index"].values
    n_k = ds.sizes["category"]
    shape = (len(methods), len(steps))
    top, classwise = np.zeros(shape), np.zeros(shape)
    diagram = np.zeros((3, *shape, n_bins))
    for i, m in enumerate(methods):
        for j, s in enumerate(steps):
            p = ds["p_class"].sel({"method": m, "step": s}).values.astype(np.float64)
            onehot = np.eye(n_k)[truth]
            conf = p.max(-1)
            right = (p.argmax(-1) == truth).astype(float)
            top[i, j] = M.expected_calibration_error(conf, right, n_bins)
            classwise[i, j] = M.expected_calibration_error(p, onehot, n_bins)
            diagram[:, i, j] = M.reliability(conf, right, n_bins)
    dims = ("method", "step")
    return xr.Dataset(
        {
            "ece_top": (dims, top),
            "ece_classwise": (dims, classwise),
            **{
                name: ((*dims, "bin"), diagram[k])
                for k, name in enumerate(("mean_p", "frac", "count"))
            },
        },
        coords={"method": methods, "step": steps, "bin": np.arange(n_bins)},
    )
