"""How few views a trial could have needed: a clairvoyant bound and the model-optimal reference.

Two yardsticks for the experiment's *views to confidence* (:func:`scrppl.sim.metrics.trial_metrics`:
the first ``k`` with ``p(o* | f_1..f_k) > threshold``, ``K + 1`` if never):

* :func:`clairvoyant_views` / :func:`clairvoyant_bound` -- a planner that *knew every response of the
  trial* in advance: the fewest views, the start view included, after which the method's own filter is
  confident in the true class. An exact filter's posterior after a set of views does not depend on the
  order they were seen in, so the minimum runs over the ``2^(A-1)`` sets of azimuths that contain the
  start view (enumerated, vectorised; sets with a missing view are excluded). No planner of the same
  filter, however lucky, does better on that trial.
* :func:`model_optimal_views` -- the best adaptive policy *under the model* (it knows only what the
  filter knows): the expected views to confidence after each trial's start response, bracketed by
  depth-limited expectimax (:func:`scrppl.confident.optimal_remaining_views`).

"Both filters" are those of :mod:`scrppl.belief`: the paper's naive Bayes and the instance-aware filter;
each bound uses the filter the method runs (:data:`scrppl.belief.FILTERS`). Views are the robot azimuths
at the trial's start elevation and scale (the experiment's ``mode="azimuth"``).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from scrppl import belief as B
from scrppl.confident import RESPONSES, optimal_remaining_views, step_cost
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig
from scrppl.sim.metrics import CONFIDENCE
from scrppl.sim.runner import check_trial_inputs
from scrppl.sim.simulator import Trials, robot_frame

__all__ = ["subset_masks", "clairvoyant_views", "clairvoyant_bound", "model_optimal_views"]


def subset_masks(n_views: int, start) -> jax.Array:
    """Every set of views that contains ``start``, as boolean rows ``(2^(n_views - 1), n_views)``.

    Row ``i`` holds bit ``j`` of ``i`` at view ``(start + 1 + j) mod n_views`` and ``True`` at ``start``
    (``start`` may be a traced integer).
    """
    bits = (np.arange(2 ** (n_views - 1))[:, None] >> np.arange(n_views - 1)) & 1
    others = (jnp.asarray(start) + 1 + jnp.arange(n_views - 1)) % n_views
    masks = jnp.zeros((bits.shape[0], n_views), bool).at[:, others].set(jnp.asarray(bits, bool))
    return masks.at[:, start].set(True)


def _check_filter(filter: str) -> None:
    if filter not in B.FILTERS:
        raise ValueError(f"unknown filter {filter!r}; expected one of {B.FILTERS}")


def _trial_views(responses, available, pose, start):
    """The trial's responses and availability at the start elevation and scale, by robot azimuth."""
    resp_r, avail_r = robot_frame(responses, available, pose)
    return resp_r[:, start[1], start[2]], avail_r[:, start[1], start[2]]


def clairvoyant_views(
    model: ResponseModel,
    responses,
    available,
    pose,
    start,
    label,
    *,
    filter: str = "naive_bayes",
    threshold: float = CONFIDENCE,
    n_steps: int | None = None,
) -> jax.Array:
    """Fewest views (start included) after which the filter is confident in the true class, one trial.

    For each set of azimuths containing the start view (:func:`subset_masks`), the filter is run over
    the set's responses (in azimuth order: an exact filter's posterior does not depend on the order) and
    ``p(o* | F) > threshold`` is checked. Traceable (``vmap`` over trials works).

    Parameters
    ----------
    model
        The response model.
    responses, available
        The trial's object-frame responses and availability, ``(A, E, S)`` (as in :class:`Trials`).
    pose
        Hidden pose ``theta*``.
    start
        Start view ``(phi0, e0, s0)``.
    label
        True class ``o*``.
    filter
        ``"naive_bayes"`` or ``"instance"``.
    threshold
        Confidence threshold.
    n_steps
        Views the trial may take (default ``A``): sets larger than this do not count.

    Returns
    -------
    Integer scalar: the fewest views, or ``n_steps + 1`` if no set of at most ``n_steps`` views makes
    the filter confident (the censoring of :func:`scrppl.sim.metrics.trial_metrics`).
    """
    _check_filter(filter)
    n_a = model.mu.shape[2]
    n_steps = n_a if n_steps is None else int(n_steps)
    start = jnp.asarray(start, jnp.int32)
    f, ok = _trial_views(responses, available, pose, start)
    masks = subset_masks(n_a, start[0])  # (2^(A-1), A)
    e0, s0 = start[1], start[2]

    def posterior_true(mask):
        def step(belief, phi):
            new = B.update(model, belief, f[phi], phi, e0, s0)
            return jax.tree.map(lambda n, o: jnp.where(mask[phi], n, o), new, belief), None

        belief, _ = jax.lax.scan(step, B.init_belief(filter, model), jnp.arange(n_a))
        return B.class_marginal(belief)[label]

    p_true = jax.vmap(posterior_true)(masks)
    size = masks.sum(axis=1)
    allowed = jnp.all(ok | ~masks, axis=1) & (size <= n_steps)
    return jnp.min(jnp.where(allowed & (p_true > threshold), size, n_steps + 1))


def clairvoyant_bound(
    model: ResponseModel,
    trials: Trials,
    *,
    filter: str = "naive_bayes",
    threshold: float = CONFIDENCE,
    n_steps: int | None = None,
    batch_size: int = 16,
) -> np.ndarray:
    """:func:`clairvoyant_views` of every trial, ``(T,)`` integers (compiled, batched over trials).

    A lower bound, per trial, on the views to confidence of any planner with the same filter, model and
    threshold (:func:`scrppl.sim.metrics.trial_metrics`), over trials of ``n_steps`` views.

    Parameters
    ----------
    model
        The response model, on the trials' view grid.
    trials
        The trials (their responses through this model's transform).
    filter, threshold, n_steps
        As in :func:`clairvoyant_views`.
    batch_size
        Trials vectorised together (memory only).
    """
    n_steps = check_trial_inputs(model, trials, PlannerConfig(mode="azimuth"), filter, n_steps)
    out = _clairvoyant_bound(
        model, tuple(trials)[:5], filter=filter, threshold=float(threshold), n_steps=n_steps,
        batch_size=max(1, int(batch_size)),
    )  # fmt: skip
    return np.asarray(out)


@partial(jax.jit, static_argnames=("filter", "threshold", "n_steps", "batch_size"))
def _clairvoyant_bound(model, per_trial, filter, threshold, n_steps, batch_size):
    def one(args):
        resp, avail, label, pose, start = args
        return clairvoyant_views(
            model, resp, avail, pose, start, label, filter=filter, threshold=threshold,
            n_steps=n_steps,
        )  # fmt: skip

    return jax.lax.map(one, per_trial, batch_size=batch_size)


def model_optimal_views(
    model: ResponseModel,
    trials: Trials,
    *,
    filter: str = "naive_bayes",
    key: jax.Array | None = None,
    depth: int = 2,
    response: str = "sampled",
    n_samples: int = 64,
    order: int = 2,
    threshold: float = CONFIDENCE,
    n_steps: int | None = None,
    leaf: str = "horizon",
    n_futures: int = 64,
    progress: bool = False,
) -> np.ndarray:
    """Bracket of the model-optimal expected views to confidence after each trial's start response.

    The best adaptive policy under the filter's own model (it sees only the responses), for the metric
    of :func:`scrppl.sim.metrics.trial_metrics`: ``E[T | f_1] = 1 + s_1 + V`` with ``s_1`` the step cost
    of the start view (:func:`scrppl.confident.step_cost`) and ``V`` the optimal expected remaining
    views, bracketed by depth-limited expectimax (:func:`scrppl.confident.optimal_remaining_views`):
    the truncated views count ``0`` (lower) or ``s`` each (upper). Exact (lower = upper) when
    ``depth >= n_steps - 1``, for the discretised predictive of ``"quadrature"``.

    The bracket is exact for the predictive as discretised; the discretisation adds its own error. The
    step cost jumps where ``p(o | F)`` crosses the threshold, so Gauss-Hermite nodes converge slowly
    (about 0.02 views per step at 24 nodes per component on the test model), and sampled responses have
    a Monte Carlo error and, below the first level, the optimistic bias of a minimum over noisy
    estimates; hence sampling is the default.

    ``leaf="futures"`` narrows the bracket where ``depth`` views do not settle most trials: each leaf of
    the tree draws ``n_futures`` futures of the filter's own model and counts the rest in hindsight
    (lower: the fewest views any policy could need on that future) and in a fixed order (upper: the value
    of a policy). See :func:`scrppl.confident.expected_remaining_views`.

    Cost per trial: ``((A - 1) J)^depth`` responses, ``J = n_samples`` or ``N O A order``.

    Parameters
    ----------
    model
        The response model.
    trials
        The trials (their responses through this model's transform).
    filter
        ``"naive_bayes"`` or ``"instance"``.
    key
        PRNG key of the sampled responses (the same draws for every trial; unused by ``"quadrature"``).
    depth, response, n_samples, order, threshold, leaf, n_futures
        As in :func:`scrppl.confident.expected_remaining_views`.
    n_steps
        Views per trial (default ``A``).
    progress
        A progress bar over the trials.

    Returns
    -------
    ``(T, 2)``: ``[lower, upper]`` expected views to confidence per trial.
    """
    if response not in RESPONSES:
        raise ValueError(f"unknown response expectation {response!r}; expected one of {RESPONSES}")
    n_steps = check_trial_inputs(model, trials, PlannerConfig(mode="azimuth"), filter, n_steps)
    n_a = model.mu.shape[2]
    options = dict(depth=depth, response=response, order=order, n_samples=n_samples, key=key,
                   threshold=threshold, leaf=leaf, n_futures=n_futures)  # fmt: skip
    out = []
    for t in tqdm(range(trials.n_trials), desc="model-optimal", disable=not progress):
        resp, avail, _, pose, start = (np.asarray(x[t]) for x in tuple(trials)[:5])
        f, ok = (np.asarray(x) for x in _trial_views(resp, avail, pose, start))
        phi0, e0, s0 = (int(v) for v in start)
        belief = B.update(model, B.init_belief(filter, model), f[phi0], phi0, e0, s0)
        s1, alive = step_cost(
            B.class_marginal(belief), jnp.ones(model.mu.shape[1], bool), threshold
        )
        views = np.stack([np.arange(n_a), np.full(n_a, e0), np.full(n_a, s0)], axis=1)
        valid = ok & (np.arange(n_a) != phi0)
        lo, hi = optimal_remaining_views(
            model, belief, views, valid, alive=alive, steps_left=n_steps - 1, **options
        )
        out.append([1.0 + float(s1) + float(lo), 1.0 + float(s1) + float(hi)])
    return np.asarray(out)
