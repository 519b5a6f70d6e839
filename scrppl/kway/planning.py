r"""Choosing the next view for K-way recognition: expected entropy of a *vector* observation.

At every view the ``T`` target detectors respond together, so the observation is the vector
``f = (f_1 .. f_T)`` and the paper's criterion (Meger et al. 2010, eq. 5) becomes

.. math::

    V^* = \arg\min_V \; E_{f \sim p(f | F, V)} \big[ H\big(p(k, \theta | F, f_V)\big) \big],

the expectation over the ``T``-dimensional predictive of :func:`scrppl.kway.filter.predictive_mixture`.
:func:`sampled_expected_entropy` estimates it by plain Monte Carlo: draw ``M`` states ``(k, theta)`` from
the belief, per target a posterior draw (from its weight given the state) and a response from its
Gaussian, update with each response vector (:func:`scrppl.kway.filter.mixture_posterior`) and average
the posterior entropy. Unbiased, standard error ``O(1/sqrt(M))`` whatever ``T``. The same random numbers
serve every candidate view (common random numbers), and the decision is
:func:`scrppl.planning.select_view` with the settings of a :class:`scrppl.planning.PlannerConfig`.

Why not quadrature? The binary planner's reference (:func:`scrppl.planning.quadrature_expected_entropy`)
integrates the 1-D response of every mixture component on ``order`` Gauss-Hermite nodes. A vector
response needs a tensor-product rule: ``order^T`` nodes per component. With ``T = 10`` detectors even a
crude 8-node rule is ``8^10 ≈ 10^9`` posterior updates per component and candidate; sparse grids cut the
exponent but not the growth, and the integrand (an entropy of a posterior over ``K x A`` states) is not
smooth enough for low orders. Monte Carlo's error does not depend on the dimension, so it is the method
here; the brute-force reference of the tests is Monte Carlo with very many samples on a small case.

The exact estimator is slow when the predictive keeps several posterior draws per target: every term of
``log p(f | k, theta)`` is then a log-sum-exp over the ``N`` draws, so one candidate costs ``M T N K A``
exponentials (``256 x 10 x 8 x 80 ≈ 1.6 M``, 13 M for 8 candidates: 7-13 ms per decision on two cores,
``benchmarks/results/kway.json``). The **collapsed** planner replaces, per target and state, the mixture
over the draws by the one Gaussian with the same mean and variance (moment matching,
:func:`collapse_mixture`):

.. math::

    \bar m = \sum_n w_n m_n, \qquad \bar v = \sum_n w_n v_n + \sum_n w_n (m_n - \bar m)^2
    \quad (E[\mathrm{var}] + \mathrm{Var}[\mathrm{mean}]),

``w_n = exp(log_draw[t, n, k, theta])``. Every target's term is then a quadratic in ``f_t`` and the
unnormalised log posterior of all ``M`` samples is two ``(M, T) x (T, K A)`` matrix products: ``O(M T K
A)`` multiply-adds per candidate and no exponential per term (the only exponentials left are the ``M K
A`` of the entropy itself, as with one draw). It approximates only the one-step posterior the planner
scores; the filters stay exact. The collapsed Gaussian keeps each state's predictive location and
spread, and so the separation between categories that the decision turns on; it loses the mixture's
shape (heavier tails, several modes), which matters only when the draws disagree strongly for a state
and a response falls between or beyond them. With one draw per target it *is* the exact planner.

The collapsed planner's responses are still drawn from the exact mixture, with the exact planner's
random numbers (:func:`sample_responses`; ``responses="mixture"`` of
:func:`collapsed_expected_entropy`): the expectation is then taken over the right distribution of
``f`` and only the posterior of each sample is approximated, and the two planners score the same
response vectors (common random numbers), so their difference has little Monte Carlo noise. Drawing
from the collapsed Gaussians instead (``responses="collapsed"``) scores the collapsed model against
itself. Measured on the beliefs that the book profile's trials reached after 1, 2 and 3 views (eight
draws per target, ``M = 4096``, ``benchmarks/results/kway.json``, ``approximation``), responses from the
mixture were the closer: the collapsed expected class entropy was on average about ``2e-4`` nats from the
exact one (``2.5e-4`` with collapsed responses; at most ``0.011``), the two chose the same view in about
nine of ten beliefs where the candidates' exact scores differ by ``0.01`` nats or more (elsewhere the
choice is a near tie), and the view the collapsed planner chose cost on average about ``2e-5`` nats of
exact expected entropy, a tenth or less of what the exact planner's own Monte Carlo noise costs at the
experiment's ``M = 128``. The draws of the samples cost ``M T N`` exponentials once per decision, not
per candidate.

* ``planner="sampled"`` -- the exact entropy planner above (the mixture over the draws kept);
* ``planner="collapsed"`` -- the same with the moment-matched posterior update;
* ``planner="equicorrelated"`` -- for the correlated filter only, over the azimuths of the current ring
  (``mode="azimuth"``): the collapsed planner with each state's collapsed means and variances and one
  correlation shared by every two detectors and every state, the view noise's mean correlation
  (:func:`scrppl.kway.correlation._ring_expected_entropies`): no ``T x T`` covariance per state to build
  or invert. The correlated experiment's default (:data:`scrppl.kway.experiment.CORRELATED_PLANNER`, where
  the measurements are);
* ``planner="random"`` -- a uniformly random unseen view (:func:`scrppl.planning.random_unseen_view`).

Objectives ``"joint"`` ``H(k, theta)``, ``"class"`` ``H(k)``, ``"pose"`` ``H(theta)``; candidate sets
and motion cost as in :mod:`scrppl.planning`.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from scrppl.belief import OBJECTIVES
from scrppl.kway import correlation as CR
from scrppl.kway.filter import (
    VectorMixture,
    check_kway_belief,
    predictive_mixture,
)
from scrppl.kway.models import KwayModel, check_kway_model
from scrppl.planning import (
    MODES,
    PlannerConfig,
    _check_views,
    candidate_views,
    random_unseen_view,
    select_view,
)
from scrppl.views import angular_distance, check_mask_shape

__all__ = [
    "PLANNERS",
    "check_equicorrelated",
    "sample_responses",
    "posterior_entropy",
    "sampled_expected_entropy",
    "collapse_mixture",
    "collapsed_expected_entropy",
    "candidate_mixtures",
    "expected_entropies",
    "choose_view",
]

#: Planners for K-way recognition (quadrature does not scale to a vector response: module docstring).
PLANNERS = ("sampled", "collapsed", "equicorrelated", "random")
#: Where the collapsed planner's responses come from: ``"mixture"`` (the exact predictive, with the exact
#: planner's random numbers) or ``"collapsed"`` (the moment-matched Gaussians); see the module docstring.
RESPONSES = ("mixture", "collapsed")
#: The default settings (:class:`scrppl.planning.PlannerConfig` with its own defaults).
DEFAULT_CONFIG = PlannerConfig()


def _check_config(config: PlannerConfig) -> None:
    if not isinstance(config, PlannerConfig):
        raise ValueError(f"expected a scrppl.planning.PlannerConfig, got {type(config).__name__}")
    if config.planner not in PLANNERS:
        raise ValueError(
            f"planner {config.planner!r} is not available for K-way recognition; expected one of "
            f"{PLANNERS} (quadrature needs order^T nodes for T detectors, see scrppl.kway.planning)"
        )
    if config.objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {config.objective!r}; expected one of {OBJECTIVES}")
    if config.mode not in MODES:
        raise ValueError(f"unknown candidate mode {config.mode!r}; expected one of {MODES}")
    if int(config.n_samples) < 1:
        raise ValueError(f"n_samples must be positive, got {config.n_samples}")


def _components(key: jax.Array, log_state, log_draw, n_samples: int):
    """The random part of a sample: states ``(M,)``, per-target draws ``(M, T)`` and normals ``(M, T)``.

    States by inverse CDF of ``exp(log_state)`` ``(K, A)``, each target's draw by inverse CDF of
    ``exp(log_draw[t, :, k, theta])`` ``(T, N, K, A)``. Both depend only on the belief, not on the view.
    """
    n_t, n_d = log_draw.shape[:2]
    k_state, k_draw, k_eps = jax.random.split(key, 3)
    dtype = log_draw.dtype
    cdf = jnp.cumsum(jnp.exp(log_state.reshape(-1)))
    u = jax.random.uniform(k_state, (n_samples,), dtype)
    state = jnp.minimum(jnp.sum(cdf[:, None] <= u * cdf[-1], axis=0), cdf.shape[0] - 1)
    eps = jax.random.normal(k_eps, (n_samples, n_t), dtype)
    if n_d == 1:
        return state, jnp.zeros((n_samples, n_t), jnp.int32), eps
    w = jnp.exp(log_draw.reshape(n_t, n_d, -1)[:, :, state])  # (T, N, M)
    cdf_d = jnp.cumsum(w, axis=1)
    ud = jax.random.uniform(k_draw, (n_t, n_samples), dtype)
    draw = jnp.sum(cdf_d <= (ud * cdf_d[:, -1])[:, None, :], axis=1)
    return state, jnp.minimum(draw, n_d - 1).T, eps


def _responses(mean, var, state, draw, eps) -> jax.Array:
    """Responses ``(M, T)`` of the drawn components from one candidate's ``mean, var`` ``(T, N, K, A)``."""
    n_t, n_d = mean.shape[:2]
    targets = jnp.arange(n_t)[None, :]
    st = state[:, None]
    m = mean.reshape(n_t, n_d, -1)[targets, draw, st]
    v = var.reshape(n_t, n_d, -1)[targets, draw, st]
    return m + jnp.sqrt(v) * eps


def sample_responses(key: jax.Array, mixture: VectorMixture, n_samples: int) -> jax.Array:
    """``M`` response vectors from the predictive mixture, ``(M, T)``.

    A state ``(k, theta) ~ exp(log_state)``, per target a draw ``n ~ exp(log_draw[t, :, k, theta])``,
    then ``f_t ~ Normal(mean, var)``. The state and draw choices depend only on the belief, so with one
    key every candidate view gets the same states, draws and standard normals (common random numbers).
    """
    state, draw, eps = _components(key, mixture.log_state, mixture.log_draw, n_samples)
    return _responses(mixture.mean, mixture.var, state, draw, eps)


def _log_joint(mixture: VectorMixture, f) -> jax.Array:
    """Unnormalised ``log p(k, theta | F, f)`` for ``f`` ``(M, T)``, as ``(M, K * A)``.

    Each Gaussian term is a quadratic in ``f_t``: ``c + b f_t + a f_t^2`` with ``a = -1/(2 var)``,
    ``b = mean / var``, ``c = log w - mean^2 / (2 var) - log(var) / 2`` (the ``2 pi`` cancels). With one
    draw per target the sum over targets is then two small matrix products.
    """
    n_t, n_d = mixture.mean.shape[:2]
    mean = mixture.mean.reshape(n_t, n_d, -1)
    var = mixture.var.reshape(n_t, n_d, -1)
    a = -0.5 / var
    b = mean / var
    # impossible states (log weight -inf) get a very negative finite constant: no NaN arises
    c = (
        jnp.maximum(mixture.log_draw.reshape(n_t, n_d, -1), -1e30)
        + a * mean**2
        - 0.5 * jnp.log(var)
    )
    log_state = jnp.maximum(mixture.log_state.reshape(-1), -1e30)
    if n_d == 1:
        return log_state + c[:, 0].sum(0) + (f**2) @ a[:, 0] + f @ b[:, 0]
    # The sum over draws is taken relative to ref[t], the largest peak log density of target t's
    # components (an upper bound of every term): one exponential per term and no pass for a maximum.
    # A state whose terms all underflow (more than ~87 nats below that peak) is clamped there: its
    # posterior weight is then negligible but finite, so no NaN arises.
    ref = jnp.max(
        jnp.maximum(mixture.log_draw.reshape(n_t, n_d, -1), -1e30) - 0.5 * jnp.log(var), axis=(1, 2)
    )
    ff = f[:, :, None, None]  # (M, T, 1, 1)
    q = jnp.exp(c - ref[:, None, None] + ff * (b + ff * a)).sum(axis=2)  # (M, T, S)
    tiny = jnp.finfo(q.dtype).tiny
    return log_state + ref.sum() + jnp.log(jnp.maximum(q, tiny)).sum(axis=1)


def _entropy(log_joint, n_classes: int, objective: str) -> jax.Array:
    """Entropy (nats) of ``∝ exp(log_joint)`` ``(M, K * A)`` under the objective, ``(M,)``."""
    shifted = log_joint - jnp.max(log_joint, axis=-1, keepdims=True)
    p = jnp.exp(shifted)
    if objective == "joint":
        z = p.sum(-1)
        return jnp.log(z) - (p * shifted).sum(-1) / z
    p = p.reshape(p.shape[0], n_classes, -1)
    q = p.sum(-1) if objective == "class" else p.sum(-2)
    z = q.sum(-1)
    qlogq = jnp.where(q > 0, q * jnp.log(jnp.where(q > 0, q, 1.0)), 0.0).sum(-1)
    return jnp.log(z) - qlogq / z


@partial(jax.jit, static_argnames=("objective",))
def posterior_entropy(mixture: VectorMixture, f, objective: str = "joint") -> jax.Array:
    """Entropy of ``p(k, theta | F, f)`` for response vectors ``f`` ``(M, T)``; shape ``(M,)``."""
    f = jnp.asarray(f, mixture.mean.dtype)
    if f.ndim != 2 or f.shape[1] != mixture.mean.shape[0]:
        raise ValueError(f"responses must have shape (M, T={mixture.mean.shape[0]}), got {f.shape}")
    return _entropy(_log_joint(mixture, f), mixture.mean.shape[2], objective)


@partial(jax.jit, static_argnames=("n_samples", "objective"))
def sampled_expected_entropy(
    key: jax.Array, mixture: VectorMixture, n_samples: int = 256, objective: str = "joint"
) -> jax.Array:
    """Monte Carlo ``E_f[H(p(k, theta | F, f))]`` for one candidate view (eq. 5 for a vector ``f``).

    ``(1/M) sum_m H(p(. | F, f_m))`` with ``f_m`` from :func:`sample_responses`; unbiased, standard
    error ``O(1/sqrt(M))``.

    Parameters
    ----------
    key
        JAX PRNG key (the same for every candidate: common random numbers).
    mixture
        The candidate's :class:`~scrppl.kway.filter.VectorMixture`.
    n_samples
        ``M``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.

    Returns
    -------
    Scalar, nats.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")
    f = sample_responses(key, mixture, n_samples)
    return _entropy(_log_joint(mixture, f), mixture.mean.shape[2], objective).mean()


def _collapse(w, mixture: VectorMixture) -> VectorMixture:
    """Moment-matched :class:`VectorMixture` with one draw, given the draw weights ``w`` ``(..., T, N, K, A)``.

    ``w`` are normalised here, so that with one draw (``w = 1``) the mean and variance are the component's
    own, bit for bit.
    """
    w = w / w.sum(axis=-3, keepdims=True)
    mean = (w * mixture.mean).sum(axis=-3, keepdims=True)
    var = (w * (mixture.var + (mixture.mean - mean) ** 2)).sum(axis=-3, keepdims=True)
    return VectorMixture(mixture.log_state, jnp.zeros_like(mean), mean, var)


def collapse_mixture(mixture: VectorMixture) -> VectorMixture:
    """Per target and state, the one Gaussian with the mixture's mean and variance (moment matching).

    ``mean = sum_n w_n m_n`` and ``var = sum_n w_n (v_n + (m_n - mean)^2)`` (``E[var] + Var[mean]``) with
    ``w_n = exp(log_draw[..., t, n, k, theta])``; the state weights are kept.

    Parameters
    ----------
    mixture
        A :class:`~scrppl.kway.filter.VectorMixture`, ``log_draw, mean, var`` ``(..., T, N, K, A)``.

    Returns
    -------
    VectorMixture
        ``log_draw`` zeros, ``mean`` and ``var`` ``(..., T, 1, K, A)``; ``log_state`` unchanged.
    """
    return _collapse(jnp.exp(mixture.log_draw), mixture)


@partial(jax.jit, static_argnames=("n_samples", "objective", "responses"))
def collapsed_expected_entropy(
    key: jax.Array,
    mixture: VectorMixture,
    n_samples: int = 256,
    objective: str = "joint",
    responses: str = "mixture",
) -> jax.Array:
    """Monte Carlo expected entropy with the collapsed posterior update (the ``"collapsed"`` planner).

    ``(1/M) sum_m H(q(. | F, f_m))``, ``q`` the posterior under :func:`collapse_mixture`; ``f_m`` from
    :func:`sample_responses` of the exact mixture (``responses="mixture"``, the planner's choice: the
    same response vectors as :func:`sampled_expected_entropy` with the same key) or of the collapsed one
    (``responses="collapsed"``). Cost ``O(M T K A)`` without an exponential per term.

    Parameters
    ----------
    key
        JAX PRNG key.
    mixture
        The candidate's :class:`~scrppl.kway.filter.VectorMixture`.
    n_samples
        ``M``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    responses
        One of :data:`RESPONSES`.

    Returns
    -------
    Scalar, nats.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")
    if responses not in RESPONSES:
        raise ValueError(f"unknown responses {responses!r}; expected one of {RESPONSES}")
    collapsed = collapse_mixture(mixture)
    f = sample_responses(key, mixture if responses == "mixture" else collapsed, n_samples)
    return _entropy(_log_joint(collapsed, f), mixture.mean.shape[2], objective).mean()


def candidate_mixtures(model: KwayModel, belief, views) -> VectorMixture:
    """Predictive mixtures of every candidate view ``(C, 3)``: ``log_state (C, K, A)``, rest ``(C, T, N, K, A)``."""
    views = jnp.asarray(views)
    return jax.vmap(lambda v: predictive_mixture(model, belief, v[0], v[1], v[2]))(views)


def expected_entropies(
    key: jax.Array, model: KwayModel, belief, views, config: PlannerConfig = DEFAULT_CONFIG
) -> jax.Array:
    """Sampled expected posterior entropy of each candidate view ``(C, 3)``, shape ``(C,)``, in nats.

    ``config.planner`` ``"sampled"`` (exact update) or ``"collapsed"`` (moment-matched update, the same
    response vectors).
    """
    _check_config(config)
    check_kway_model(model)
    check_kway_belief(model, belief)
    _check_views(model.mu.shape[3:6], views, "candidate views", ndim=2)
    if config.planner == "random":
        raise ValueError(
            "the random planner scores no view; expected_entropies needs planner 'sampled' or "
            "'collapsed' (scrppl.kway.planning)"
        )
    if config.planner == "equicorrelated":
        raise ValueError(
            "the equicorrelated planner scores the azimuths of the current ring together: use "
            "choose_view (mode 'azimuth', a correlated belief), or planner 'collapsed' here"
        )
    return _expected_entropies(
        key, model, belief, jnp.asarray(views), config.n_samples, config.objective, config.planner
    )


@partial(jax.jit, static_argnames=("n_samples", "objective", "planner"))
def _expected_entropies(key, model, belief, views, n_samples, objective, planner="sampled"):
    """All candidates at once: the states and draws are sampled once (they depend on the belief only).

    ``planner="collapsed"`` scores the same response vectors with the moment-matched update; the draw
    weights are one array for every candidate (the belief's), so their exponentials are taken once.
    """
    if isinstance(belief, CR.CorrelatedBelief):
        return CR._expected_entropies(key, model, belief, views, n_samples, objective, planner)
    mixtures = candidate_mixtures(model, belief, views)
    first = jax.tree.map(lambda x: x[0], mixtures)
    comps = _components(key, first.log_state, first.log_draw, n_samples)
    n_k = model.mu.shape[2]
    w = jnp.exp(first.log_draw) if planner == "collapsed" else None

    def one(mixture):
        f = _responses(mixture.mean, mixture.var, *comps)
        scored = _collapse(w, mixture) if planner == "collapsed" else mixture
        return _entropy(_log_joint(scored, f), n_k, objective).mean()

    return jax.vmap(one)(mixtures)


def choose_view(
    key: jax.Array,
    model: KwayModel,
    belief,
    current,
    visited,
    available,
    config: PlannerConfig = DEFAULT_CONFIG,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view for K-way recognition.

    Parameters
    ----------
    key
        JAX PRNG key.
    model
        The :class:`~scrppl.kway.models.KwayModel`.
    belief
        Either K-way belief (:mod:`scrppl.kway.filter`).
    current
        Current robot view ``(phi, e, s)``.
    visited, available
        Boolean ``(A, E, S)`` masks by robot view (see :func:`scrppl.planning.candidate_views`).
    config
        :class:`scrppl.planning.PlannerConfig`: ``planner`` (one of :data:`PLANNERS`),
        ``objective``, ``mode``, ``n_samples`` (``M``) and ``motion_cost``.

    Returns
    -------
    view
        The chosen view, ``(3,)``.
    found
        ``False`` when no candidate was left.
    scores
        Expected entropy plus cost per candidate (``+inf`` for invalid ones; zeros for ``"random"``).

    Notes
    -----
    With the correlated filter, the collapsed planner and ``mode="azimuth"`` the candidates are scored
    together from one table (:func:`scrppl.kway.correlation._ring_expected_entropies`: the same scores
    to rounding, about a fifth less time); the current azimuth, which the trials always mark visited, is
    then not scored and never chosen.
    """
    _check_config(config)
    check_kway_model(model)
    check_kway_belief(model, belief)
    grid = tuple(model.mu.shape[3:6])
    check_mask_shape(visited, grid, name="visited mask")
    check_mask_shape(available, grid, name="available mask")
    _check_views(grid, current, "current view", ndim=1)
    check_equicorrelated(config, belief)
    return _choose_view(key, model, belief, current, visited, available, config)


def check_equicorrelated(config: PlannerConfig, belief) -> None:
    """Raise ``ValueError`` unless the ``"equicorrelated"`` planner (if chosen) can run here."""
    if config.planner != "equicorrelated":
        return
    if not isinstance(belief, CR.CorrelatedBelief):
        raise ValueError(
            "the equicorrelated planner needs the correlated filter's belief "
            f"(scrppl.kway.correlation), got {type(belief).__name__}; use planner 'collapsed'"
        )
    if config.mode != "azimuth":
        raise ValueError(
            f"the equicorrelated planner scores the azimuths of the current ring (mode 'azimuth'), "
            f"got mode {config.mode!r}"
        )


@partial(jax.jit, static_argnames=("config",))
def _choose_view(key, model, belief, current, visited, available, config):
    views, valid = candidate_views(current, visited, available, config.mode)
    if config.planner == "random":
        idx, found = random_unseen_view(key, valid)
        return views[idx], found, jnp.where(valid, 0.0, jnp.inf)
    if (
        isinstance(belief, CR.CorrelatedBelief)
        and config.planner in ("collapsed", "equicorrelated")
        and config.mode == "azimuth"
    ):
        # every azimuth of the ring from one table (the same scores, about half the time)
        h = CR._ring_expected_entropies(
            key,
            model,
            belief,
            jnp.asarray(current),
            config.n_samples,
            config.objective,
            equicorrelated=config.planner == "equicorrelated",
        )
    else:
        h = _expected_entropies(
            key, model, belief, views, config.n_samples, config.objective, config.planner
        )
    cost = config.motion_cost * angular_distance(
        views[:, 0], jnp.asarray(current)[0], model.mu.shape[3]
    )
    idx, found, scores = select_view(h, cost, valid)
    return views[idx], found, scores
