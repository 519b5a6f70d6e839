r"""K-way viewpoint detection models: ``p(f_t | k, a, e, s)`` for every target detector ``t`` of a family.

The paper (Meger et al. 2010) asks "is this a bicycle?": one target category, two classes. To answer
"which of ``K`` categories is this?" the robot runs the ``T`` target detectors of one family (the DPM
trained for bicycle, the one trained for car, ...) at every view and needs, for each detector ``t``, the
distribution of its response given the object's *true category* ``k`` (all ``K`` of them) and view.

The hierarchical model of :mod:`scrppl.models.hierarchical` already holds exactly this. For target ``t``
it writes the response of an instance of category ``k`` as

.. math::

    f = \mu_{1aes} + u + \sigma_{1a}\varepsilon \quad (k = t), \qquad
    f = \mu_{0aes} + \delta_k + u + \sigma_{0a}\varepsilon \quad (k \ne t),

with an instance effect ``u ~ Normal(0, tau_o^2)`` per object and target detector, and the non-target
categories' shifts ``delta_k`` pooled hierarchically (deviations of ``K - 1`` iid ``Normal(0, kappa^2)``
effects from their mean): a detector that confuses two categories has their shifts pulled towards each
other only as far as the data allow, rather than fitting ``K - 1`` unrelated cells. Fitted by NUTS on the
``fit`` split with the same diagnostics gates, it is read here ``K``-way: class index ``k`` of the
returned :class:`~scrppl.models.response.ResponseModel` is category ``k`` with ``tau`` the instance sd
(the category is known, so ``kappa`` is *not* folded in as it is for the binary predictive of a new
category, :mod:`scrppl.models.predictive`). No model code is copied: :func:`fit_kway` calls
:func:`scrppl.models.fit.fit_hierarchical` once per target, and :func:`kway_from_fits` reads the fits
``scrppl fit`` saved.

The limitation this inherits: the non-target categories share one azimuth profile and noise sd per
target, shifted by ``delta_k``; a detector whose response to another category has a viewpoint shape of
its own is modelled by the mean shape of all non-targets.

A second one matters more in practice: the instance effects are Gaussian with an sd ``tau`` learnt from
the few ``fit`` instances, shared by all non-target categories of a target. A held-out instance unlike
every fitted one -- on the book table, a shoe to which the cellphone detector responds about 7.6 fitted
``tau`` above every fitted shoe, with the cellphone's azimuth profile -- is nearly impossible under *every*
category, and the filter, exact and calibrated on data drawn from these models
(``tests/test_kway.py``), then picks between two wrong hypotheses in the far tails of the predictive.
There accuracy can fall as views accumulate (evidence for the wrong category's viewpoint profile grows
with each view), and the outcome depends on which posterior draws represent the tails: with 2 draws per
target the book table's K-way accuracy fell from view 2 to view 4, with 8 it did not. Hence the command's
profiles keep 8 draws; a heavier-tailed instance effect would be the modelling fix.

A third, measured later, matters most: the ``T`` fits are separate, so the K-way filters treat the
detectors' responses as independent given the state, although all of them score the same image. In the
paper regime their residuals correlate about 0.3 from view to view, and with independent detectors the
K-way filter is less accurate than one-vs-rest after one view. :mod:`scrppl.kway.correlation` fits the
correlations and its filter (``filter="correlated"``, the full profile's) is more accurate than
one-vs-rest after 1, 2, 4 and 8 views in ``make reproduce`` (after 8 by +0.024 [+0.020, +0.028]; on
an earlier benchmark run only not behind).

A :class:`KwayModel` is the stack of the ``T`` response models (``O = K`` classes each) with a leading
target axis; :func:`target_model` returns one of them as a plain ``ResponseModel``.
"""

from __future__ import annotations

import json
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl._io import read_netcdf, write_netcdf
from scrppl.models.response import ResponseModel, check_response_model

__all__ = [
    "KwayModel",
    "KwayFit",
    "check_kway_model",
    "target_model",
    "stack_models",
    "kway_response_model",
    "rest_reading",
    "fit_kway",
    "kway_from_fits",
    "diagnostic_failures",
    "save_kway",
    "load_kway",
    "kway_path",
]


class KwayModel(NamedTuple):
    """The ``T`` target detectors' K-way response models, stacked (a JAX pytree).

    Attributes
    ----------
    mu
        Mean response, ``(T, N, K, A, E, S)``: target detector, posterior draw, true category, view.
    sigma
        Within-instance noise sd, ``(T, N, K, A, E, S)``.
    tau
        Instance-effect sd, ``(T, N, K)``.
    """

    mu: jax.Array
    sigma: jax.Array
    tau: jax.Array

    @property
    def n_targets(self) -> int:
        """Number of target detectors ``T``."""
        return self.mu.shape[0]

    @property
    def n_draws(self) -> int:
        """Posterior draws ``N`` per target."""
        return self.mu.shape[1]

    @property
    def n_classes(self) -> int:
        """Number of categories ``K``."""
        return self.mu.shape[2]

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """``(A, E, S)``."""
        return tuple(self.mu.shape[3:6])


def check_kway_model(model: KwayModel) -> None:
    """Raise ``ValueError`` naming the problem unless ``model`` is a well-formed :class:`KwayModel`.

    Shapes ``mu, sigma (T, N, K, A, E, S)``, ``tau (T, N, K)``; each target's slice must pass
    :func:`~scrppl.models.response.check_response_model` (finite, ``sigma > 0``, ``tau >= 0``; values
    only for concrete arrays).
    """
    try:
        mu, sigma, tau = model.mu, model.sigma, model.tau
    except AttributeError:
        raise ValueError(
            f"expected a KwayModel (mu, sigma, tau), got {type(model).__name__}"
        ) from None
    if len(np.shape(mu)) != 6:
        raise ValueError(f"KwayModel.mu must have shape (T, N, K, A, E, S), got {np.shape(mu)}")
    if np.shape(sigma) != np.shape(mu):
        raise ValueError(f"KwayModel.sigma shape {np.shape(sigma)} differs from mu {np.shape(mu)}")
    if np.shape(tau) != np.shape(mu)[:3]:
        raise ValueError(
            f"KwayModel.tau must have shape {np.shape(mu)[:3]} (T, N, K), got {np.shape(tau)}"
        )
    if any(isinstance(x, jax.core.Tracer) for x in (mu, sigma, tau)):
        return
    refs = _CHECKED.get((id(mu), id(sigma), id(tau)))
    if refs is not None and refs[0]() is mu and refs[1]() is sigma and refs[2]() is tau:
        return  # these very (immutable) arrays passed before
    for t in range(np.shape(mu)[0]):
        try:
            check_response_model(ResponseModel(*(np.asarray(x[t]) for x in (mu, sigma, tau))))
        except ValueError as err:
            raise ValueError(f"target detector {t}: {err}") from None
    if all(isinstance(x, jax.Array) for x in (mu, sigma, tau)):
        key = (id(mu), id(sigma), id(tau))

        def forget(_ref, key=key):
            _CHECKED.pop(key, None)

        _CHECKED[key] = tuple(weakref.ref(x, forget) for x in (mu, sigma, tau))


#: K-way models that passed :func:`check_kway_model` (ids of JAX arrays -> weak references), so that a
#: planner checking the same model on every call pays a dictionary look-up (as
#: :func:`scrppl.models.response.check_response_model` does).
_CHECKED: dict[tuple[int, int, int], tuple[weakref.ref, ...]] = {}


def target_model(model: KwayModel, t: int) -> ResponseModel:
    """Target detector ``t``'s response model, ``O = K`` classes (the true categories)."""
    return ResponseModel(model.mu[t], model.sigma[t], model.tau[t])


def stack_models(models: Sequence[ResponseModel], n_draws: int | None = None) -> KwayModel:
    """Stack ``T`` response models with ``O = K`` classes into a :class:`KwayModel`.

    Each is thinned to the common number of draws ``min(n_draws, N_1, .., N_T)`` (evenly spaced); draws
    of different targets come from separate fits and are independent, so aligning them by index is
    only a storage layout.

    Raises
    ------
    ValueError
        If no model is given, or the models differ in classes or view grid.
    """
    models = list(models)
    if not models:
        raise ValueError("stack_models needs at least one response model")
    for m in models:
        check_response_model(m)
    shapes = {tuple(np.shape(m.mu)[1:]) for m in models}
    if len(shapes) != 1:
        raise ValueError(
            f"response models differ in (K, A, E, S): {sorted(shapes)}; a K-way stack needs one "
            "category set and one view grid"
        )
    n = min(m.mu.shape[0] for m in models)
    if n_draws is not None:
        n = max(1, min(n, int(n_draws)))

    def thin(x):
        idx = np.linspace(0, x.shape[0] - 1, n).round().astype(int)
        return jnp.asarray(x)[idx]

    return KwayModel(
        jnp.stack([thin(m.mu) for m in models]),
        jnp.stack([thin(m.sigma) for m in models]),
        jnp.stack([thin(m.tau) for m in models]),
    )


def rest_reading(binary: ResponseModel) -> KwayModel:
    r"""The ``T`` binary viewpoint models read K-way with every non-target category as "absent".

    For target detector ``t`` the response to its own category is the binary model's present class and
    the response to *any* other category is its absent class -- the posterior predictive of a new
    negative from a random non-target category (:func:`scrppl.models.predictive.to_response_model`,
    ``kappa`` folded in), the same for all ``K - 1`` of them:

    .. math::

        p(f_t \mid k, \theta) = p_{\text{present}}(f_t \mid \theta) \ (k = t), \qquad
        p(f_t \mid k, \theta) = p_{\text{absent}}(f_t \mid \theta) \ (k \ne t).

    The K-way filter then multiplies the ``T`` detectors' likelihood ratios present : absent, each
    coupled to the others only through the shared pose; with an absent class that does not vary with the
    view it picks exactly the category of the largest binary posterior odds, the one-vs-rest decision, but
    its class probabilities are one normalised posterior rather than ``T`` separate ones. It is the
    reference a model that knows every category must beat: it uses no category's own response
    (:func:`kway_from_fits` uses the fitted shifts ``delta_k``, :mod:`scrppl.kway.profiles` whole
    per-category profiles), so nothing it says about a held-out instance rests on the few fitted
    instances of the other categories.

    Parameters
    ----------
    binary
        The ``T`` binary models stacked along a leading target axis: ``mu, sigma (T, N, 2, A, E, S)``,
        ``tau (T, N, 2)``, class 0 absent and 1 present, target ``t`` the detector of category ``t``.

    Returns
    -------
    :class:`KwayModel` with ``K = T`` categories.

    Raises
    ------
    ValueError
        If the arrays are not shaped as above (two classes, matching target axes).
    """
    mu, sigma, tau = (jnp.asarray(x) for x in binary)
    if mu.ndim != 6 or mu.shape[2] != 2 or sigma.shape != mu.shape or tau.shape != mu.shape[:3]:
        raise ValueError(
            "rest_reading needs T binary models stacked along a leading axis: mu and sigma of shape "
            f"(T, N, 2, A, E, S) and tau (T, N, 2); got mu {tuple(mu.shape)}, sigma "
            f"{tuple(sigma.shape)}, tau {tuple(tau.shape)}"
        )
    own = jnp.eye(mu.shape[0], dtype=bool)  # (T, K): category k is target t's own

    def read(x: jax.Array) -> jax.Array:
        mask = own.reshape(own.shape[0], 1, own.shape[1], *([1] * (x.ndim - 3)))
        return jnp.where(mask, x[:, :, 1:2], x[:, :, 0:1])

    model = KwayModel(read(mu), read(sigma), read(tau))
    check_kway_model(model)
    return model


def kway_response_model(
    posterior: xr.DataTree, categories: Sequence[str], n_draws: int | None = None
) -> ResponseModel:
    """One target detector's hierarchical fit read K-way: a ``ResponseModel`` with ``O = K`` classes.

    Class ``k`` is ``categories[k]``: the target's own category gets the present class's ``mu, sigma,
    tau``; every other category ``c`` the absent class's, shifted by its fitted category effect
    ``delta_c`` (response scale; see the module docstring). A fit with an instance x azimuth effect
    (``omega``) is read for views on one ring, as :func:`scrppl.models.predictive.to_response_model`
    reads it: noise sd ``sqrt(sigma^2 + omega^2)`` of each class.

    Parameters
    ----------
    posterior
        A fit of :func:`scrppl.models.fit.fit_hierarchical` (or loaded by
        :func:`scrppl.models.io.load_posterior`).
    categories
        The ``K`` categories, in the order of the class axis; must be the fit's target plus its
        non-target categories.
    n_draws
        Keep this many draws, evenly spaced over the pooled chains (default: all).
    """
    from scrppl.models.predictive import category_shifts, draw_index

    if "posterior" not in posterior.children:
        raise ValueError("not a fitted posterior: the DataTree has no 'posterior' group")
    meta = json.loads(posterior.attrs.get("meta", "{}"))
    target = str(posterior.attrs.get("target", meta.get("target", "")))
    negs = [str(c) for c in meta.get("neg_categories", [])]
    categories = [str(c) for c in categories]
    if sorted(categories) != sorted([target, *negs]):
        raise ValueError(
            f"categories {categories} are not the fit's target {target!r} plus its non-target "
            f"categories {negs}"
        )
    post = posterior["posterior"].to_dataset()
    for name in ("mu", "sigma", "tau"):
        if name not in post:
            raise ValueError(
                f"posterior has no {name!r} variable (not written by fit_hierarchical?)"
            )

    def flat(name):
        x = np.asarray(post[name].values, dtype=np.float64)
        return x.reshape((-1,) + x.shape[2:])

    mu2, sigma2, tau2 = flat("mu"), flat("sigma"), flat("tau")  # (N,2,A,E,S), (N,2,A), (N,2)
    if "omega" in post:  # an instance x azimuth effect, read for a ring as the binary model does
        sigma2 = np.sqrt(sigma2**2 + flat("omega")[:, :, None] ** 2)
    n = mu2.shape[0]
    delta = category_shifts(posterior, len(negs))
    k_classes = len(categories)
    mu = np.empty((n, k_classes) + mu2.shape[2:])
    sigma = np.empty_like(mu)
    tau = np.empty((n, k_classes))
    for k, cat in enumerate(categories):
        o = int(cat == target)
        shift = 0.0 if o else delta[:, negs.index(cat)][:, None, None, None]
        mu[:, k] = mu2[:, o] + shift
        sigma[:, k] = sigma2[:, o][:, :, None, None]
        tau[:, k] = tau2[:, o]
    idx = draw_index(n, n_draws)
    if idx is not None:
        mu, sigma, tau = mu[idx], sigma[idx], tau[idx]
    return ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))


class KwayFit(NamedTuple):
    """A family's K-way models with what produced them.

    Attributes
    ----------
    model
        The stacked :class:`KwayModel` (targets in the order of ``categories``).
    info
        ``detector``, ``categories``, ``targets`` (the target detectors, in stack order), ``transform`` and ``diagnostics`` (``{target: report}`` of each
        target's MCMC fit).
    """

    model: KwayModel
    info: dict


def _info(detector: str, categories, trees: dict) -> dict:
    transforms = {str(t.attrs["transform"]) for t in trees.values()}
    if len(transforms) != 1:
        raise ValueError(f"the fits of {detector!r} use different transforms: {sorted(transforms)}")
    return {
        "detector": str(detector),
        "categories": [str(c) for c in categories],
        "targets": [str(t) for t in trees],
        "transform": transforms.pop(),
        "diagnostics": {
            t: json.loads(tree.attrs.get("diagnostics", "{}")) for t, tree in trees.items()
        },
    }


def fit_kway(
    key: jax.Array,
    table: xr.Dataset,
    detector: str,
    config=None,
    *,
    n_draws: int | None = None,
    progress: bool = True,
    azimuth_effect: bool | str = "auto",
) -> tuple[KwayFit, dict[str, xr.DataTree]]:
    """Fit the K-way models of one detector family by NUTS: one hierarchical fit per target detector.

    Target ``j`` (in the table's category order) is fitted with ``jax.random.fold_in(key, j)`` on the
    ``fit`` split by :func:`scrppl.models.fit.fit_hierarchical`; every category must be a target.

    Parameters
    ----------
    key
        JAX PRNG key.
    table
        The response table (:mod:`scrppl.responses`).
    detector
        The family (a name on the table's ``detector`` axis).
    config
        :class:`~scrppl.models.mcmc.SamplerConfig` (default: the package's default sampler).
    n_draws
        Posterior draws kept per target in the stacked model (default: all).
    progress
        Show the sampler's progress bars.
    azimuth_effect
        The instance x azimuth effect of each fit, as ``scrppl fit`` takes it
        (:func:`scrppl.models.study.wants_azimuth_effect`; default ``"auto"``, the pipeline's model: the
        effect where the grid has more than one ring, read for a ring as extra noise).

    Returns
    -------
    fit
        The :class:`KwayFit`.
    posteriors
        ``{target: DataTree}`` of the fits (save them with :func:`scrppl.models.io.save_posterior`).
    """
    from scrppl.models.data import extract_view_data
    from scrppl.models.fit import fit_hierarchical
    from scrppl.models.mcmc import DEFAULT_SAMPLER
    from scrppl.models.study import wants_azimuth_effect

    categories = _categories(table)
    config = DEFAULT_SAMPLER if config is None else config
    trees = {}
    for j, target in enumerate(categories):
        data, meta = extract_view_data(table, detector, target, split="fit")
        trees[target] = fit_hierarchical(
            jax.random.fold_in(key, j), data, meta, config, progress=progress, warn=False,
            azimuth_effect=wants_azimuth_effect(azimuth_effect, data),
        )  # fmt: skip
    model = stack_models([kway_response_model(trees[t], categories) for t in categories], n_draws)
    return KwayFit(model, _info(detector, categories, trees)), trees


def _categories(table: xr.Dataset) -> list[str]:
    categories = [str(c) for c in table["category"].values]
    missing = [c for c in categories if c not in table["target"].values.tolist()]
    if missing:
        raise ValueError(
            f"K-way recognition needs a target detector for every category; the table has none for "
            f"{missing}"
        )
    return categories


def kway_from_fits(
    models_dir: str | Path,
    detector: str,
    categories: Sequence[str],
    n_draws: int | None = None,
) -> KwayFit:
    """The K-way models of one family from the hierarchical fits ``scrppl fit`` saved.

    Reads ``<models_dir>/hierarchical-<detector>-<target>.nc`` for every category (each a target).

    Raises
    ------
    FileNotFoundError
        If a target's fit is missing (run ``scrppl fit``, or fit with :func:`fit_kway`).
    """
    from scrppl.models.io import load_posterior, model_path

    categories = [str(c) for c in categories]
    trees = {
        t: load_posterior(model_path(models_dir, "hierarchical", detector, t)) for t in categories
    }
    model = stack_models([kway_response_model(trees[t], categories) for t in categories], n_draws)
    return KwayFit(model, _info(detector, categories, trees))


def diagnostic_failures(info: dict) -> dict[str, list]:
    """``{target: failures}`` of the target fits whose MCMC diagnostics failed (empty when all pass)."""
    return {
        t: r.get("failures", []) for t, r in info["diagnostics"].items() if not r.get("ok", False)
    }


def kway_path(kway_dir: str | Path, detector: str) -> Path:
    """``<kway_dir>/kway-<detector>.nc``."""
    return Path(kway_dir) / f"kway-{detector}.nc"


def save_kway(path: str | Path, fit: KwayFit) -> Path:
    """Write a :class:`KwayFit` to netCDF atomically (arrays plus ``info`` as attributes)."""
    m = fit.model
    check_kway_model(m)
    cats = [str(c) for c in fit.info["categories"]]
    targets = [str(t) for t in fit.info["targets"]]
    if (len(cats), len(targets)) != (m.n_classes, m.n_targets):
        raise ValueError(
            f"info names {len(cats)} categories and {len(targets)} targets but the model has "
            f"K = {m.n_classes}, T = {m.n_targets}"
        )
    dims = ("target", "draw", "category", "azimuth", "elevation", "scale")
    ds = xr.Dataset(
        {
            "mu": (dims, np.asarray(m.mu)),
            "sigma": (dims, np.asarray(m.sigma)),
            "tau": (dims[:3], np.asarray(m.tau)),
        },
        coords={"category": cats, "target": targets},
        attrs={
            "kind": "kway",
            "detector": str(fit.info["detector"]),
            "transform": str(fit.info["transform"]),
            "info": json.dumps(fit.info),
        },
    )
    return write_netcdf(ds, path)


def load_kway(path: str | Path) -> KwayFit:
    """Load a :class:`KwayFit` written by :func:`save_kway`."""
    ds = read_netcdf(path, "K-way model")
    if ds.attrs.get("kind") != "kway":
        raise ValueError(f"{path} is not a K-way viewpoint model (kind={ds.attrs.get('kind')!r})")
    model = KwayModel(*(jnp.asarray(ds[v].values) for v in ("mu", "sigma", "tau")))
    check_kway_model(model)
    return KwayFit(model, json.loads(ds.attrs["info"]))
