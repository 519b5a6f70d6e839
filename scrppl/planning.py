"""Next-view planners: random unseen view and expected-entropy minimisation (Meger et al. 2010, eq. 5).

A planner looks at the current belief over ``(o, theta)`` (either filter of :mod:`scrppl.belief`) and a
set of candidate robot views, and returns the view to visit next.

* ``"random"`` -- a uniformly random candidate (the paper's baseline, Sec. IV-A).
* ``"sampled"`` -- the paper's planner (eq. 5): for each candidate view draw ``M`` pairs
  ``(state, response)`` from the current belief and the posterior predictive, update, and average the
  posterior entropy; take the argmin. The same random numbers are used for every candidate (common
  random numbers), so comparisons between candidates are less noisy than the estimates themselves.
* ``"quadrature"`` -- the expected entropy by Gauss-Hermite quadrature over the 1-D response for each
  component of the predictive mixture: the value the sampled planner converges to as ``M`` grows, up to
  the quadrature error (:func:`quadrature_expected_entropy` states it).
* ``"plug_in"`` -- updates with the *expected* response only. The paper notes that this gives a biased
  estimate of the entropy; it is kept to demonstrate that bias.
* ``"confident"`` -- not an entropy planner: the view that minimises the expected *views to confidence*
  (``p(true class) > 0.95``), by depth-limited expectimax with sampled responses
  (``scrppl.confident``; ``n_samples`` responses per level).
* ``"rollout"`` -- also for views to confidence: each candidate looked at next, then the others in a
  random order, scored over ``n_samples`` sampled futures of the filter's model
  (:func:`scrppl.confident.rollout_scores`).

Objectives (:data:`scrppl.belief.OBJECTIVES`): ``"joint"`` ``H(o, theta)`` (eq. 5), ``"class"`` ``H(o)``
(the quantity of Fig. 5 right) and ``"pose"`` ``H(theta)``.

Candidate sets (``mode``): ``"azimuth"`` -- the paper's setting, every robot azimuth at the current
elevation and scale; ``"all"`` -- every view of the ``A x E x S`` grid. Visited views and views that are
unavailable (missing images) are never candidates. An optional ``motion_cost`` (nats per azimuth bin
travelled, :func:`scrppl.views.angular_distance`) is added to the expected entropy.

Every planner decides by :func:`select_view`: the valid candidate of least expected entropy plus cost.
The settings -- planner, objective, candidate mode, ``M``, quadrature order, motion cost -- travel as one
:class:`PlannerConfig`, checked once where it enters (:func:`check_planner_config`), to
:func:`choose_view`, the trial runner (:func:`scrppl.sim.run_trials`), the experiment and the extensions.

The module reads in the paper's order: candidate sets, the posterior entropy after a response
(:func:`posterior_entropy`), the three estimates of its expectation (:func:`sampled_expected_entropy`
is eq. 5 as written, in a few lines), then scoring all candidates (:func:`expected_entropies`) and the
decision (:func:`select_view`, :func:`choose_view`). For the sampled planner :func:`expected_entropies`
and :func:`choose_view` call a kernel tuned for the CPU (``scrppl._planning_kernel``: the Threefry
hash unrolled, a polynomial ``exp2``, fused scans), which computes the same numbers as
:func:`sampled_expected_entropy` with the same key, for all candidates at once.

Everything is pure JAX: ``jit`` and ``vmap`` over trials work. The predictive distribution of the next
response is the Gaussian mixture of :func:`scrppl.belief.predictive_mixture`, so every planner works with
both the naive-Bayes and the instance-aware filter.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

from scrppl._checks import is_concrete
from scrppl._planning_kernel import _draws, _sample_responses, _sampled_entropies
from scrppl.belief import OBJECTIVES, Mixture, check_belief, predictive_mixture
from scrppl.models.response import ResponseModel, check_response_model
from scrppl.views import angular_distance, check_mask_shape, check_view_array

__all__ = [
    "PLANNERS",
    "ENTROPY_PLANNERS",
    "MODES",
    "PlannerConfig",
    "DEFAULT_PLANNER",
    "candidate_views",
    "random_unseen_view",
    "posterior_entropy",
    "sampled_expected_entropy",
    "quadrature_expected_entropy",
    "plug_in_expected_entropy",
    "candidate_mixtures",
    "expected_entropies",
    "mixture_expected_entropies",
    "predictive_expected_entropies",
    "travel_cost",
    "select_view",
    "choose_view",
    "check_planner_config",
    "check_planner_inputs",
    "check_same_grid",
]

#: Planner names accepted by :func:`choose_view`.
PLANNERS = ("random", "sampled", "quadrature", "plug_in", "confident", "rollout")
#: Planners that score candidates by an expected entropy (all but ``"random"``).
ENTROPY_PLANNERS = ("sampled", "quadrature", "plug_in")
#: Candidate-set modes.
MODES = ("azimuth", "all")


class PlannerConfig(NamedTuple):
    """How the next view is chosen: one value passed to every layer that plans.

    The planning counterpart of :class:`scrppl.models.mcmc.SamplerConfig`: :func:`choose_view`, the
    trial runner, the experiment and the extensions take one ``PlannerConfig`` instead of a row of
    keyword arguments. It is hashable, so it can be a static argument of a compiled function.

    Attributes
    ----------
    planner
        One of :data:`PLANNERS`.
    objective
        The entropy to minimise, one of :data:`scrppl.belief.OBJECTIVES`.
    mode
        Candidate set, one of :data:`MODES`.
    n_samples
        ``M``, the number of ``(state, response)`` draws per candidate of the sampled planner (eq. 5).
    order
        Gauss-Hermite order of the quadrature planner.
    motion_cost
        Nats per azimuth bin travelled, added to each candidate's expected entropy (``0`` disables).
    """

    planner: str = "sampled"
    objective: str = "joint"
    mode: str = "azimuth"
    n_samples: int = 256
    order: int = 32
    motion_cost: float = 0.0


#: The paper's planner (eq. 5) with ``M = 256`` samples: the default of every function that plans.
DEFAULT_PLANNER = PlannerConfig()


def check_planner_config(
    config: PlannerConfig, planners: tuple[str, ...] = PLANNERS
) -> PlannerConfig:
    """Check a :class:`PlannerConfig` where it enters; return it with plain ``int``/``float`` fields.

    Raises ``ValueError`` naming the field: ``planner`` not in ``planners`` (default :data:`PLANNERS`; a
    function that cannot run every planner passes its own), ``objective`` not in
    :data:`scrppl.belief.OBJECTIVES`, ``mode`` not in :data:`MODES`, ``n_samples`` or ``order`` not a
    positive integer, ``motion_cost`` negative or not finite (checked when concrete: a traced cost, inside
    a compiled trial, is checked where the trial runner is called).
    """
    if not isinstance(config, PlannerConfig):
        raise ValueError(f"expected a scrppl.planning.PlannerConfig, got {type(config).__name__}")
    if config.planner not in planners:
        raise ValueError(
            f"PlannerConfig.planner: unknown planner {config.planner!r}; expected one of {planners}"
        )
    if config.objective not in OBJECTIVES:
        raise ValueError(
            f"PlannerConfig.objective: unknown objective {config.objective!r}; expected one of {OBJECTIVES}"
        )
    if config.mode not in MODES:
        raise ValueError(
            f"PlannerConfig.mode: unknown candidate mode {config.mode!r}; expected one of {MODES}"
        )
    for field in ("n_samples", "order"):
        value = getattr(config, field)
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ValueError(f"PlannerConfig.{field} must be a positive integer, got {value!r}")
    cost = config.motion_cost
    if is_concrete(cost):
        try:
            value = float(cost) if np.ndim(cost) == 0 else math.nan
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value) or value < 0:
            raise ValueError(
                f"PlannerConfig.motion_cost must be a finite number >= 0 (nats per azimuth bin), got {cost!r}"
            )
        cost = value
    return config._replace(
        n_samples=int(config.n_samples), order=int(config.order), motion_cost=cost
    )


def _compiled_part(config: PlannerConfig) -> PlannerConfig:
    """The settings compiled into the planner: ``config`` without its motion cost (passed as a value)."""
    return config._replace(motion_cost=0.0)


#: Configs already checked, with their compiled part: a decision in a loop checks its config once.
_CHECKED: dict = {}


def _checked(config, planners: tuple[str, ...] = PLANNERS) -> tuple[PlannerConfig, PlannerConfig]:
    """:func:`check_planner_config` and :func:`_compiled_part`, remembered for hashable configs.

    The field types are part of the key (``True == 1``, but ``n_samples=True`` is refused). A config
    holding a traced motion cost is not hashable and is checked every time (only while tracing).
    """
    try:
        fields = (type(config.n_samples), type(config.order), type(config.motion_cost))
        return _CHECKED[config, planners, fields]
    except (AttributeError, KeyError, TypeError):
        pass
    checked = check_planner_config(config, planners)
    out = (checked, _compiled_part(checked))
    try:
        if len(_CHECKED) < 1024:
            _CHECKED[config, planners, fields] = out
    except TypeError:  # a traced motion cost
        pass
    return out


def _check_objective(objective: str) -> None:
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


def check_same_grid(model: ResponseModel, other: ResponseModel, name: str = "predictive") -> None:
    """Raise ``ValueError`` if ``other`` (a model whose predictive a planner draws from) is on another grid.

    The two models must have the same states, poses and views (``mu.shape[1:]``); their posterior draws
    may differ in number.
    """
    grid, theirs = tuple(model.mu.shape[1:]), tuple(other.mu.shape[1:])
    if grid != theirs:
        raise ValueError(
            f"the {name} model's grid (states, poses, views) {theirs} is not the filter's {grid}"
        )


def check_planner_inputs(
    model: ResponseModel, belief=None, *, views=None, current=None, visited=None, available=None
) -> None:
    """Check what a planner is given; the public planners call this before their compiled code.

    Raises ``ValueError`` naming the problem: a malformed model
    (:func:`~scrppl.models.response.check_response_model`), a belief of another model
    (:func:`~scrppl.belief.check_belief`), candidate ``views`` ``(C, 3)`` or a ``current`` view ``(3,)``
    outside the model's grid, ``visited``/``available`` masks not of the grid's shape ``(A, E, S)``.
    JAX would clamp out-of-range indices and silently score views that do not exist. Shapes are checked
    also while tracing; values only for concrete arrays (inside ``jit`` or ``vmap`` they are skipped).
    Arguments left ``None`` are not checked.
    """
    check_response_model(model)
    if belief is not None:
        check_belief(model, belief)
    grid = tuple(model.mu.shape[2:5])
    if visited is not None:
        check_mask_shape(visited, grid, name="visited mask")
    if available is not None:
        check_mask_shape(available, grid, name="available mask")
    if views is not None:
        _check_views(grid, views, "candidate views", ndim=2)
    if current is not None:
        _check_views(grid, current, "current view", ndim=1)


def _check_views(grid, views, name: str, ndim: int) -> None:
    """``(C, 3)`` candidates (``ndim=2``) or one ``(3,)`` view inside the grid (values when concrete)."""
    concrete = is_concrete(views)
    if concrete:
        views = np.asarray(views)
    shape = np.shape(views)
    if len(shape) != ndim or shape[-1] != 3:
        want = "(C, 3)" if ndim == 2 else "(3,)"
        raise ValueError(f"{name} must have shape {want}, rows (phi, e, s), got {shape}")
    if concrete:
        check_view_array(grid, views, name=name)


# ------------------------------------------------------------------------------------------------
# candidate sets


def candidate_views(
    current, visited, available, mode: str = "azimuth"
) -> tuple[jax.Array, jax.Array]:
    """Candidate robot views and which of them may be chosen.

    Parameters
    ----------
    current
        The robot's current view ``(phi, e, s)``, integer array of shape ``(3,)``.
    visited
        Views already observed, boolean ``(A, E, S)`` indexed by *robot* azimuth.
    available
        Views that can be observed at all (``False`` where the image is missing), boolean ``(A, E, S)``.
    mode
        ``"azimuth"``: the ``A`` robot azimuths at the current elevation and scale (the paper);
        ``"all"``: all ``A * E * S`` views in flat-index order ``(phi * E + e) * S + s``.

    Returns
    -------
    views
        Integer array ``(C, 3)`` of ``(phi, e, s)``; ``C = A`` or ``A * E * S``.
    valid
        Boolean ``(C,)``: not visited and available.
    """
    if len(np.shape(visited)) != 3:
        raise ValueError(f"visited mask must have shape (A, E, S), got {np.shape(visited)}")
    check_mask_shape(available, np.shape(visited), name="available mask", where="the visited mask")
    _check_views(np.shape(visited), current, "current view", ndim=1)
    visited = jnp.asarray(visited, bool)
    available = jnp.asarray(available, bool)
    n_a, n_e, n_s = visited.shape
    current = jnp.asarray(current)
    if mode == "azimuth":
        phi = jnp.arange(n_a)
        e = jnp.broadcast_to(current[1], (n_a,))
        s = jnp.broadcast_to(current[2], (n_a,))
    elif mode == "all":
        grid = np.stack(np.meshgrid(np.arange(n_a), np.arange(n_e), np.arange(n_s), indexing="ij"))
        phi, e, s = (jnp.asarray(g.ravel()) for g in grid)
    else:
        raise ValueError(f"unknown candidate mode {mode!r}; expected one of {MODES}")
    valid = ~visited[phi, e, s] & available[phi, e, s]
    return jnp.stack([phi, e, s], axis=1), valid


def random_unseen_view(key: jax.Array, valid) -> tuple[jax.Array, jax.Array]:
    """The paper's baseline: a uniformly random valid candidate.

    Parameters
    ----------
    key
        JAX PRNG key.
    valid
        Boolean ``(C,)`` mask of candidates.

    Returns
    -------
    index
        Index into the candidates (``0`` when none is valid).
    found
        Whether any candidate was valid.
    """
    valid = jnp.asarray(valid, bool)
    logits = jnp.where(valid, 0.0, -jnp.inf)
    found = valid.any()
    idx = jax.random.categorical(key, jnp.where(found, logits, 0.0))
    return jnp.where(found, idx, 0), found


# ------------------------------------------------------------------------------------------------
# expected posterior entropy for one candidate's predictive mixture


def _state_major_entropy(log_joint, n_classes: int, objective: str) -> jax.Array:
    """Entropy (nats) of ``∝ exp(log_joint)`` over the state axis; ``log_joint`` is ``(O*A, K)``.

    States ``(o, theta)`` lie along the *first* axis and the ``K`` responses along the last, contiguous
    one, so every reduction over states is an elementwise operation on vectors of length ``K`` (this
    layout is several times faster on CPUs than reducing over a short trailing axis). One exponential
    per element: ``H = log Z - sum(p~ l) / Z`` with ``p~ = exp(l - max)``.
    """
    mx = jnp.max(log_joint, axis=0)
    shifted = log_joint - mx  # finite: log_joint is clamped below in _log_joint_after
    pt = jnp.exp(shifted)
    if objective == "joint":
        z = pt.sum(axis=0)
        return jnp.log(z) - (pt * shifted).sum(axis=0) / z
    pt = pt.reshape(n_classes, -1, pt.shape[-1])
    q = pt.sum(axis=1) if objective == "class" else pt.sum(axis=0)
    z = q.sum(axis=0)
    qlogq = jnp.where(q > 0, q * jnp.log(jnp.where(q > 0, q, 1.0)), 0.0).sum(axis=0)
    return jnp.log(z) - qlogq / z


def _log_joint_after(mixture: Mixture, f) -> jax.Array:
    """Unnormalised ``log p(o, theta | F, f)`` for responses ``f`` of shape ``(K,)``, as ``(O*A, K)``.

    The Gaussian log density is written as ``c + a (f - m)^2`` with ``a = -1 / (2 v)`` and
    ``c = log w - log(v) / 2`` computed once per component (the ``2 pi`` constant cancels).
    """
    n = mixture.mean.shape[0]
    mean = mixture.mean.reshape(n, -1, 1)
    var = mixture.var.reshape(n, -1, 1)
    a = -0.5 / var
    # clamp impossible states (log weight -inf) to a very small finite value so that no NaN arises
    c = jnp.maximum(mixture.log_weight.reshape(n, -1, 1) - 0.5 * jnp.log(var), -1e30)
    lp = c + a * (f - mean) ** 2  # (N, O*A, K)
    return lp[0] if n == 1 else logsumexp(lp, axis=0)


@partial(jax.jit, static_argnames=("objective",))
def posterior_entropy(mixture: Mixture, f, objective: str = "joint") -> jax.Array:
    """Entropy of the belief after observing response(s) ``f`` (any shape), shape ``f.shape``.

    The posterior is ``p(o, theta | F, f) ∝ sum_n w[n, o, theta] Normal(f; mean, var)``.
    """
    _check_objective(objective)
    f = jnp.asarray(f, mixture.mean.dtype)
    flat = f.reshape(-1)
    h = _state_major_entropy(_log_joint_after(mixture, flat), mixture.mean.shape[1], objective)
    return h.reshape(f.shape)


@partial(jax.jit, static_argnames=("n_samples", "objective"))
def sampled_expected_entropy(
    key: jax.Array, mixture: Mixture, n_samples: int = 256, objective: str = "joint"
) -> jax.Array:
    """Monte Carlo estimate of ``E_f[H(p(o, theta | F, f))]`` for one candidate view (Meger et al. 2010, eq. 5).

    ``E_f[H] ~ (1/M) sum_m H(p(o, theta | F, f_m))``, ``f_m ~ p(f | F, V)``: draw ``M = n_samples``
    pairs ``(state, response)`` -- a component ``k = (n, o, theta)`` of the predictive mixture (the
    current belief over posterior draw and state), then ``f_m`` from its Gaussian -- update the belief
    with each response and average the posterior entropy. Unbiased; standard error ``O(1/sqrt(M))``.

    The state is drawn by inverse CDF from a uniform, the response from a standard normal, both from
    :mod:`jax.random`. :func:`expected_entropies` and :func:`choose_view` compute the same numbers for all
    candidates at once with a kernel tuned for the CPU (``scrppl._planning_kernel``); with the same key
    it agrees with this function to float32 rounding (``tests/test_planning.py``).

    Parameters
    ----------
    key
        JAX PRNG key (use the same key for every candidate: common random numbers).
    mixture
        The candidate's predictive mixture, arrays ``(N, O, A)``.
    n_samples
        ``M``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.

    Returns
    -------
    Scalar expected entropy in nats.
    """
    _check_objective(objective)
    k_state, k_response = jax.random.split(key)
    log_w, mean, var = (x.ravel() for x in mixture)  # the N * O * A components
    # M states k ~ p(n, o, theta | F): inverse CDF of the mixture weights
    cdf = jnp.cumsum(jnp.exp(log_w))
    u = jax.random.uniform(k_state, (n_samples,), mean.dtype)
    k = jnp.minimum(jnp.searchsorted(cdf, u * cdf[-1], side="right"), cdf.shape[0] - 1)
    # M responses f ~ Normal(mean_k, var_k)
    f = mean[k] + jnp.sqrt(var[k]) * jax.random.normal(k_response, (n_samples,), mean.dtype)
    # update with each response; average the posterior entropy
    return posterior_entropy(mixture, f, objective).mean()


@partial(jax.jit, static_argnames=("objective", "order"))
def quadrature_expected_entropy(
    mixture: Mixture, objective: str = "joint", order: int = 32
) -> jax.Array:
    """Expected posterior entropy by Gauss-Hermite quadrature over the response.

    ``E_f[H] = sum_k w_k integral Normal(f; m_k, v_k) H(f) df`` with ``order`` nodes per mixture component
    ``k = (n, o, theta)``: ``f = m_k + sqrt(2 v_k) x_q``, weights ``w_q / sqrt(pi)``. Cost
    ``O((N O A)^2 * order)``; components are processed one at a time to bound memory.

    Accuracy, measured against a fine-grid integral over ``f`` (``tests/test_planning.py``; class means
    spread by 1-4, beliefs after up to 12 responses). At the default ``order = 32`` the error was below
    5e-4 nats when every noise sd was at least 0.3, and also with sds down to 0.05 for models with several
    posterior draws and an instance effect. For the paper's Gaussian (one draw, ``tau = 0``) with sds down
    to 0.05 it reached 2e-2 nats, and fell only slowly with the order (5e-3 at ``order = 128``, 2e-3 at
    256): a component much narrower than the spacing of the other components' means makes ``H(f)`` change
    in steps of its width, which the nodes placed for the wide components resolve poorly.

    Parameters
    ----------
    mixture
        The candidate's predictive mixture, arrays ``(N, O, A)``.
    objective
        ``"joint"``, ``"class"`` or ``"pose"``.
    order
        Number of Gauss-Hermite nodes per component.

    Returns
    -------
    Scalar expected entropy in nats.
    """
    _check_objective(objective)
    x, w = np.polynomial.hermite.hermgauss(order)
    x = jnp.asarray(x, mixture.mean.dtype)
    w = jnp.asarray(w / math.sqrt(math.pi), mixture.mean.dtype)

    def one(component):
        log_wk, mk, vk = component
        f = mk + jnp.sqrt(2.0 * vk) * x  # (Q,)
        return jnp.exp(log_wk) * jnp.sum(w * posterior_entropy(mixture, f, objective))

    comps = (mixture.log_weight.ravel(), mixture.mean.ravel(), mixture.var.ravel())
    return jax.lax.map(one, comps).sum()


@partial(jax.jit, static_argnames=("objective",))
def plug_in_expected_entropy(mixture: Mixture, objective: str = "joint") -> jax.Array:
    """The biased shortcut: entropy after observing the *expected* response ``E[f]`` only.

    ``E[H(f)] != H(E[f])``; this planner is kept to show the bias that Meger et al. (2010, Sec. III-C)
    avoid by sampling.
    """
    f_bar = jnp.sum(jnp.exp(mixture.log_weight) * mixture.mean)
    return posterior_entropy(mixture, f_bar, objective)


# ------------------------------------------------------------------------------------------------
# choosing a view


def candidate_mixtures(model: ResponseModel, belief, views) -> Mixture:
    """Predictive mixtures for each candidate view, arrays ``(C, N, O, A)`` (``views``: ``(C, 3)``)."""
    check_planner_inputs(model, belief, views=views)
    views = jnp.asarray(views)
    return jax.vmap(lambda v: predictive_mixture(model, belief, v[0], v[1], v[2]))(views)


def expected_entropies(
    key: jax.Array,
    model: ResponseModel,
    belief,
    views,
    config: PlannerConfig = DEFAULT_PLANNER,
) -> jax.Array:
    """Expected posterior entropy (nats) of each candidate view, shape ``(C,)``.

    The sampled planner scores all candidates in one fused kernel with the same draws (common random
    numbers): each value equals :func:`sampled_expected_entropy` of that candidate's mixture with the
    same key.

    Parameters
    ----------
    key
        JAX PRNG key (only used by ``"sampled"``; the same draws serve every candidate).
    model
        The response model.
    belief
        A :class:`~scrppl.belief.NaiveBayesBelief` or :class:`~scrppl.belief.InstanceBelief`.
    views
        Candidate robot views ``(phi, e, s)``, integer ``(C, 3)``.
    config
        The planner (``"sampled"``, ``"quadrature"`` or ``"plug_in"``), the objective, ``M``
        (``n_samples``, sampled) and the Gauss-Hermite ``order`` (quadrature); ``mode`` and
        ``motion_cost`` are not used here.
    """
    _, compiled = _checked(config, ENTROPY_PLANNERS)
    check_planner_inputs(model, belief, views=views)
    return _expected_entropies(key, model, belief, views, compiled)


@partial(jax.jit, static_argnames=("config",))
def _expected_entropies(key, model, belief, views, config: PlannerConfig):
    """:func:`expected_entropies` without the input checks (compiled)."""
    return mixture_expected_entropies(key, candidate_mixtures(model, belief, views), config)


def mixture_expected_entropies(key, mixtures: Mixture, config: PlannerConfig) -> jax.Array:
    """Expected posterior entropy of each of a batch of predictive mixtures (arrays ``(C, N, O, A)``).

    The one place where ``config.planner`` selects the estimate: :func:`sampled_expected_entropy` (by
    the CPU kernel, the same draws for every mixture), :func:`quadrature_expected_entropy` or
    :func:`plug_in_expected_entropy`. The mixtures must share their weights, as the candidates of one
    belief do (:func:`candidate_mixtures`): the sampled planner draws the states once, from the first.
    Traceable, no input checks (the callers check).
    """
    objective = config.objective
    _check_objective(objective)
    if config.planner == "sampled":
        # the predictive weights are the belief over (n, o, theta): the same for every candidate
        u, eps = _draws(key, config.n_samples, mixtures.mean.dtype)
        lw = mixtures.log_weight[0]
        return _sampled_entropies(u, eps, lw, mixtures.mean, mixtures.var, objective)
    if config.planner == "quadrature":
        return jax.vmap(lambda m: quadrature_expected_entropy(m, objective, config.order))(mixtures)
    if config.planner == "plug_in":
        return jax.vmap(lambda m: plug_in_expected_entropy(m, objective))(mixtures)
    raise ValueError(
        f"unknown entropy planner {config.planner!r}; expected one of {ENTROPY_PLANNERS}"
    )


def predictive_expected_entropies(
    key: jax.Array,
    model: ResponseModel,
    belief,
    predictive_model: ResponseModel,
    predictive_belief,
    views,
    n_samples: int = 256,
    objective: str = "joint",
) -> jax.Array:
    """Eq. 5 with the responses drawn from another model: expected entropy of ``belief`` per candidate.

    The sampled planner's estimate (:func:`sampled_expected_entropy`) with its two roles split: the
    ``M`` responses of each candidate come from ``predictive_model``'s predictive under
    ``predictive_belief`` (its filter run on the same responses), and each is scored by the entropy of
    ``belief`` -- the filter whose confidence counts -- updated through ``model``. With the same model and
    belief in both roles it is :func:`expected_entropies`' sampled planner, the same draws (common random
    numbers). What it is for: measuring how much of a planner's loss comes from its predictive being
    wrong, with a predictive fitted on the test objects themselves (the oracle of
    :mod:`scrppl.sim.decomposition`) while the filter and the metric stay the method's.

    Parameters
    ----------
    key
        JAX PRNG key: the same draws serve every candidate.
    model, belief
        The filter whose expected entropy is scored (either filter).
    predictive_model, predictive_belief
        Where the responses are drawn from: a model on the same grid and its filter's belief.
    views
        Candidate robot views ``(phi, e, s)``, integer ``(C, 3)``.
    n_samples, objective
        ``M`` and the entropy (:data:`scrppl.belief.OBJECTIVES`).

    Returns
    -------
    ``(C,)`` expected entropies in nats.
    """
    _check_objective(objective)
    if isinstance(n_samples, bool) or int(n_samples) != n_samples or int(n_samples) < 1:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    check_same_grid(model, predictive_model)
    check_planner_inputs(model, belief, views=views)
    check_planner_inputs(predictive_model, predictive_belief, views=views)
    return _predictive_expected_entropies(
        key, model, belief, predictive_model, predictive_belief, views, int(n_samples), objective
    )


@partial(jax.jit, static_argnames=("n_samples", "objective"))
def _predictive_expected_entropies(
    key, model, belief, predictive_model, predictive_belief, views, n_samples, objective
):
    """:func:`predictive_expected_entropies` without the input checks (compiled)."""
    scored = candidate_mixtures(model, belief, views)
    drawn = candidate_mixtures(predictive_model, predictive_belief, views)
    f = jax.vmap(lambda m: _sample_responses(key, m, n_samples))(drawn)  # (C, M)
    return jax.vmap(lambda m, fc: posterior_entropy(m, fc, objective).mean())(scored, f)


def travel_cost(views, current, motion_cost, n_azimuths: int) -> jax.Array:
    """Motion cost of each candidate, ``motion_cost * angular_distance(phi_V, phi)``, shape ``(C,)``.

    ``motion_cost`` is in nats per azimuth bin travelled (:func:`scrppl.views.angular_distance`, on a
    ring of ``n_azimuths`` bins), the cost term of :func:`select_view`.
    """
    return motion_cost * angular_distance(
        jnp.asarray(views)[:, 0], jnp.asarray(current)[0], n_azimuths
    )


def select_view(expected_entropy, cost, valid) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The decision rule of eq. 5: the valid candidate of least expected entropy plus cost.

    ``V* = argmin_{V valid} E_f[H(p(o, theta | F, f_V))] + cost(V)`` (Meger et al. 2010, eq. 5; the
    cost, e.g. ``motion_cost * angular_distance``, is zero in the paper). Every planner of this package
    and its extensions decides with this function.

    Parameters
    ----------
    expected_entropy
        Score of each candidate, any shape, e.g. ``(C,)`` views or ``(C, D)`` (view, detector) pairs.
    cost
        Cost of each candidate in nats, broadcastable to ``expected_entropy`` (``0.0`` for none).
    valid
        Boolean mask of the candidates that may be chosen, the shape of ``expected_entropy``.

    Returns
    -------
    index
        Flat index of the chosen candidate (into ``scores.ravel()``); ``0`` when none is valid.
    found
        Whether any candidate was valid.
    scores
        ``expected_entropy + cost``, ``+inf`` for invalid candidates.
    """
    valid = jnp.asarray(valid, bool)
    scores = jnp.where(valid, expected_entropy + cost, jnp.inf)
    return jnp.argmin(scores.ravel()), valid.any(), scores


def choose_view(
    key: jax.Array,
    model: ResponseModel,
    belief,
    current,
    visited,
    available,
    config: PlannerConfig = DEFAULT_PLANNER,
    *,
    max_candidates: int | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Choose the next robot view.

    ``V* = argmin_V E_f[H(p(o, theta | F, f_V))] + motion_cost * angular_distance(phi_V, phi)``
    (Meger et al. 2010, eq. 5, with an optional motion cost), or a random unseen view.

    Parameters
    ----------
    key
        JAX PRNG key (the sampled planner's draws, or the random planner's choice).
    model, belief
        The response model and the current belief (either filter).
    current
        Current robot view ``(phi, e, s)``, integer ``(3,)``.
    visited, available
        Boolean ``(A, E, S)`` masks over robot views (see :func:`candidate_views`).
    config
        How to plan (:class:`PlannerConfig`): the planner (:data:`PLANNERS`), the objective
        (:data:`scrppl.belief.OBJECTIVES`), the candidate ``mode`` (:data:`MODES`), ``M`` for
        ``"sampled"``, the Gauss-Hermite order for ``"quadrature"`` and the motion cost in nats per
        azimuth bin travelled (``0`` disables). Checked by :func:`check_planner_config`.
    max_candidates
        An upper bound on the number of valid candidates, known when tracing (e.g. ``C - k`` after
        ``k`` views): only that many are evaluated. The result is the same as without it, as long as
        the bound holds (it is not checked); the trial runner uses it to skip visited views.

    Returns
    -------
    view
        The chosen view ``(phi, e, s)``, integer ``(3,)``.
    found
        ``False`` when no candidate was left (then ``view`` is meaningless and must not be observed).
    scores
        Score of each candidate ``(C,)`` (``+inf`` for invalid ones; zeros for ``"random"``; expected
        remaining views, not nats, for ``"confident"`` and ``"rollout"``).
    """
    # values here, once per call; the shapes of the belief and the masks (known while tracing) are
    # checked when the compiled function is traced, which costs nothing on later calls
    config, compiled = _checked(config)
    check_response_model(model)
    _check_views(model.mu.shape[2:5], current, "current view", ndim=1)
    args = (key, model, belief, current, visited, available, config.motion_cost)
    return _choose_view(*args, config=compiled, max_candidates=max_candidates)


@partial(jax.jit, static_argnames=("config", "max_candidates"))
def _choose_view(
    key, model, belief, current, visited, available, motion_cost, config, max_candidates
):
    """:func:`choose_view` without the input checks (compiled; the motion cost is a traced value)."""
    check_planner_inputs(model, belief, current=current, visited=visited, available=available)
    views, valid = candidate_views(current, visited, available, config.mode)
    if config.planner == "random":
        idx, found = random_unseen_view(key, valid)
        return views[idx], found, jnp.where(valid, 0.0, jnp.inf)
    if config.planner in ("confident", "rollout"):
        # imported here: scrppl.confident imports this module
        from scrppl.confident import _confident_scores, _rollout_scores

        scorer = _confident_scores if config.planner == "confident" else _rollout_scores
        h = scorer(key, model, belief, views, valid, config)
        cost = travel_cost(views, current, motion_cost, model.mu.shape[2])
        idx, found, scores = select_view(h, cost, valid)
        return views[idx], found, scores
    n_c = views.shape[0]
    if max_candidates is not None and max_candidates < n_c:
        # evaluate only the first `max_candidates` valid candidates and scatter the values back
        k = max(int(max_candidates), 1)
        sel = jnp.nonzero(valid, size=k, fill_value=0)[0]
        sel_valid = valid[sel] & (jnp.arange(k) < valid.sum())
        sub = _expected_entropies(key, model, belief, views[sel], config)
        sub = jnp.where(sel_valid, sub, jnp.inf)
        h = jnp.full(n_c, jnp.inf, sub.dtype).at[sel].min(sub)
    else:
        h = _expected_entropies(key, model, belief, views, config)
    cost = travel_cost(views, current, motion_cost, model.mu.shape[2])
    idx, found, scores = select_view(h, cost, valid)
    return views[idx], found, scores
