"""Checks for the exercises of chapter 5 (hierarchical viewpoint models).

The exercises use a small version of the chapter's model: responses ``f[i, a]`` of ``I`` instances of one
class, each seen from all ``A`` azimuths,

    f[i, a] = mu[a] + u[i] + sigma * eps[i, a],    u[i] ~ Normal(0, tau),    eps ~ Normal(0, 1),

with priors ``mu[a] ~ Normal(0, 2)``, ``sigma ~ HalfNormal(1)``, ``tau ~ HalfNormal(1)``. The references
rest on the library's closed-form instance marginal :func:`scrppl.models.instance_log_marginal`:

* 5.1 -- the marginal covariance ``diag(sigma^2) + tau^2 1 1^T`` is the inverse of minus the Hessian of
  the library's log density (a quadratic in the responses), and the dense log density is the library's;
* 5.3 -- the marginal model's log density is the prior plus the library's marginal of every instance;
* 5.2 -- the latent-instance model's log joint density follows from the same marginal by the identity
  ``p(f_i | u_i) p(u_i) = p(f_i) p(u_i | f_i)``: the posterior of ``u_i`` given the responses of instance
  ``i`` is normal with precision ``1 / tau^2 + A / sigma^2`` and mean ``sum_a (f[i, a] - mu[a]) / sigma^2``
  over that precision (the "completing the square" of the chapter's derivation);
* 5.4 -- the non-centred model ``u = tau * u_raw``, ``u_raw ~ Normal(0, 1)`` has the latent model's
  log density at ``u = tau * u_raw`` plus the log-Jacobian ``I log(tau)``.

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


@jax.jit
def _precision_jit(sigma, tau):
    """Minus the Hessian in ``y`` of the library's log density of one instance: ``Sigma^-1``."""
    from scrppl.models.marginal import instance_log_marginal

    def logp(y):
        return instance_log_marginal(
            y[None], jnp.zeros_like(y)[None], sigma[None], tau[None], jnp.ones((1, y.size), bool)
        )[0]

    return -jax.hessian(logp)(jnp.zeros_like(sigma))


# -- 5.1 the instance effect integrated out ---------------------------------------------------------
def _cov_ref(sigma, tau):
    sigma = np.asarray(sigma, np.float32)
    prec = np.asarray(_precision_jit(sigma, np.float32(tau)), np.float64)
    return np.linalg.inv(prec)


def _density_ref(y, m, sigma, tau):
    return float(_marginal(np.asarray(y)[None], m, sigma, [tau])[0])


def _cov_cases() -> list[Case]:
    rng = np.random.default_rng(51)
    out = []
    for n, tau, label in (
        (1, 0.6, "one view"),
        (3, 0.4, "three views with different noise sds"),
        (8, 1.5, "eight views, a large instance effect"),
        (4, 0.0, "four views, no instance effect (tau = 0)"),
    ):
        sigma = rng.uniform(0.3, 1.0, n).round(3)
        out.append(Case((sigma, tau), f"{label}, tau = {tau}"))
    return out


def _density_cases() -> list[Case]:
    rng = np.random.default_rng(52)
    out = []
    for n, tau, shift, label in (
        (1, 0.6, 0.0, "one view"),
        (3, 0.4, 0.0, "three views"),
        (8, 0.8, 1.5, "eight views of an instance far above its class mean"),
        (8, 0.8, 0.0, "eight views scattered around the means"),
        (4, 0.0, 0.0, "four views, no instance effect (tau = 0)"),
    ):
        m = rng.normal(0.0, 1.0, n).round(3)
        sigma = rng.uniform(0.3, 1.0, n).round(3)
        y = (m + shift + sigma * rng.normal(size=n)).round(3)
        out.append(Case((y, m, sigma, tau), f"{label}, tau = {tau}"))
    return out


def _dense(y, m, cov):
    return float(stats.multivariate_normal(m, cov).logpdf(y))


_COV_MISTAKES = [
    Mistake(
        "the views of one instance share its effect u: every pair of views has covariance tau^2, "
        "so Sigma = diag(sigma^2) + tau^2 * ones((n, n)), not only a diagonal.",
        lambda sigma, tau: np.diag(np.asarray(sigma) ** 2 + tau**2),
    ),
    Mistake(
        "tau is a standard deviation: the covariance adds tau^2 (not tau) to every entry.",
        lambda sigma, tau: np.diag(np.asarray(sigma) ** 2) + tau * np.ones((len(sigma),) * 2),
    ),
    Mistake(
        "sigma is a standard deviation: the diagonal holds sigma^2.",
        lambda sigma, tau: np.diag(np.asarray(sigma)) + tau**2 * np.ones((len(sigma),) * 2),
    ),
]

_DENSITY_MISTAKES = [
    Mistake(
        "this is the product of the views' marginals N(y_j; m_j, sqrt(sigma_j^2 + tau^2)), which "
        "treats the views as independent; use the full covariance diag(sigma^2) + tau^2 1 1^T in a "
        "multivariate normal.",
        lambda y, m, sigma, tau: float(
            stats.norm.logpdf(y, m, np.sqrt(np.asarray(sigma) ** 2 + tau**2)).sum()
        ),
    ),
    Mistake(
        "the instance effect is missing: this is the density given u = 0. Integrate u out: it "
        "adds tau^2 to every entry of the covariance.",
        lambda y, m, sigma, tau: float(stats.norm.logpdf(y, m, sigma).sum()),
    ),
    Mistake(
        "tau is a standard deviation: the covariance adds tau^2 (not tau) to every entry.",
        lambda y, m, sigma, tau: _dense(y, m, _COV_MISTAKES[1].fn(sigma, tau)),
    ),
]


@exercise(
    "5.1",
    "The instance effect integrated out",
    "easy",
    reference=lambda: (_cov_ref, _density_ref),
    wrong=lambda: [
        (_COV_MISTAKES[0].fn, _density_ref),
        (_cov_ref, _DENSITY_MISTAKES[0].fn),
        (_cov_ref, _DENSITY_MISTAKES[2].fn),
    ],
)
def check_5_1(marginal_covariance, instance_log_density) -> str:
    """Check exercise 5.1.

    ``marginal_covariance(sigma, tau)`` is compared with the inverse of minus the Hessian of
    :func:`scrppl.models.instance_log_marginal` (its log density is a quadratic in the responses), and
    ``instance_log_density(y, m, sigma, tau)`` with :func:`scrppl.models.instance_log_marginal` itself.
    """
    n = check_function(
        marginal_covariance,
        _cov_ref,
        _cov_cases(),
        name="marginal_covariance(sigma, tau)",
        rtol=1e-4,
        atol=1e-5,
        mistakes=_COV_MISTAKES,
        hint="Sigma[j, k] = sigma_j^2 [j == k] + tau^2 for every pair of views j, k.",
    )
    m = check_function(
        instance_log_density,
        _density_ref,
        _density_cases(),
        name="instance_log_density(y, m, sigma, tau)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_DENSITY_MISTAKES,
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.models.instance_log_marginal on {n + m} inputs"


# -- NumPyro models: tracing and log densities ------------------------------------------------------
def _numpyro():
    import numpyro
    import numpyro.distributions as dist

    return numpyro, dist


def _prior(mu, sigma, tau) -> float:
    """The exercises' prior: mu[a] ~ Normal(0, 2), sigma ~ HalfNormal(1), tau ~ HalfNormal(1)."""
    return float(
        stats.norm.logpdf(mu, 0.0, 2.0).sum()
        + stats.halfnorm.logpdf(sigma)
        + stats.halfnorm.logpdf(tau)
    )


def _latent_ref(f, mu, sigma, tau, u):
    """Log joint density of the latent-instance model, from the library's instance marginal."""
    f = np.asarray(f, np.float64)
    n_inst, n_az = f.shape
    marginal = _marginal(f, np.broadcast_to(mu, f.shape), sigma, np.full(n_inst, tau))
    precision = 1.0 / tau**2 + n_az / sigma**2
    mean = ((f - mu).sum(axis=1) / sigma**2) / precision
    posterior_u = stats.norm.logpdf(u, mean, precision**-0.5)
    return _prior(mu, sigma, tau) + float(marginal.sum() + posterior_u.sum())


def _marginal_ref(f, mu, sigma, tau):
    """Log density of the marginal model: the prior plus the library's marginal of each instance."""
    f = np.asarray(f, np.float64)
    marginal = _marginal(f, np.broadcast_to(mu, f.shape), sigma, np.full(f.shape[0], tau))
    return _prior(mu, sigma, tau) + float(marginal.sum())


def _noncentred_ref(f, mu, sigma, tau, u_raw):
    """The latent model at ``u = tau * u_raw`` plus the log-Jacobian ``I log(tau)`` of that change."""
    u_raw = np.asarray(u_raw, np.float64)
    return _latent_ref(f, mu, sigma, tau, tau * u_raw) + u_raw.size * float(np.log(tau))


def _log_joint(model, f, params: dict) -> float:
    """``numpyro.infer.util.log_density`` of ``model(f)`` at ``params`` (compiled: one XLA call).

    ``f`` stays a concrete NumPy array inside the model (only the parameters are traced), so a model
    may use NumPy on its data.
    """
    from numpyro import handlers
    from numpyro.infer.util import log_density

    f = np.asarray(f)

    def logp(values):
        return log_density(handlers.seed(model, 0), (f,), {}, values)[0]

    values = {k: jnp.asarray(v, jnp.float32) for k, v in params.items()}
    return float(jax.jit(logp)(values))


def _sites(model, name: str, case: Case, where: str, names) -> tuple[dict, list[str]]:
    """Latent sample sites (name -> shape) and observed sites of ``model(f)`` for ``case``.

    The model is traced abstractly (:func:`jax.eval_shape`): nothing is computed.
    """
    from numpyro import handlers

    observed: dict[str, bool] = {}

    def run(f, *_params):
        def values():
            tr = handlers.trace(handlers.seed(model, 0)).get_trace(np.asarray(f))
            sites = {k: s for k, s in tr.items() if s["type"] == "sample"}
            observed.update({k: bool(s["is_observed"]) for k, s in sites.items()})
            return {k: s["value"] for k, s in sites.items()}

        return jax.eval_shape(values)

    shapes = call(run, name, case, where=where, arg_names=["f", *names])
    latent = {k: tuple(v.shape) for k, v in shapes.items() if not observed[k]}
    return latent, [k for k, obs in observed.items() if obs]


def _describe_input(case: Case, where: str) -> str:
    f = np.asarray(case.args[0])
    return f"on input {where} ({case.label}; f of shape {f.shape})"


def _check_sites(
    model, name: str, cases: list[Case], expected, names, free: int = 0
) -> list[str | None]:
    """Fail unless ``model`` has the expected latent sites (and ``free`` extra ones of shape (I,)).

    ``expected(I, A)`` gives ``{site: shape}``. Returns, per case, the name of the extra site (the
    non-centred exercise lets the student name it).
    """
    require(model, name)
    if not callable(model):
        fail(f"`{name}` should be a NumPyro model (a function of f), but it is {model!r}.")
    extras = []
    for i, case in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        latent, observed = _sites(model, name, case, where, names)
        n_inst, n_az = np.shape(case.args[0])
        want = expected(n_inst, n_az)
        at = _describe_input(case, where)
        if "f" in latent:
            fail(
                f"`{name}` samples 'f' as a latent variable {at}: the responses are data, so pass "
                "them as numpyro.sample('f', ..., obs=f)."
            )
        for site, shape in want.items():
            if site not in latent:
                fail(
                    f"`{name}` has no latent sample site named {site!r} {at}; its latent sites are "
                    f"{sorted(latent)}. Name the sites exactly as the exercise says."
                )
            if latent[site] != shape:
                fail(
                    f"`{name}`: the site {site!r} has shape {latent[site]} {at}, expected {shape}. "
                    + (
                        "One value per azimuth: sample it in a plate over the A azimuths (or with "
                        "dist.Normal(...).expand([A]))."
                        if site == "mu"
                        else "One value per instance: sample it in a plate over the I instances."
                        if len(shape) == 1
                        else "It is a single number, shared by every instance and azimuth."
                    )
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


def _model_cases(with_u: bool) -> list[Case]:
    """Data sets ``f`` ``(I, A)`` and parameter values (including a small tau: the funnel's neck)."""
    out = []
    for seed, (n_inst, n_az), tau, label in (
        (53, (4, 8), 0.5, "4 instances x 8 azimuths"),
        (54, (4, 8), 0.05, "4 instances x 8 azimuths, a small tau"),
        (55, (3, 5), 1.2, "3 instances x 5 azimuths, a large tau"),
    ):  # two shapes only: every new shape compiles the model anew
        rng = np.random.default_rng(seed)
        mu_true = rng.normal(0.0, 1.0, n_az)
        f = mu_true + 0.6 * rng.normal(size=(n_inst, 1)) + 0.5 * rng.normal(size=(n_inst, n_az))
        mu = (mu_true + 0.3 * rng.normal(size=n_az)).round(3)
        sigma = round(float(rng.uniform(0.3, 1.0)), 3)
        args = (f.round(3), mu, sigma, tau)
        if with_u:
            args += (rng.normal(0.0, 1.0, n_inst).round(3),)
        out.append(Case(args, f"{label}, seed={seed}"))
    return out


def _model_as_function(model, names: tuple[str, ...]):
    """``model`` as a function of ``(f, *parameter values)``: its log joint density."""

    def logp(f, *values):
        return _log_joint(model, f, dict(zip(names, values, strict=True)))

    return logp


# -- 5.2 the latent-instance model ------------------------------------------------------------------
def _latent_model(f, u_scale_power=1, with_u=True, marginal_sd=False):
    """The latent-instance model (and, through its flags, some wrong versions of it)."""
    numpyro, dist = _numpyro()
    n_inst, n_az = np.shape(f)
    with numpyro.plate("azimuth", n_az):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    with numpyro.plate("instance", n_inst):
        u = numpyro.sample("u", dist.Normal(0.0, tau**u_scale_power))
    loc = mu + (u[:, None] if with_u else 0.0)
    sd = jnp.sqrt(sigma**2 + tau**2) if marginal_sd else sigma
    numpyro.sample("f", dist.Normal(loc, sd), obs=f)


def _latent_variance_scale(f):
    _latent_model(f, u_scale_power=2)


def _latent_without_u(f):
    _latent_model(f, with_u=False)


def _latent_double(f):
    _latent_model(f, marginal_sd=True)


_LATENT_SITES = ("mu", "sigma", "tau", "u")
_LATENT_MISTAKES = [
    Mistake(
        "dist.Normal takes a standard deviation: u ~ Normal(0, tau), not Normal(0, tau**2).",
        _model_as_function(_latent_variance_scale, _LATENT_SITES),
    ),
    Mistake(
        "the instance effect must shift every response of its instance: the mean of f[i, a] is "
        "mu[a] + u[i] (e.g. mu[None, :] + u[:, None]).",
        _model_as_function(_latent_without_u, _LATENT_SITES),
    ),
    Mistake(
        "given u, the responses of an instance only have the noise sigma; sqrt(sigma^2 + tau^2) "
        "is the sd once u is integrated out, and here u is still in the model.",
        _model_as_function(_latent_double, _LATENT_SITES),
    ),
]


def _check_model(model, name, reference, cases, names, mistakes, hint) -> int:
    """Compare the log density of ``model`` at every case's parameters with ``reference``."""
    return check_function(
        _model_as_function(model, names),
        reference,
        cases,
        name=f"the log density of {name}",
        rtol=1e-4,
        atol=2e-3,
        mistakes=mistakes,
        hint=hint,
    )


@exercise(
    "5.2",
    "A latent-instance model in NumPyro",
    "medium",
    reference=lambda: (_latent_model,),
    wrong=lambda: [(_latent_variance_scale,), (_latent_without_u,), (_latent_double,)],
)
def check_5_2(latent_model) -> str:
    """Check exercise 5.2.

    The sites of ``latent_model(f)`` are checked by tracing it; its log joint density
    (:func:`numpyro.infer.util.log_density`) at given ``mu, sigma, tau, u`` is compared with the prior
    plus :func:`scrppl.models.instance_log_marginal` plus the log posterior density of ``u`` (the
    module docstring gives the identity).
    """
    cases = _model_cases(with_u=True)
    _check_sites(
        latent_model,
        "latent_model(f)",
        cases,
        lambda n_inst, n_az: {"mu": (n_az,), "sigma": (), "tau": (), "u": (n_inst,)},
        _LATENT_SITES,
    )
    n = _check_model(
        latent_model,
        "latent_model(f)",
        _latent_ref,
        cases,
        _LATENT_SITES,
        _LATENT_MISTAKES,
        "check the priors (mu[a] ~ Normal(0, 2), sigma and tau ~ HalfNormal(1)), u[i] ~ Normal(0, "
        "tau), and f[i, a] ~ Normal(mu[a] + u[i], sigma).",
    )
    return (
        f"its log density agrees with the library's closed-form instance marginal on {n} data sets"
    )


# -- 5.3 the marginal model -------------------------------------------------------------------------
def _marginal_model(f, kind="mvn"):
    """The marginal model (``kind="mvn"``), or wrong versions of it."""
    numpyro, dist = _numpyro()
    n_inst, n_az = np.shape(f)
    with numpyro.plate("azimuth", n_az):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    if kind == "independent":
        numpyro.sample("f", dist.Normal(mu, jnp.sqrt(sigma**2 + tau**2)), obs=f)
        return
    shared = tau if kind == "tau" else tau**2
    cov = sigma**2 * jnp.eye(n_az) + shared * jnp.ones((n_az, n_az))
    with numpyro.plate("instance", n_inst):
        numpyro.sample("f", dist.MultivariateNormal(mu, covariance_matrix=cov), obs=f)


def _marginal_independent(f):
    _marginal_model(f, kind="independent")


def _marginal_tau_not_squared(f):
    _marginal_model(f, kind="tau")


def _marginal_without_tau(f):
    numpyro, dist = _numpyro()
    n_az = np.shape(f)[1]
    with numpyro.plate("azimuth", n_az):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    numpyro.sample("tau", dist.HalfNormal(1.0))
    numpyro.sample("f", dist.Normal(mu, sigma), obs=f)


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
    Mistake(
        "tau must enter the likelihood: integrating u out adds tau^2 to every entry of each "
        "instance's covariance.",
        _model_as_function(_marginal_without_tau, _MARGINAL_SITES),
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

    ``marginal_model(f)`` must have the latent sites ``mu, sigma, tau`` only; its log density at given
    values is compared with the prior plus :func:`scrppl.models.instance_log_marginal` of every
    instance.
    """
    cases = _model_cases(with_u=False)
    _check_sites(
        marginal_model,
        "marginal_model(f)",
        cases,
        lambda n_inst, n_az: {"mu": (n_az,), "sigma": (), "tau": ()},
        _MARGINAL_SITES,
    )
    n = _check_model(
        marginal_model,
        "marginal_model(f)",
        _marginal_ref,
        cases,
        _MARGINAL_SITES,
        _MARGINAL_MISTAKES,
        "each row f[i] is one draw of a multivariate normal with mean mu and covariance "
        "sigma^2 I + tau^2 1 1^T; the priors are those of exercise 5.2.",
    )
    return f"its log density agrees with scrppl.models.instance_log_marginal on {n} data sets"


# -- 5.4 the non-centred model ----------------------------------------------------------------------
def _noncentred_model(f, kind="right"):
    """The non-centred latent model (``kind="right"``), or wrong versions of it."""
    numpyro, dist = _numpyro()
    n_inst, n_az = np.shape(f)
    with numpyro.plate("azimuth", n_az):
        mu = numpyro.sample("mu", dist.Normal(0.0, 2.0))
    sigma = numpyro.sample("sigma", dist.HalfNormal(1.0))
    tau = numpyro.sample("tau", dist.HalfNormal(1.0))
    with numpyro.plate("instance", n_inst):
        raw = numpyro.sample("u_raw", dist.Normal(0.0, tau if kind == "twice" else 1.0))
    u = numpyro.deterministic("u", raw if kind == "unscaled" else tau * raw)
    numpyro.sample("f", dist.Normal(mu + u[:, None], sigma), obs=f)


def _noncentred_unscaled(f):
    _noncentred_model(f, kind="unscaled")


def _noncentred_twice(f):
    _noncentred_model(f, kind="twice")


def _noncentred_reparam():
    """The same model from NumPyro's ``LocScaleReparam`` (a correct answer with another site name)."""
    from numpyro.handlers import reparam
    from numpyro.infer.reparam import LocScaleReparam

    return reparam(_latent_model, config={"u": LocScaleReparam(0)})


_NONCENTRED_MISTAKES = [
    Mistake(
        "the instance effect is u = tau * u_raw: without the factor tau, tau only appears in its "
        "prior and no longer controls the spread of the instances.",
        lambda f, mu, sigma, tau, u_raw: _log_joint(
            _noncentred_unscaled, f, dict(mu=mu, sigma=sigma, tau=tau, u_raw=u_raw)
        ),
    ),
    Mistake(
        "the standardised effects have a fixed prior, u_raw ~ Normal(0, 1); tau enters only "
        "through u = tau * u_raw (here it scales u twice).",
        lambda f, mu, sigma, tau, u_raw: _log_joint(
            _noncentred_twice, f, dict(mu=mu, sigma=sigma, tau=tau, u_raw=u_raw)
        ),
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

    ``noncentred_model(f)`` must have the latent sites ``mu, sigma, tau`` and one more of shape ``(I,)``
    (the standardised instance effects, any name: ``u_raw``, or NumPyro's ``u_decentered``); its log
    density is compared with the latent model's at ``u = tau * u_raw`` plus ``I log(tau)``, from
    :func:`scrppl.models.instance_log_marginal`.
    """
    cases = _model_cases(with_u=True)
    extras = _check_sites(
        noncentred_model,
        "noncentred_model(f)",
        cases,
        lambda n_inst, n_az: {"mu": (n_az,), "sigma": (), "tau": ()},
        ("mu", "sigma", "tau", "u_raw"),
        free=1,
    )
    if len(set(extras)) != 1:
        fail(
            f"`noncentred_model(f)` names its standardised effects differently on different inputs: "
            f"{sorted(set(extras))}"
        )
    names = ("mu", "sigma", "tau", extras[0])
    n = _check_model(
        noncentred_model,
        "noncentred_model(f)",
        _noncentred_ref,
        [Case(c.args, c.label + f" (the values of {extras[0]!r} are u_raw)") for c in cases],
        names,
        _NONCENTRED_MISTAKES,
        "sample u_raw ~ Normal(0, 1) in a plate over the instances and use u = tau * u_raw where the "
        "latent model of exercise 5.2 used u.",
    )
    return f"its log density is the latent model's at u = tau * u_raw plus I log(tau), on {n} data sets"
