"""`ResponseModel`: the posterior predictive of a viewpoint detection model, as arrays.

A viewpoint detection model says how a detector's (transformed) response ``f`` is distributed for an
object of class ``o`` seen from relative azimuth ``a``, elevation ``e`` and scale ``s``:
``p(f | o, a, e, s)`` (Meger et al. 2010, Sec. III-A). Every model in scrppl -- the paper's per-view
Gaussian and the hierarchical Bayesian model fitted by MCMC -- is summarised by ``N`` posterior draws of

* ``mu[n, o, a, e, s]``    the class-and-view mean response,
* ``sigma[n, o, a, e, s]`` the within-instance noise standard deviation,
* ``tau[n, o]``            the standard deviation of the instance effect ``u ~ Normal(0, tau)`` that all
  views of one object share,

so that for draw ``n`` and a *new* instance, ``f = mu + u + sigma * eps``. The paper's model is the
special case ``N = 1``, ``tau = 0``.

The belief filters and planners read the per-draw arrays directly (:mod:`scrppl.belief` marginalises
the draws and, for the instance-aware filter, tracks each draw's instance effect with a Kalman update),
with the one Gaussian density :func:`normal_log_density`; :func:`log_prob` and :func:`sample` are the
predictive of a single response, used to check and simulate. Both kinds of model plug into every filter
and planner.

:meth:`ResponseModel.from_profile` builds a small model by hand from a mean response over relative
azimuth (the README's example and the book's first chapters).

Class index convention: ``o = 0`` is "target absent" (negatives), ``o = 1`` "target present".
"""

from __future__ import annotations

import math
import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp

__all__ = [
    "ResponseModel",
    "normal_log_density",
    "log_prob",
    "sample",
    "predictive_moments",
    "check_response_model",
]

_LOG_2PI = math.log(2.0 * math.pi)


class ResponseModel(NamedTuple):
    """Posterior draws of a viewpoint detection model (a JAX pytree).

    Attributes
    ----------
    mu
        Mean response, shape ``(N, O, A, E, S)``.
    sigma
        Within-instance noise sd, shape ``(N, O, A, E, S)``; strictly positive.
    tau
        Instance-effect sd, shape ``(N, O)``; zero for the paper's model.
    """

    mu: jax.Array
    sigma: jax.Array
    tau: jax.Array

    @property
    def n_draws(self) -> int:
        """Number of posterior draws ``N``."""
        return self.mu.shape[0]

    @property
    def n_classes(self) -> int:
        """Number of classes ``O``."""
        return self.mu.shape[1]

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """``(A, E, S)`` of the view grid the model was fitted on."""
        return tuple(self.mu.shape[2:5])

    @classmethod
    def from_profile(cls, present, absent=0.0, sigma=1.0, tau=0.0) -> ResponseModel:
        """A one-draw model at one elevation and scale, from mean responses over relative azimuth.

        Parameters
        ----------
        present
            Mean response of the target class (``o = 1``) at each relative azimuth, shape ``(A,)``.
        absent
            Mean response when the target is absent (``o = 0``): a number or shape ``(A,)``.
        sigma
            Noise sd: a number, or ``(2, A)`` (absent, present) per view.
        tau
            Instance-effect sd: a number or ``(2,)``; ``0`` gives the paper's model.

        Returns
        -------
        ResponseModel
            ``mu``, ``sigma`` of shape ``(1, 2, A, 1, 1)``, ``tau`` of shape ``(1, 2)``.

        Examples
        --------
        >>> m = ResponseModel.from_profile([0.5, 1, 2, 1, 0.5, 1, 2, 1], sigma=0.5)
        >>> m.mu.shape
        (1, 2, 8, 1, 1)
        """
        present = np.asarray(present, dtype=np.float64)
        if present.ndim != 1 or present.size == 0:
            raise ValueError(f"present must be a 1-D profile over azimuth, got shape {present.shape}")
        n_az = present.size
        try:
            mean = np.stack([np.broadcast_to(np.asarray(absent, np.float64), (n_az,)), present])
            sd = np.broadcast_to(np.asarray(sigma, np.float64), (2, n_az))
            inst = np.broadcast_to(np.asarray(tau, np.float64), (2,))
        except ValueError:
            raise ValueError(
                f"absent must be a number or ({n_az},), sigma a number or (2, {n_az}), tau a number or "
                f"(2,); got shapes {np.shape(absent)}, {np.shape(sigma)}, {np.shape(tau)}"
            ) from None
        model = cls(
            jnp.asarray(mean[None, :, :, None, None]),
            jnp.asarray(np.array(sd)[None, :, :, None, None]),
            jnp.asarray(np.array(inst)[None]),
        )
        check_response_model(model)
        return model


def check_response_model(
    model: ResponseModel, grid_shape: tuple[int, int, int] | None = None
) -> None:
    """Raise ``ValueError`` naming the problem if ``model`` is malformed or fitted on another grid.

    Shapes: ``mu`` and ``sigma`` ``(N, O, A, E, S)``, ``tau`` ``(N, O)``. Values: ``mu``, ``sigma``, ``tau``
    finite, ``sigma > 0``, ``tau >= 0``. Shapes are checked always (also on traced arrays, inside ``jit``);
    values only on concrete arrays. A model of JAX arrays (which cannot change) is checked once:
    :data:`_CHECKED` remembers the arrays that passed, so that checking the same model on every call of a
    planner costs a dictionary look-up.

    Parameters
    ----------
    model
        The model to check.
    grid_shape
        If given, the ``(A, E, S)`` the caller's view grid has.
    """
    try:
        mu, sigma, tau = model.mu, model.sigma, model.tau
    except AttributeError:
        hint = (
            ": pass its .response_model" if hasattr(model, "response_model") else ""
        )  # a loaded ViewpointModel
        raise ValueError(
            f"expected a ResponseModel (mu, sigma, tau), got {type(model).__name__}{hint}"
        ) from None
    refs = _CHECKED.get((id(mu), id(sigma), id(tau)))
    if refs is None or refs[0]() is not mu or refs[1]() is not sigma or refs[2]() is not tau:
        _check_shapes(np.shape(mu), np.shape(sigma), np.shape(tau))
        if not any(isinstance(x, jax.core.Tracer) for x in (mu, sigma, tau)):
            _check_values(mu, sigma, tau)
    if grid_shape is not None and tuple(grid_shape) != tuple(np.shape(mu)[2:5]):
        raise ValueError(
            f"response model was fitted on a view grid of shape {tuple(np.shape(mu)[2:5])} (A, E, S) "
            f"but is used with a grid of shape {tuple(grid_shape)}"
        )


#: Models that passed :func:`check_response_model`: the ids of ``(mu, sigma, tau)`` -> weak references
#: to those arrays. Only JAX arrays are remembered (they cannot change); an entry is dropped when one
#: of its arrays is freed, and a look-up also compares the arrays themselves.
_CHECKED: dict[tuple[int, int, int], tuple[weakref.ref, ...]] = {}


def _check_shapes(mu_shape, sigma_shape, tau_shape) -> None:
    if len(mu_shape) != 5:
        raise ValueError(f"ResponseModel.mu must have shape (N, O, A, E, S), got {mu_shape}")
    if sigma_shape != mu_shape:
        raise ValueError(f"ResponseModel.sigma shape {sigma_shape} differs from mu {mu_shape}")
    if tau_shape != mu_shape[:2]:
        raise ValueError(
            f"ResponseModel.tau must have shape {mu_shape[:2]} (N, O), got {tau_shape}"
        )


def _check_values(mu, sigma, tau) -> None:
    arrays = (mu, sigma, tau)
    for name, x in zip(("mu", "sigma", "tau"), arrays, strict=True):
        bad = ~np.isfinite(np.asarray(x))
        if bad.any():
            raise ValueError(
                f"ResponseModel.{name} contains NaN or infinite values (at index "
                f"{tuple(int(i) for i in np.argwhere(bad)[0])} of shape {bad.shape})"
            )
    if np.any(np.asarray(sigma) <= 0):
        raise ValueError(
            "ResponseModel.sigma must be strictly positive (a noise sd), got minimum "
            f"{float(np.min(np.asarray(sigma)))}"
        )
    if np.any(np.asarray(tau) < 0):
        raise ValueError(
            "ResponseModel.tau must be non-negative (an instance-effect sd), got minimum "
            f"{float(np.min(np.asarray(tau)))}"
        )
    if all(isinstance(x, jax.Array) for x in arrays):
        key = (id(mu), id(sigma), id(tau))

        def forget(_ref, key=key):
            _CHECKED.pop(key, None)

        _CHECKED[key] = tuple(weakref.ref(x, forget) for x in arrays)


def _gather(model: ResponseModel, o, a, e, s):
    """Per-draw parameters at the given state/view; leading axis N, then the broadcast shape."""
    o, a, e, s = (jnp.asarray(x) for x in (o, a, e, s))
    shape = jnp.broadcast_shapes(o.shape, a.shape, e.shape, s.shape)
    o, a, e, s = (jnp.broadcast_to(x, shape) for x in (o, a, e, s))
    return model.mu[:, o, a, e, s], model.sigma[:, o, a, e, s], model.tau[:, o]


def normal_log_density(f, mean, var) -> jax.Array:
    """``log Normal(f; mean, var)`` elementwise (arrays broadcast together): the one Gaussian density.

    ``-((f - mean)^2 / var + log var + log 2 pi) / 2``. The response model, both filters of
    :mod:`scrppl.belief` and the detector fusion of :mod:`scrppl.extensions.fusion` use it.
    """
    return -0.5 * ((f - mean) ** 2 / var + jnp.log(var) + _LOG_2PI)


def log_prob(model: ResponseModel, f, o, a, e=0, s=0) -> jax.Array:
    """Posterior-predictive log density of a response from a *new* instance.

    ``log p(f | o, a, e, s) = log (1/N) sum_n Normal(f; mu_n, sqrt(sigma_n^2 + tau_n^2))`` -- the
    instance effect is integrated out in closed form and the draws are mixed.

    Parameters
    ----------
    model
        The response model.
    f
        Response(s), any shape broadcastable with the indices.
    o, a, e, s
        Integer class, relative azimuth, elevation and scale indices (broadcast together with ``f``).

    Returns
    -------
    Array of the broadcast shape of ``f, o, a, e, s``.
    """
    o, a, e, s = (jnp.asarray(x) for x in (o, a, e, s))
    shape = jnp.broadcast_shapes(jnp.shape(f), o.shape, a.shape, e.shape, s.shape)
    mu, sigma, tau = _gather(model, *(jnp.broadcast_to(x, shape) for x in (o, a, e, s)))
    lp = normal_log_density(jnp.broadcast_to(f, shape)[None], mu, sigma**2 + tau**2)
    return logsumexp(lp, axis=0) - math.log(model.mu.shape[0])


def predictive_moments(model: ResponseModel, o, a, e=0, s=0) -> tuple[jax.Array, jax.Array]:
    """Mean and variance of the posterior predictive for a new instance (law of total variance)."""
    mu, sigma, tau = _gather(model, o, a, e, s)
    mean = mu.mean(axis=0)
    var = (sigma**2 + tau**2).mean(axis=0) + mu.var(axis=0)
    return mean, var


def sample(
    key: jax.Array, model: ResponseModel, o, a, e=0, s=0, shape: tuple[int, ...] = ()
) -> jax.Array:
    """Draw responses of *new* instances from the posterior predictive.

    Each sample picks a posterior draw uniformly, an instance effect ``u ~ Normal(0, tau)`` and noise
    ``sigma * eps``. Samples are independent (each from its own new instance).

    Parameters
    ----------
    key
        JAX PRNG key.
    model
        The response model.
    o, a, e, s
        Integer indices, broadcast together to a shape ``B``.
    shape
        Leading sample shape.

    Returns
    -------
    Array of shape ``shape + B``.
    """
    o, a, e, s = (jnp.asarray(x) for x in (o, a, e, s))
    batch = jnp.broadcast_shapes(o.shape, a.shape, e.shape, s.shape)
    out_shape = tuple(shape) + batch
    k_draw, k_u, k_eps = jax.random.split(key, 3)
    n = jax.random.randint(k_draw, out_shape, 0, model.mu.shape[0])
    o, a, e, s = (jnp.broadcast_to(x, out_shape) for x in (o, a, e, s))
    mu = model.mu[n, o, a, e, s]
    sigma = model.sigma[n, o, a, e, s]
    tau = model.tau[n, o]
    return (
        mu
        + tau * jax.random.normal(k_u, out_shape, mu.dtype)
        + sigma * jax.random.normal(k_eps, out_shape, mu.dtype)
    )
