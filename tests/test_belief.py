"""Belief filters against brute-force Bayes' rule written independently in NumPy/SciPy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from scrppl import belief as B
from scrppl.models.response import ResponseModel, check_response_model


def random_model(rng, n=3, o=2, a=4, e=2, s=1, tau=(0.4, 0.7)):
    mu = rng.normal(0.0, 1.5, size=(n, o, a, e, s))
    sigma = rng.uniform(0.5, 1.2, size=(n, o, a, e, s))
    tau = np.broadcast_to(np.asarray(tau, float), (n, o)) * rng.uniform(0.7, 1.3, size=(n, o))
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau))), (mu, sigma, tau)


def random_observations(rng, k, a, e, s):
    phi = rng.integers(0, a, size=k)
    ee = rng.integers(0, e, size=k)
    ss = rng.integers(0, s, size=k)
    f = rng.normal(0.0, 2.0, size=k)
    return f, phi, ee, ss


def brute_force_naive_bayes(params, f, phi, ee, ss, prior=None):
    """Eq. 3 by enumeration: product over responses of the marginal predictive mixture."""
    mu, sigma, tau = params
    n, o_n, a_n = mu.shape[:3]
    logp = np.zeros((o_n, a_n)) if prior is None else np.log(prior)
    for o in range(o_n):
        for theta in range(a_n):
            for fk, pk, ek, sk in zip(f, phi, ee, ss, strict=True):
                a = (pk - theta) % a_n
                sd = np.sqrt(sigma[:, o, a, ek, sk] ** 2 + tau[:, o] ** 2)
                logp[o, theta] += np.log(np.mean(stats.norm.pdf(fk, mu[:, o, a, ek, sk], sd)))
    return logp - logsumexp(logp)


def brute_force_instance(params, f, phi, ee, ss, prior=None):
    """p(F | o, theta) = mean_n integral prod_k N(f_k; mu + u, sigma^2) N(u; 0, tau^2) du, by quadrature."""
    mu, sigma, tau = params
    n_n, o_n, a_n = mu.shape[:3]
    post = np.zeros((o_n, a_n))
    moments = np.zeros((n_n, o_n, a_n, 2))
    for o in range(o_n):
        for theta in range(a_n):
            a = (phi - theta) % a_n
            for n in range(n_n):
                m = mu[n, o, a, ee, ss]
                sd = sigma[n, o, a, ee, ss]

                def integrand(u, m=m, sd=sd, n=n, o=o, power=0):
                    return (
                        u**power
                        * np.prod(stats.norm.pdf(f, m + u, sd))
                        * stats.norm.pdf(u, 0.0, tau[n, o])
                    )

                lim = 10 * tau[n, o]
                z = integrate.quad(integrand, -lim, lim, epsabs=0, epsrel=1e-10, limit=200)[0]
                m1 = integrate.quad(
                    lambda u, g=integrand: g(u, power=1),
                    -lim,
                    lim,
                    epsabs=0,
                    epsrel=1e-10,
                    limit=200,
                )[0]
                m2 = integrate.quad(
                    lambda u, g=integrand: g(u, power=2),
                    -lim,
                    lim,
                    epsabs=0,
                    epsrel=1e-10,
                    limit=200,
                )[0]
                post[o, theta] += z / n_n
                moments[n, o, theta] = m1 / z, m2 / z - (m1 / z) ** 2
    if prior is not None:
        post = post * prior
    return post / post.sum(), moments


def run_filter(kind, model, f, phi, ee, ss, prior=None):
    b = B.init_belief(kind, model, prior)
    for fk, pk, ek, sk in zip(f, phi, ee, ss, strict=True):
        b = B.update(model, b, jnp.float32(fk), int(pk), int(ek), int(sk))
    return b


@pytest.mark.parametrize("use_prior", [False, True])
def test_naive_bayes_equals_enumeration(rng, use_prior):
    model, params = random_model(rng)
    check_response_model(model)
    f, phi, ee, ss = random_observations(rng, 6, 4, 2, 1)
    prior = rng.uniform(0.1, 1.0, size=(2, 4)) if use_prior else None
    b = run_filter("naive_bayes", model, f, phi, ee, ss, prior)
    ref = brute_force_naive_bayes(
        params, f, phi, ee, ss, None if prior is None else prior / prior.sum()
    )
    np.testing.assert_allclose(np.asarray(B.joint_log_belief(b)), ref, atol=2e-4)
    np.testing.assert_allclose(np.asarray(B.joint_belief(b)).sum(), 1.0, atol=1e-5)


@pytest.mark.parametrize("use_prior", [False, True])
def test_instance_filter_equals_numerical_integration(rng, use_prior):
    model, params = random_model(rng, n=2, a=3)
    f, phi, ee, ss = random_observations(rng, 4, 3, 2, 1)
    prior = rng.uniform(0.1, 1.0, size=(2, 3)) if use_prior else None
    b = run_filter("instance", model, f, phi, ee, ss, prior)
    ref, moments = brute_force_instance(params, f, phi, ee, ss, prior)
    np.testing.assert_allclose(np.asarray(B.joint_belief(b)), ref, rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(np.asarray(b.u_mean), moments[..., 0], rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(np.asarray(b.u_var), moments[..., 1], rtol=1e-3, atol=1e-5)


def test_instance_filter_with_zero_tau_and_one_draw_is_naive_bayes(rng):
    model, params = random_model(rng, n=1, tau=(0.0, 0.0))
    f, phi, ee, ss = random_observations(rng, 7, 4, 2, 1)
    nb = run_filter("naive_bayes", model, f, phi, ee, ss)
    ia = run_filter("instance", model, f, phi, ee, ss)
    np.testing.assert_allclose(
        np.asarray(B.joint_log_belief(ia)), np.asarray(nb.log_belief), atol=1e-4
    )


def test_repeated_view_evidence_is_bounded_for_instance_filter(rng):
    # One view seen k times with the same response y. With equal sigma and tau for every state, the
    # instance-aware posterior has the closed form p(o, theta) ∝ Normal(y; mu, tau^2 + sigma^2 / k):
    # the agreement is explained by the shared instance effect. Naive Bayes instead multiplies the same
    # evidence k times and collapses onto one state.
    n, o, a, k, y, sig, tau = 1, 2, 4, 20, 1.0, 0.5, 1.0
    mu = rng.normal(0.0, 1.0, size=(n, o, a, 1, 1))
    model = ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, sig, jnp.float32), jnp.full((n, o), tau)
    )
    nb, ia = B.naive_bayes_init(model), B.instance_init(model)
    for _ in range(k):
        nb = B.update(model, nb, jnp.float32(y), 1, 0, 0)
        ia = B.update(model, ia, jnp.float32(y), 1, 0, 0)
    rel = (1 - np.arange(a)) % a  # relative azimuth seen from phi = 1 for every pose theta
    ref = stats.norm.pdf(y, mu[0, :, rel, 0, 0].T, np.sqrt(tau**2 + sig**2 / k))
    np.testing.assert_allclose(np.asarray(B.joint_belief(ia)), ref / ref.sum(), rtol=1e-4)
    log_nb = k * stats.norm.logpdf(y, mu[0, :, rel, 0, 0].T, np.sqrt(tau**2 + sig**2))
    np.testing.assert_allclose(np.asarray(nb.log_belief), log_nb - logsumexp(log_nb), atol=1e-3)
    assert float(B.joint_entropy(nb)) < float(B.joint_entropy(ia)) - 0.5


def test_constant_likelihood_leaves_belief_unchanged(rng):
    # mu and sigma independent of class and view: every (o, theta) explains f equally well.
    n, o, a = 2, 2, 4
    mu = np.broadcast_to(rng.normal(size=(n, 1, 1, 1, 1)), (n, o, a, 1, 1))
    sigma = np.broadcast_to(rng.uniform(0.5, 1, size=(n, 1, 1, 1, 1)), (n, o, a, 1, 1))
    tau = np.broadcast_to(rng.uniform(0.2, 1, size=(n, 1)), (n, o))
    model = ResponseModel(*(jnp.asarray(np.array(x), jnp.float32) for x in (mu, sigma, tau)))
    prior = rng.uniform(0.1, 1.0, size=(o, a))
    for kind in B.FILTERS:
        b0 = B.init_belief(kind, model, prior)
        b = b0
        for fk in rng.normal(size=5):
            b = B.update(model, b, jnp.float32(fk), int(rng.integers(a)), 0, 0)
        np.testing.assert_allclose(
            np.asarray(B.joint_belief(b)), prior / prior.sum(), rtol=1e-5, err_msg=kind
        )


@pytest.mark.parametrize("kind", B.FILTERS)
def test_rotating_robot_and_object_together_keeps_class_marginal(rng, kind):
    model, _ = random_model(rng, a=6)
    f, phi, ee, ss = random_observations(rng, 5, 6, 2, 1)
    b0 = run_filter(kind, model, f, phi, ee, ss)
    for r in (1, 3):
        b1 = run_filter(kind, model, f, (phi + r) % 6, ee, ss)
        np.testing.assert_allclose(
            np.asarray(B.class_marginal(b1)), np.asarray(B.class_marginal(b0)), atol=1e-5
        )
        # the pose marginal rotates with the object
        np.testing.assert_allclose(
            np.asarray(B.pose_marginal(b1)), np.roll(np.asarray(B.pose_marginal(b0)), r), atol=1e-5
        )


def test_marginals_and_entropies_against_numpy(rng):
    model, _ = random_model(rng)
    f, phi, ee, ss = random_observations(rng, 3, 4, 2, 1)
    for kind in B.FILTERS:
        b = run_filter(kind, model, f, phi, ee, ss)
        p = np.asarray(B.joint_belief(b), float)
        np.testing.assert_allclose(np.asarray(B.class_marginal(b)), p.sum(1), atol=1e-6)
        np.testing.assert_allclose(np.asarray(B.pose_marginal(b)), p.sum(0), atol=1e-6)
        np.testing.assert_allclose(float(B.joint_entropy(b)), stats.entropy(p.ravel()), atol=1e-5)
        np.testing.assert_allclose(float(B.class_entropy(b)), stats.entropy(p.sum(1)), atol=1e-5)
        np.testing.assert_allclose(float(B.pose_entropy(b)), stats.entropy(p.sum(0)), atol=1e-5)
    # zero-probability states contribute nothing
    assert float(B.entropy(jnp.log(jnp.array([1.0, 0.0])))) == 0.0
    np.testing.assert_allclose(float(B.entropy(jnp.log(jnp.full(8, 0.125)))), np.log(8), rtol=1e-6)


def test_naive_bayes_stable_over_thousands_of_updates(rng):
    model, params = random_model(rng, n=2)
    k = 5000
    f, phi, ee, ss = random_observations(rng, k, 4, 2, 1)

    def step(b, obs):
        fk, pk, ek, sk = obs
        return B.naive_bayes_update(model, b, fk, pk, ek, sk), None

    obs = (jnp.asarray(f, jnp.float32), jnp.asarray(phi), jnp.asarray(ee), jnp.asarray(ss))
    b, _ = jax.jit(lambda b0: jax.lax.scan(step, b0, obs))(B.naive_bayes_init(model))
    logp = np.asarray(b.log_belief)
    assert np.all(np.isfinite(logp) | (logp == -np.inf))
    np.testing.assert_allclose(np.exp(logp).sum(), 1.0, atol=1e-5)
    ref = brute_force_naive_bayes(params, f[:300], phi[:300], ee[:300], ss[:300])
    b300 = run_filter("naive_bayes", model, f[:300], phi[:300], ee[:300], ss[:300])
    # with 300 updates the log posterior is a sum of hundreds of terms; float32 keeps it to ~1e-2
    best = ref.max()
    mask = ref > best - 30
    np.testing.assert_allclose(np.asarray(b300.log_belief)[mask], ref[mask], atol=2e-2)


def test_filters_jit_and_vmap_over_trials(rng):
    model, params = random_model(rng)
    n_trials, k = 5, 4
    f = rng.normal(size=(n_trials, k))
    phi = rng.integers(0, 4, size=(n_trials, k))

    for kind in B.FILTERS:

        def run(fs, phis, kind=kind):
            b = B.init_belief(kind, model)
            for j in range(k):
                b = B.update(model, b, fs[j], phis[j], 0, 0)
            return B.joint_log_belief(b)

        batched = jax.jit(jax.vmap(run))(jnp.asarray(f, jnp.float32), jnp.asarray(phi))
        for t in range(n_trials):
            single = B.joint_log_belief(
                run_filter(kind, model, f[t], phi[t], np.zeros(k, int), np.zeros(k, int))
            )
            np.testing.assert_allclose(np.asarray(batched[t]), np.asarray(single), atol=1e-5)


def test_mixture_posterior_equals_filter_update(rng):
    model, _ = random_model(rng)
    f, phi, ee, ss = random_observations(rng, 3, 4, 2, 1)
    for kind in B.FILTERS:
        b = run_filter(kind, model, f, phi, ee, ss)
        mix = B.predictive_mixture(model, b, 2, 1, 0)
        np.testing.assert_allclose(
            float(jnp.exp(logsumexp(np.asarray(mix.log_weight)))), 1.0, atol=1e-5
        )
        post = B.mixture_posterior(mix, jnp.float32(0.3))
        after = B.joint_log_belief(B.update(model, b, jnp.float32(0.3), 2, 1, 0))
        np.testing.assert_allclose(np.asarray(post), np.asarray(after), atol=1e-5, err_msg=kind)


def test_bad_input_gives_clear_errors(rng):
    model, _ = random_model(rng)
    b = B.naive_bayes_init(model)
    with pytest.raises(ValueError, match="robot azimuth index out of the view grid"):
        B.naive_bayes_update(model, b, 0.0, 4, 0, 0)
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        B.instance_update(model, B.instance_init(model), 0.0, 0, 2, 0)
    with pytest.raises(ValueError, match="scale index out of the view grid"):
        B.update(model, b, 0.0, 0, 0, -1)
    with pytest.raises(ValueError, match="not finite"):
        B.naive_bayes_update(model, b, float("nan"), 0, 0, 0)
    with pytest.raises(ValueError, match="not finite"):
        B.instance_update(model, B.instance_init(model), jnp.nan, 0, 0, 0)
    with pytest.raises(ValueError, match="prior must have shape"):
        B.naive_bayes_init(model, np.ones(3))
    with pytest.raises(ValueError, match="unknown filter"):
        B.init_belief("kalman", model)
    with pytest.raises(ValueError, match="unknown objective"):
        B.objective_entropy(b.log_belief, "colour")
    with pytest.raises(ValueError, match="must be an integer"):
        B.naive_bayes_update(model, b, 0.0, 1.5, 0, 0)


def test_filters_check_model_belief_and_view_where_they_enter(rng):
    model, _ = random_model(rng)  # N = 3 draws, (O, A, E, S) = (2, 4, 2, 1)
    nb, ia = B.naive_bayes_init(model), B.instance_init(model)
    # a belief of a model with another view grid (A = 6) or another number of draws
    wide, _ = random_model(rng, a=6)
    for belief in (nb, ia):
        with pytest.raises(ValueError, match="belief was made with another model"):
            B.update(wide, belief, 0.0, 0, 0, 0)
        with pytest.raises(ValueError, match="belief was made with another model"):
            B.predictive_mixture(wide, belief, 0, 0, 0)
    fewer = ResponseModel(*(x[:2] for x in model))
    with pytest.raises(ValueError, match=r"InstanceBelief.u_mean has shape \(3, 2, 4\)"):
        B.instance_update(fewer, ia, 0.0, 0, 0, 0)
    with pytest.raises(ValueError, match="not a belief"):
        B.predictive_mixture(model, nb.log_belief, 0, 0, 0)
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        B.predictive_mixture(model, nb, 0, 2, 0)
    # malformed models are refused by every filter function, before any arithmetic
    bad_models = {
        r"mu must have shape \(N, O, A, E, S\)": model._replace(mu=model.mu[0]),
        "sigma shape": model._replace(sigma=model.sigma[..., 0]),
        r"tau must have shape \(3, 2\)": model._replace(tau=model.tau[0]),
        "mu contains NaN": model._replace(mu=model.mu.at[2, 1, 3, 1, 0].set(jnp.nan)),
        "sigma contains NaN": model._replace(sigma=model.sigma.at[0, 0, 0, 0, 0].set(jnp.nan)),
        "sigma must be strictly positive": model._replace(sigma=-model.sigma),
        "tau must be non-negative": model._replace(tau=model.tau.at[0, 0].set(-0.1)),
    }
    for message, bad in bad_models.items():
        for call in (
            lambda m: B.naive_bayes_init(m),
            lambda m: B.instance_init(m),
            lambda m: B.naive_bayes_update(m, nb, 0.0, 0, 0, 0),
            lambda m: B.instance_update(m, ia, 0.0, 0, 0, 0),
            lambda m: B.predictive_mixture(m, nb, 0, 0, 0),
        ):
            with pytest.raises(ValueError, match=message):
                call(bad)
