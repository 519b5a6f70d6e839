"""Checks for the exercises of chapter 5 (hierarchical viewpoint models).

The exercises grow the chapter's toy model, eq. (5.1): responses ``f[i, a]`` of ``I`` instances of one
class, each seen from all ``A`` views,

    f[i, a] = mu[a] + u[i] + sigma * eps[i, a],    u[i] ~ N(0, tau^2),    eps ~ N(0, 1),

with priors ``mu[a] ~ N(0, 2^2)``, ``sigma ~ HalfNormal(1)``, ``tau ~ HalfNormal(1)``. In NumPyro,
``dist.Normal(loc, scale)`` takes a standard deviation: ``u ~ dist.Normal(0, tau)`` is ``N(0, tau^2)``.
Every model is a function ``model(n_instances, n_views, f=None)`` like the chapter's ``toy_model``
(5.2: ``model(o, n_views, f=None)``, with the class ``o[i]`` of each instance).

The references rest on the library's closed-form instance marginal :func:`scrppl.models.instance_log_marginal`
(eq. 5.3 of the chapter):

* 5.1, 5.2 -- a latent-instance model's log joint density follows from the marginal by the identity
  ``p(f_i | u_i) p(u_i) = p(f_i) p(u_i | f_i)``: the posterior of ``u_i`` given the responses of instance
  ``i`` is normal with precision ``1 / tau_i^2 + sum_a 1 / sigma_a^2`` and mean
  ``sum_a (f[i, a] - m[i, a]) / sigma_a^2`` over that precision (the "completing the square" of the
  chapter's derivation); 5.1 has one noise sd per view, 5.2 a mean profile and an instance sd per class;
* 5.3 -- the marginal model's log density is the prior plus the library's marginal of every instance;
* 5.4 -- the non-centred model ``u = tau * u_raw``, ``u_raw ~ N(0, 1)`` has the latent model's log density
  at ``u = tau * u_raw`` plus the log-Jacobian ``I log(tau)``.

Student models are evaluated with :func:`numpyro.infer.util.log_density` at given parameter values.
NumPyro is imported on first use, so that listing the exercises stays light.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from scrppl.exercises._core import (
    Case,
    Mistake,
    call,
    check_function,
    exercise,
    fail,
    require,
)

__all__ = ["check_5_1", "check_5_2", "check_5_3", "check_5_4"]


# -- the library's closed form ----------------------------------------------------------------------
@jax.jit
def _marginal_jit(y, m, sigma, tau):
    from scrppl.models.marginal import instance_log_marginal

    return instance_log_marginal(y, m, sigma, tau, jnp.ones(y.shape, bool))


def _marginal(y, m, sigma, tau) -> np.ndarray:
    """``instance_log_marginal`` of every row of ``y`` ``(I, n)``; ``tau`` ``(I,)``; float64 out."""
    y = np.atleast_2d(np.asarray(y, np.float32))
    args = (np.broadcast_to(np.asarray(x, np.float32), y.shape) for x in (m, sigma))
    tau = np.broadcast_to(np.asarray(tau, np.float32), y.shape[:1])
    return np.asarray(_marginal_jit(y, *args, tau), np.float64)


def _instances_log_joint(f, m, sigma, tau, u) -> float:
    """``sum_i log p(f_i | u_i) p(u_i)`` from the library's marginal and the posterior of each ``u_i``.

    ``f``, ``m`` ``(I, A)`` (``m``: each instance's mean at each view); ``sigma`` a number or ``(A,)``
    (noise sd of each view); ``tau`` ``(I,)`` (each instance's instance-effect sd); ``u`` ``(I,)``.
    """
    f = np.asarray(f, np.float64)
    m = np.broadcast_to(np.asarray(m, np.float64), f.shape)
    sigma = np.broadcast_to(np.asarray(sigma, np.float64), f.shape[1:])
    tau = np.broadcast_to(np.asarray(tau, np.float64), f.shape[:1])
    marginal = _marginal(f, m, sigma, tau)
    w = 1.0 / sigma**2
    precision = 1.0 / tau**2 + w.sum()
    mean = ((f - m) * w).sum(axis=1) / precision
    posterior_u = stats.norm.logpdf(np.asarray(u, np.float64), mean, precision**-0.5)
    return float(marginal.sum() + posterior_u.sum())


def _log_prior(**sites) -> float:
    """The exercises' priors: ``mu ~ N(0, 2^2)``; ``sigma`` and ``tau`` (any shape) ``~ HalfNormal(1)``."""
    out = stats.norm.logpdf(np.asarray(sites.pop("mu"), np.float64), 0.0, 2.0).sum()
    for value in sites.values():
        out += stats.halfnorm.logpdf(np.asarray(value, np.float64)).sum()
    return float(out)


# -- NumPyro models: tracing and log densities ------------------------------------------------------
def _numpyro():
    import numpyro
    import numpyro.distributions as dist

    return numpyro, dist


def _data(args: tuple, with_class: bool) -> tuple[tuple, np.ndarray, tuple]:
    """``(model arguments, f, parameter values)`` of a case's ``args``.

    A case is ``(f, *values)``, the model called as ``model(I, A, f=f)``; with ``with_class`` it is
    ``(o, f, *values)`` and the model is called as ``model(o, A, f=f)``.
    """
    if with_class:
        o, f, *values = args
        return (np.asarray(o), int(np.shape(f)[1])), np.asarray(f), tuple(values)
    f, *values = args
    n_inst, n_views = np.shape(f)
    return (int(n_inst), int(n_views)), np.asarray(f), tuple(values)


def _log_joint(model, model_args: tuple, f, params: dict) -> float:
    """``numpyro.infer.util.log_density`` of ``model(*model_args, f=f)`` at ``params`` (compiled).

    ``f`` and the model's arguments stay concrete NumPy values inside the model (only the parameters
    are traced), so a model may use NumPy on its data or index with ``o``.
    """
    from numpyro import handlers
    from numpyro.infer.util import log_density

    def logp(values):
        return log_density(handlers.seed(model, 0), model_args, {"f": f}, values)[0]

    values = {k: jnp.asarray(v, jnp.float32) for k, v in params.items()}
    return float(jax.jit(logp)(values))


def _model_as_function(model, names: tuple[str, ...], with_class: bool = False):
    """``model`` as a function of a case's ``args``: its log joint density at the parameter values."""

    def logp(*args):
        model_args, f, values = _data(args, with_class)
        return _log_joint(model, model_args, f, dict(zip(names, values, strict=True)))

    return logp


def _sites(model, name: str, case: Case, where: str, with_class: bool) -> tuple[dict, list[str]]:
    """Latent sample sites (name -> shape) and observed sites of the model on ``case``.

    The model is traced abstractly (:func:`jax.eval_shape`): nothing is computed.
    """
    from numpyro import handlers

    model_args, f, _ = _data(case.args, with_class)
    observed: dict[str, bool] = {}

    def run(*_args):
        def values():
            tr = handlers.trace(handlers.seed(model, 0)).get_trace(*model_args, f=f)
            sites = {k: s for k, s in tr.items() if s["type"] == "sample"}
            observed.update({k: bool(s["is_observed"]) for k, s in sites.items()})
            return {k: s["value"] for k, s in sites.items()}

        return jax.eval_shape(values)

    arg_names = ["o", "f"] if with_class else ["f"]
    shapes = call(
        run, name, Case(case.args[: len(arg_names)], case.label), where=where, arg_names=arg_names
    )
    latent = {k: tuple(v.shape) for k, v in shapes.items() if not observed[k]}
    return latent, [k for k, obs in observed.items() if obs]


def _describe_input(case: Case, where: str, with_class: bool) -> str:
    _, f, _ = _data(case.args, with_class)
    return f"on input {where} ({case.label}; f of shape {f.shape})"


#: What each site's shape means, for the messages.
_SHAPE_HINTS = {
    "mu": "one mean per view: sample it in a plate over the views",
    "mu2": "one mean per class and view: sample it in two nested plates, classes (dim=-2) and views "
    "(dim=-1), or with dist.Normal(0.0, 2.0).expand([2, n_views])",
    "sigma": "it is a single number, shared by every instance and view",
    "sigma_view": "one noise sd per view: sample it in the plate over the views, next to mu",
    "tau": "it is a single number, shared by every instance",
    "tau2": "one instance sd per class: sample it in a plate over the 2 classes (or with .expand([2]))",
    "u": "one value per instance: sample it in a plate over the instances",
}


def _check_sites(
    model, name: str, cases: list[Case], expected, with_class: bool = False, free: int = 0
) -> list[str | None]:
    """Fail unless ``model`` has the expected latent sites (and ``free`` extra ones of shape (I,)).

    ``expected(I, A)`` gives ``{site: (shape, hint key)}``. Returns, per case, the name of the extra
    site (the non-centred exercise lets the student name it).
    """
    require(model, name)
    if not callable(model):
        fail(
            f"`{name}` should be a NumPyro model (a function like toy_model), but it is {model!r}."
        )
    extras = []
    for i, case in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        latent, observed = _sites(model, name, case, where, with_class)
        _, f, _ = _data(case.args, with_class)
        n_inst, n_views = f.shape
        want = expected(n_inst, n_views)
        at = _describe_input(case, where, with_class)
        if "f" in latent:
            fail(
                f"`{name}` samples 'f' as a latent variable {at}: the responses are data, so pass "
                "them as numpyro.sample('f', ..., obs=f)."
            )
        for site, (shape, hint) in want.items():
            if site not in latent:
                fail(
                    f"`{name}` has no latent sample site named {site!r} {at}; its latent sites are "
                    f"{sorted(latent)}. Name the sites exactly as the exercise says."
                )
            if latent[site] != shape:
                fail(
                    f"`{name}`: the site {site!r} has shape {latent[site]} {at}, expected {shape}: "
                    f"{_SHAPE_HINTS[hint]}."
                )
        others = sorted(set(latent) - set(want))
        if len(others) != free:
            if free == 0:
                fail(
                    f"`{name}` has latent sites the model does not have {at}: {others}. "
                    f"Its only latent sites are {sorted(want)}."
                )
            fail(
                f"`{name}` should have exactly one latent site besides {sorted(want)} (the "
                f"standardised instance effects, one per instance) {at}; it has {others}."
            )
        if free:
            (extra,) = others
            if latent[extra] != (n_inst,):
                fail(
                    f"`{name}`: the standardised instance effects {extra!r} have shape "
                    f"{latent[extra]} {at}, expected ({n_inst},): one per instance."
                )
            extras.append(extra)
        else:
            extras.append(None)
        if not observed:
            fail(
                f"`{name}` has no observed site {at}: the responses f must enter the model, e.g. "
                "through numpyro.sample('f', ..., obs=f)."
            )
    return extras


def _simulated(seed: int, n_inst: int, n_views: int, rng=None):
    """A data set ``f (I, A)`` from the toy model, and parameter values near its truth."""
    rng = np.random.default_rng(seed) if rng is None else rng
    mu_true = rng.normal(0.0, 1.0, n_views)
    f = mu_true + 0.6 * rng.normal(size=(n_inst, 1)) + 0.5 * rng.normal(size=(n_inst, n_views))
    mu = (mu_true + 0.3 * rng.normal(size=n_views)).round(3)
    return f.round(3), mu, rng


#: Data shapes of the cases: two only, as every new shape compiles the model anew.
_SHAPES = (
    (53, (4, 8), 0.5, "4 instances x 8 views"),
    (54, (4, 8), 0.05, "4 instances x 8 views, a small tau"),
    (55, (3, 5), 1.2, "3 instances x 5 views, a large tau"),
)


def _model_cases(with_u: bool, sigma_per_view: bool = False) -> list[Case]:
    """Cases ``(f, mu, sigma, tau[, u])`` (including a small tau: the funnel's neck)."""
    out = []
    for seed, (n_inst, n_views), tau, label in _SHAPES:
        f, mu, rng = _simulated(seed, n_inst, n_views)
        if sigma_per_view:
            sigma = rng.uniform(0.3, 1.0, n_views).round(3)
        else:
            sigma = round(float(rng.uniform(0.3, 1.0)), 3)
        args = (f, mu, sigma, tau)
        if with_u:
            args += (rng.normal(0.0, 1.0, n_inst).round(3),)
        out.append(Case(args, f"{label}, seed={seed}"))
    return out


def _check_model(model, name, reference, cases, names, mistakes, hint, with_class=False) -> int:
    """Compare the log density of ``model`` at every case's parameters with ``reference``."""
    return check_function(
        _model_as_function(model, names, with_class),
        reference,
        cases,
        name=f"the log density of {name}",
        rtol=1e-4,
        atol=2e-3,
        mistakes=mistakes,
        hint=hint,
    )


# -- the chapter's toy model, and wrong versions of it ----------------------------------------------
def _toy_model(n_instances, n_views, f=None, sigma_site="shared", u_scale_power=1):
    """The chapter's ``toy_model``; ``sigma_site`` "view" gives 5.1's model (or "instance", a mistake)."""
    numpyro, dist = _numpyro()
    with numpyro.plate("view", n_views):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
        if sigma_site == "view":
            sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    if sigma_site == "shared":
        sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    with numpyro.plate("instance", n_instances):
        u = numpyro.sample("u", dist.Normal(0.0, tau**u_scale_power))
        if sigma_site == "instance":
            sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    scale = sigma[:, None] if sigma_site == "instance" else sigma
    with numpyro.plate("instance", n_instances, dim=-2), numpyro.plate("view", n_views, dim=-1):
        numpyro.sample("f", dist.Normal(mu + u[:, None], scale), obs=f)


# -- 5.1 one noise sd per view ----------------------------------------------------------------------
def _per_view_model(n_instances, n_views, f=None):
    _toy_model(n_instances, n_views, f, sigma_site="view")


def _per_view_variance_scale(n_instances, n_views, f=None):
    _toy_model(n_instances, n_views, f, sigma_site="view", u_scale_power=2)


def _per_instance_sigma(n_instances, n_views, f=None):
    _toy_model(n_instances, n_views, f, sigma_site="instance")


def _per_view_ref(f, mu, sigma, tau, u):
    """Log joint density of the toy model with one noise sd per view (exercise 5.1)."""
    f = np.asarray(f, np.float64)
    n_inst = f.shape[0]
    return _log_prior(mu=mu, sigma=sigma, tau=tau) + _instances_log_joint(
        f, np.broadcast_to(mu, f.shape), sigma, np.full(n_inst, tau), u
    )


_TOY_SITES = ("mu", "sigma", "tau", "u")
_PER_VIEW_MISTAKES = [
    Mistake(
        "dist.Normal takes a standard deviation: u[i] ~ N(0, tau^2) is dist.Normal(0.0, tau), not "
        "dist.Normal(0.0, tau**2).",
        _model_as_function(_per_view_variance_scale, _TOY_SITES),
    ),
]


@exercise(
    "5.1",
    "One noise sd per view",
    "easy",
    reference=lambda: (_per_view_model,),
    wrong=lambda: [(_per_view_variance_scale,), (_per_instance_sigma,), (_toy_model,)],
)
def check_5_1(per_view_model) -> str:
    """Check exercise 5.1.

    ``per_view_model(n_instances, n_views, f=None)`` must have the latent sites ``mu (A,)``,
    ``sigma (A,)``, ``tau ()`` and ``u (I,)``; its log joint density at given values is compared with
    the prior plus :func:`scrppl.models.instance_log_marginal` (one sd per view) plus the log posterior
    density of ``u`` (the module docstring gives the identity).
    """
    cases = _model_cases(with_u=True, sigma_per_view=True)
    _check_sites(
        per_view_model,
        "per_view_model(n_instances, n_views, f)",
        cases,
        lambda n_inst, n_views: {
            "mu": ((n_views,), "mu"),
            "sigma": ((n_views,), "sigma_view"),
            "tau": ((), "tau"),
            "u": ((n_inst,), "u"),
        },
    )
    n = _check_model(
        per_view_model,
        "per_view_model(n_instances, n_views, f)",
        _per_view_ref,
        cases,
        _TOY_SITES,
        _PER_VIEW_MISTAKES,
        "only sigma changes from the chapter's toy_model: sigma[a] ~ HalfNormal(1) in the plate over "
        "the views, and f[i, a] ~ N(mu[a] + u[i], sigma[a]^2).",
    )
    return (
        f"its log density agrees with the library's closed-form instance marginal on {n} data sets"
    )


# -- 5.2 two classes --------------------------------------------------------------------------------
def _class_model(o, n_views, f=None, kind="right"):
    """The two-class latent model (``kind="right"``), or wrong versions of it."""
    numpyro, dist = _numpyro()
    o = np.asarray(o)
    with numpyro.plate("class", 2, dim=-2), numpyro.plate("view", n_views, dim=-1):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    if kind == "shared_tau":
        tau_i = numpyro.sample("tau", dist.HalfNormal(1.0))
    else:
        with numpyro.plate("class", 2):
            tau = numpyro.sample("tau", dist.HalfNormal(1.0))
        tau_i = tau[o] ** 2 if kind == "variance" else tau[o]
    rows = mu[1 - o] if kind == "swapped" else mu[o]
    with numpyro.plate("instance", len(o)):
        u = numpyro.sample("u", dist.Normal(0.0, tau_i))
    with numpyro.plate("instance", len(o), dim=-2), numpyro.plate("view", n_views, dim=-1):
        numpyro.sample("f", dist.Normal(rows + u[:, None], sigma), obs=f)


def _class_variance_scale(o, n_views, f=None):
    _class_model(o, n_views, f, kind="variance")


def _class_swapped(o, n_views, f=None):
    _class_model(o, n_views, f, kind="swapped")


def _class_shared_tau(o, n_views, f=None):
    _class_model(o, n_views, f, kind="shared_tau")


def _class_ref(o, f, mu, sigma, tau, u):
    """Log joint density of the two-class latent model (exercise 5.2)."""
    o = np.asarray(o)
    mu, tau = np.asarray(mu, np.float64), np.asarray(tau, np.float64)
    return _log_prior(mu=mu, sigma=sigma, tau=tau) + _instances_log_joint(
        f, mu[o], sigma, tau[o], u
    )


def _class_cases() -> list[Case]:
    """Cases ``(o, f, mu (2, A), sigma, tau (2,), u)``: classes mixed, and one class only."""
    out = []
    for seed, o, label in (
        (56, [1, 0, 0, 1, 0], "3 negatives and 2 positives"),
        (57, [0, 1, 1, 1, 0], "2 negatives and 3 positives, a small tau for the positives"),
        (58, [1, 1, 1, 1, 1], "positives only"),
    ):  # one shape only: every new shape compiles the model anew
        rng = np.random.default_rng(seed)
        o = np.asarray(o)
        n_views = 8
        profile = rng.normal(0.0, 1.0, (2, n_views))
        f = (
            profile[o]
            + 0.6 * rng.normal(size=(len(o), 1))
            + 0.5 * rng.normal(size=(len(o), n_views))
        )
        mu = (profile + 0.3 * rng.normal(size=(2, n_views))).round(3)
        sigma = round(float(rng.uniform(0.3, 1.0)), 3)
        tau = np.array([0.7, 0.05 if seed == 57 else 0.4])
        u = rng.normal(0.0, 1.0, len(o)).round(3)
        out.append(Case((o, f.round(3), mu, sigma, tau, u), f"{label}, seed={seed}"))
    return out


_CLASS_SITES = ("mu", "sigma", "tau", "u")
_CLASS_MISTAKES = [
    Mistake(
        "dist.Normal takes a standard deviation: u[i] ~ N(0, tau[o[i]]^2) is "
        "dist.Normal(0.0, tau[o]), not dist.Normal(0.0, tau[o]**2).",
        _model_as_function(_class_variance_scale, _CLASS_SITES, with_class=True),
    ),
    Mistake(
        "class o = 1 is 'present': an instance of class o[i] uses row o[i] of mu, mu[o] "
        "(here the rows are swapped).",
        _model_as_function(_class_swapped, _CLASS_SITES, with_class=True),
    ),
]


@exercise(
    "5.2",
    "Two classes",
    "medium",
    reference=lambda: (_class_model,),
    wrong=lambda: [(_class_variance_scale,), (_class_swapped,), (_class_shared_tau,)],
)
def check_5_2(class_model) -> str:
    """Check exercise 5.2.

    ``class_model(o, n_views, f=None)`` must have the latent sites ``mu (2, A)``, ``sigma ()``,
    ``tau (2,)`` and ``u (I,)``; its log joint density at given values is compared with the prior plus
    :func:`scrppl.models.instance_log_marginal` (each instance with its class's means and instance sd)
    plus the log posterior density of ``u``.
    """
    cases = _class_cases()
    name = "class_model(o, n_views, f)"
    _check_sites(
        class_model,
        name,
        cases,
        lambda n_inst, n_views: {
            "mu": ((2, n_views), "mu2"),
            "sigma": ((), "sigma"),
            "tau": ((2,), "tau2"),
            "u": ((n_inst,), "u"),
        },
        with_class=True,
    )
    n = _check_model(
        class_model,
        name,
        _class_ref,
        cases,
        _CLASS_SITES,
        _CLASS_MISTAKES,
        "check the priors (mu[c, a] ~ N(0, 2^2), sigma and tau[c] ~ HalfNormal(1)), "
        "u[i] ~ N(0, tau[o[i]]^2) and f[i, a] ~ N(mu[o[i], a] + u[i], sigma^2).",
        with_class=True,
    )
    return (
        f"its log density agrees with the library's closed-form instance marginal on {n} data sets"
    )


# -- 5.3 the marginal model -------------------------------------------------------------------------
def _marginal_model(n_instances, n_views, f=None, kind="mvn"):
    """The marginal model (``kind="mvn"``), or wrong versions of it."""
    numpyro, dist = _numpyro()
    with numpyro.plate("view", n_views):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    if kind == "independent":
        with numpyro.plate("instance", n_instances, dim=-2), numpyro.plate("view", n_views, dim=-1):
            numpyro.sample("f", dist.Normal(mu, jnp.sqrt(sigma**2 + tau**2)), obs=f)
        return
    shared = tau if kind == "tau" else tau**2
    cov = sigma**2 * jnp.eye(n_views) + shared * jnp.ones((n_views, n_views))
    with numpyro.plate("instance", n_instances):
        numpyro.sample("f", dist.MultivariateNormal(mu, covariance_matrix=cov), obs=f)


def _marginal_independent(n_instances, n_views, f=None):
    _marginal_model(n_instances, n_views, f, kind="independent")


def _marginal_tau_not_squared(n_instances, n_views, f=None):
    _marginal_model(n_instances, n_views, f, kind="tau")


def _marginal_ref(f, mu, sigma, tau):
    """Log density of the marginal model: the prior plus the library's marginal of each instance."""
    f = np.asarray(f, np.float64)
    marginal = _marginal(f, np.broadcast_to(mu, f.shape), sigma, np.full(f.shape[0], tau))
    return _log_prior(mu=mu, sigma=sigma, tau=tau) + float(marginal.sum())


_MARGINAL_SITES = ("mu", "sigma", "tau")
_MARGINAL_MISTAKES = [
    Mistake(
        "independent normals with variance sigma^2 + tau^2 have the right marginals but miss the "
        "covariance tau^2 between views of one instance: each instance's responses are one "
        "multivariate normal with covariance sigma^2 I + tau^2 1 1^T.",
        _model_as_function(_marginal_independent, _MARGINAL_SITES),
    ),
    Mistake(
        "tau is a standard deviation: the covariance adds tau^2 (not tau) to every entry.",
        _model_as_function(_marginal_tau_not_squared, _MARGINAL_SITES),
    ),
]


@exercise(
    "5.3",
    "The marginal model in NumPyro",
    "medium",
    reference=lambda: (_marginal_model,),
    wrong=lambda: [(_marginal_independent,), (_marginal_tau_not_squared,)],
)
def check_5_3(marginal_model) -> str:
    """Check exercise 5.3.

    ``marginal_model(n_instances, n_views, f=None)`` must have the latent sites ``mu, sigma, tau``
    only; its log density at given values is compared with the prior plus
    :func:`scrppl.models.instance_log_marginal` of every instance.
    """
    cases = _model_cases(with_u=False)
    name = "marginal_model(n_instances, n_views, f)"
    _check_sites(
        marginal_model,
        name,
        cases,
        lambda n_inst, n_views: {
            "mu": ((n_views,), "mu"),
            "sigma": ((), "sigma"),
            "tau": ((), "tau"),
        },
    )
    n = _check_model(
        marginal_model,
        name,
        _marginal_ref,
        cases,
        _MARGINAL_SITES,
        _MARGINAL_MISTAKES,
        "each row f[i] is one draw of a multivariate normal with mean mu and covariance "
        "sigma^2 I + tau^2 1 1^T (eq. 5.2); the priors are those of the chapter's toy_model.",
    )
    return f"its log density agrees with scrppl.models.instance_log_marginal on {n} data sets"


# -- 5.4 the non-centred model ----------------------------------------------------------------------
def _noncentred_model(n_instances, n_views, f=None, kind="right"):
    """The non-centred toy model (``kind="right"``), or wrong versions of it."""
    numpyro, dist = _numpyro()
    with numpyro.plate("view", n_views):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    with numpyro.plate("instance", n_instances):
        raw = numpyro.sample("u_raw", dist.Normal(0.0, tau if kind == "twice" else 1.0))
    u = numpyro.deterministic("u", raw if kind == "unscaled" else tau * raw)
    with numpyro.plate("instance", n_instances, dim=-2), numpyro.plate("view", n_views, dim=-1):
        numpyro.sample("f", dist.Normal(mu + u[:, None], sigma), obs=f)


def _noncentred_unscaled(n_instances, n_views, f=None):
    _noncentred_model(n_instances, n_views, f, kind="unscaled")


def _noncentred_twice(n_instances, n_views, f=None):
    _noncentred_model(n_instances, n_views, f, kind="twice")


def _latent_ref(f, mu, sigma, tau, u):
    """Log joint density of the chapter's toy model (one noise sd)."""
    f = np.asarray(f, np.float64)
    return _log_prior(mu=mu, sigma=sigma, tau=tau) + _instances_log_joint(
        f, np.broadcast_to(mu, f.shape), sigma, np.full(f.shape[0], tau), u
    )


def _noncentred_ref(f, mu, sigma, tau, u_raw):
    """The toy model at ``u = tau * u_raw`` plus the log-Jacobian ``I log(tau)`` of that change."""
    u_raw = np.asarray(u_raw, np.float64)
    return _latent_ref(f, mu, sigma, tau, tau * u_raw) + u_raw.size * float(np.log(tau))


_RAW_SITES = ("mu", "sigma", "tau", "u_raw")
_NONCENTRED_MISTAKES = [
    Mistake(
        "the instance effect is u = tau * u_raw: without the factor tau, tau only appears in its "
        "prior and no longer controls the spread of the instances.",
        _model_as_function(_noncentred_unscaled, _RAW_SITES),
    ),
    Mistake(
        "the standardised effects have a fixed prior, u_raw ~ N(0, 1); tau enters only "
        "through u = tau * u_raw (here it scales u twice).",
        _model_as_function(_noncentred_twice, _RAW_SITES),
    ),
]


@exercise(
    "5.4",
    "A funnel, diagnosed and fixed",
    "hard",
    reference=lambda: (_noncentred_model,),
    wrong=lambda: [(_noncentred_unscaled,), (_noncentred_twice,)],
)
def check_5_4(noncentred_model) -> str:
    """Check exercise 5.4.

    ``noncentred_model(n_instances, n_views, f=None)`` must have the latent sites ``mu, sigma, tau``
    and one more of shape ``(I,)`` (the standardised instance effects, any name: ``u_raw``, or
    NumPyro's ``u_decentered``); its log density is compared with the toy model's at
    ``u = tau * u_raw`` plus ``I log(tau)``, from :func:`scrppl.models.instance_log_marginal`.
    """
    cases = _model_cases(with_u=True)
    name = "noncentred_model(n_instances, n_views, f)"
    extras = _check_sites(
        noncentred_model,
        name,
        cases,
        lambda n_inst, n_views: {
            "mu": ((n_views,), "mu"),
            "sigma": ((), "sigma"),
            "tau": ((), "tau"),
        },
        free=1,
    )
    if len(set(extras)) != 1:
        fail(
            f"`{name}` names its standardised effects differently on different inputs: "
            f"{sorted(set(extras))}"
        )
    names = ("mu", "sigma", "tau", extras[0])
    n = _check_model(
        noncentred_model,
        name,
        _noncentred_ref,
        [Case(c.args, c.label + f" (the values of {extras[0]!r} are u_raw)") for c in cases],
        names,
        _NONCENTRED_MISTAKES,
        "sample u_raw ~ N(0, 1) in a plate over the instances and use u = tau * u_raw where the "
        "chapter's toy_model used u.",
    )
    return (
        f"its log density is the toy model's at u = tau * u_raw plus I log(tau), on {n} data sets"
    )
