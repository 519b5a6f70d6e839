"""Detector fusion against sequential single-detector updates and brute-force Bayes written in NumPy/SciPy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import logsumexp

from scrppl import belief as B
from scrppl import planning as P
from scrppl.extensions import fusion as F
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig as PC


def random_model(rng, n=2, o=2, a=4, e=2, s=1, tau=0.6, scale=1.5):
    mu = rng.normal(0.0, scale, size=(n, o, a, e, s))
    sigma = rng.uniform(0.5, 1.1, size=(n, o, a, e, s))
    tau = np.full((n, o), tau) * rng.uniform(0.6, 1.4, size=(n, o))
    return ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))


def constant_model(n=2, o=2, a=4, e=2, s=1, tau=0.5):
    """A detector whose response distribution does not depend on the state (per draw)."""
    mu = np.broadcast_to(np.linspace(-1, 1, n)[:, None, None, None, None], (n, o, a, e, s))
    sigma = np.full((n, o, a, e, s), 0.8)
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.asarray(sigma, jnp.float32), jnp.full((n, o), tau)
    )


def observations(rng, k, d, a, e, s):
    """k views, each with responses of d detectors: (f (k, d), phi, e, s)."""
    return (
        rng.normal(0.0, 1.5, size=(k, d)),
        rng.integers(0, a, size=k),
        rng.integers(0, e, size=k),
        rng.integers(0, s, size=k),
    )


def fuse(kind, models, obs, masks=None):
    f, phi, ee, ss = obs
    b = F.fused_init(kind, models)
    for k in range(len(phi)):
        mask = None if masks is None else masks[k]
        b = F.fused_update(
            models, b, jnp.asarray(f[k], jnp.float32), int(phi[k]), int(ee[k]), int(ss[k]), mask
        )
    return b


# ------------------------------------------------------------------------------------------------
# brute force (NumPy/SciPy, independent of the filters)


def np_params(model):
    return tuple(np.asarray(x, np.float64) for x in model)


def brute_log_lik_naive(params, fs, phis, ees, sss):
    """sum_k log mean_n N(f_k; mu, sigma^2 + tau^2) for one detector, shape (O, A)."""
    mu, sigma, tau = params
    _, n_o, n_a = mu.shape[:3]
    out = np.zeros((n_o, n_a))
    for o in range(n_o):
        for th in range(n_a):
            for f, p, e, s in zip(fs, phis, ees, sss, strict=True):
                a = (p - th) % n_a
                sd = np.sqrt(sigma[:, o, a, e, s] ** 2 + tau[:, o] ** 2)
                out[o, th] += np.log(np.mean(stats.norm.pdf(f, mu[:, o, a, e, s], sd)))
    return out


def brute_log_lik_instance(params, fs, phis, ees, sss):
    """log mean_n integral prod_k N(f_k; mu + u, sigma) N(u; 0, tau) du for one detector, by quadrature."""
    mu, sigma, tau = params
    n_n, n_o, n_a = mu.shape[:3]
    fs = np.asarray(fs)
    out = np.zeros((n_o, n_a))
    for o in range(n_o):
        for th in range(n_a):
            a = (np.asarray(phis) - th) % n_a
            vals = []
            for n in range(n_n):
                m = mu[n, o, a, ees, sss]
                sd = sigma[n, o, a, ees, sss]
                lim = 12 * tau[n, o]
                vals.append(
                    integrate.quad(
                        lambda u, m=m, sd=sd, n=n, o=o: (
                            np.prod(stats.norm.pdf(fs, m + u, sd))
                            * stats.norm.pdf(u, 0.0, tau[n, o])
                        ),
                        -lim,
                        lim,
                        epsabs=0,
                        epsrel=1e-10,
                        limit=200,
                    )[0]
                )
            out[o, th] = np.log(np.mean(vals))
    return out


def normalise(logp):
    return logp - logsumexp(logp)


# ------------------------------------------------------------------------------------------------
# updates


def test_naive_fusion_equals_sequential_single_detector_updates(rng):
    models = (random_model(rng, n=1, tau=0.0), random_model(rng, n=3), random_model(rng, n=2))
    obs = observations(rng, 4, 3, 4, 2, 1)
    masks = rng.uniform(size=(4, 3)) < 0.7
    masks[0] = True
    fused = fuse("naive_bayes", models, obs, masks)
    seq = B.naive_bayes_init(models[0])
    f, phi, ee, ss = obs
    for k in range(4):
        for d in range(3):
            if masks[k, d]:
                seq = B.naive_bayes_update(
                    models[d], seq, jnp.float32(f[k, d]), int(phi[k]), int(ee[k]), int(ss[k])
                )
    np.testing.assert_allclose(fused.log_belief, seq.log_belief, atol=2e-5)


def test_naive_fusion_equals_brute_force_bayes(rng):
    models = (random_model(rng, n=2), random_model(rng, n=3))
    obs = observations(rng, 3, 2, 4, 2, 1)
    f, phi, ee, ss = obs
    want = normalise(
        sum(brute_log_lik_naive(np_params(m), f[:, d], phi, ee, ss) for d, m in enumerate(models))
    )
    got = F.fused_joint_log_belief(fuse("naive_bayes", models, obs))
    np.testing.assert_allclose(got, want, atol=5e-5)


def test_instance_fusion_equals_brute_force_integration_over_each_instance_effect(rng):
    models = (random_model(rng, n=2, tau=0.7), random_model(rng, n=1, tau=0.4))
    obs = observations(rng, 3, 2, 4, 2, 1)
    f, phi, ee, ss = obs
    want = normalise(
        sum(
            brute_log_lik_instance(np_params(m), f[:, d], phi, ee, ss) for d, m in enumerate(models)
        )
    )
    got = F.fused_joint_log_belief(fuse("instance", models, obs))
    np.testing.assert_allclose(got, want, atol=5e-5)
    # one detector: the fused instance belief is the library's instance-aware filter
    single = fuse("instance", models[:1], (f[:, :1], phi, ee, ss))
    lib = B.instance_init(models[0])
    for k in range(3):
        lib = B.instance_update(models[0], lib, jnp.float32(f[k, 0]), phi[k], ee[k], ss[k])
    np.testing.assert_allclose(F.fused_joint_log_belief(single), B.joint_log_belief(lib), atol=2e-5)


def test_instance_fusion_with_masks_equals_sequential_per_detector(rng):
    models = (random_model(rng, n=2), random_model(rng, n=2))
    obs = observations(rng, 4, 2, 4, 2, 1)
    masks = np.array([[True, False], [True, True], [False, True], [True, False]])
    got = F.fused_joint_log_belief(fuse("instance", models, obs, masks))
    f, phi, ee, ss = obs
    want = 0.0
    for d, m in enumerate(models):
        sel = masks[:, d]
        want = want + brute_log_lik_instance(np_params(m), f[sel, d], phi[sel], ee[sel], ss[sel])
    np.testing.assert_allclose(got, normalise(want), atol=5e-5)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_constant_likelihood_and_empty_mask_leave_the_belief_unchanged(rng, kind):
    models = (random_model(rng), constant_model())
    b = fuse(kind, models[:1] + models[1:], observations(rng, 2, 2, 4, 2, 1))
    before = F.fused_joint_log_belief(b)
    after = F.fused_update(models, b, jnp.asarray([0.3, 1.7]), 2, 1, 0, mask=[False, True])
    np.testing.assert_allclose(F.fused_joint_log_belief(after), before, atol=2e-6)
    after = F.fused_update(models, b, jnp.asarray([jnp.nan, jnp.nan]), 1, 0, 0, mask=[False, False])
    np.testing.assert_allclose(F.fused_joint_log_belief(after), before, atol=0)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_detector_mixture_posterior_equals_fused_update(rng, kind):
    models = (random_model(rng, n=3), random_model(rng, n=2))
    b = fuse(kind, models, observations(rng, 2, 2, 4, 2, 1))
    for d in range(2):
        mix = F.detector_mixture(models, b, d, 3, 1, 0)
        np.testing.assert_allclose(float(jnp.exp(logsumexp(mix.log_weight))), 1.0, atol=1e-5)
        for f in (-1.2, 0.4, 2.0):
            mask = np.arange(2) == d
            after = F.fused_update(models, b, jnp.asarray([f, f]), 3, 1, 0, mask=mask)
            np.testing.assert_allclose(
                B.mixture_posterior(mix, f), F.fused_joint_log_belief(after), atol=3e-5
            )


def test_fused_update_jits_and_vmaps(rng):
    models = (random_model(rng), random_model(rng, n=1))
    b0 = F.fused_init("instance", models)
    fs = jnp.asarray(rng.normal(size=(5, 2)), jnp.float32)
    step = jax.jit(jax.vmap(lambda f, phi: F.fused_update(models, b0, f, phi, 1, 0)))
    out = step(fs, jnp.arange(5) % 4)
    for i in range(5):
        one = F.fused_update(models, b0, fs[i], i % 4, 1, 0)
        np.testing.assert_allclose(
            F.fused_joint_log_belief(jax.tree.map(lambda x, i=i: x[i], out)),
            F.fused_joint_log_belief(one),
            atol=1e-5,
        )


def test_bad_fusion_input(rng):
    m = random_model(rng)
    other = random_model(rng, a=6)
    with pytest.raises(ValueError, match="share the classes and the view grid"):
        F.fused_init("naive_bayes", (m, other))
    with pytest.raises(ValueError, match="unknown filter"):
        F.fused_init("kalman", (m,))
    b = F.fused_init("naive_bayes", (m, m))
    with pytest.raises(ValueError, match="one per detector"):
        F.fused_update((m, m), b, jnp.zeros(3), 0)
    with pytest.raises(ValueError, match="not finite"):
        F.fused_update((m, m), b, jnp.asarray([0.0, jnp.nan]), 0)


def test_fusion_checks_models_beliefs_and_views_where_they_enter(rng, key):
    m = random_model(rng)  # (N, O, A, E, S) = (2, 2, 4, 2, 1)
    few = ResponseModel(*(x[:1] for x in m))
    nb = F.fused_init("naive_bayes", (m, m))
    ia = F.fused_init("instance", (m, few))
    f = jnp.zeros(2)
    # a malformed model among the detectors
    nan = m._replace(mu=m.mu.at[1, 0, 0, 0, 0].set(jnp.nan))
    with pytest.raises(ValueError, match="mu contains NaN"):
        F.fused_init("naive_bayes", (m, nan))
    with pytest.raises(ValueError, match="sigma must be strictly positive"):
        F.fused_update((m, m._replace(sigma=0.0 * m.sigma)), nb, f, 0)
    # a belief of other models: another grid, parts swapped between detectors with other draws
    wide = random_model(rng, a=6)
    with pytest.raises(ValueError, match="belief was made with another model"):
        F.fused_update((wide, wide), nb, f, 0)
    with pytest.raises(ValueError, match=r"InstanceBelief.u_mean has shape \(2, 2, 4\)"):
        F.fused_update((few, m), ia, f, 0)
    with pytest.raises(ValueError, match="the belief has 2 detectors but 1 models"):
        F.fused_posterior_entropy((m,), ia, jnp.zeros(1), 0)
    # views outside the grid
    with pytest.raises(ValueError, match="robot azimuth index out of the view grid"):
        F.fused_update((m, m), nb, f, 4)
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        F.fused_expected_entropy(key, (m, m), nb, 0, 2, 0)
    three = jnp.asarray([[1, e, 0] for e in range(3)])
    with pytest.raises(ValueError, match="elevation index out of the view grid"):
        F.fused_expected_entropies(key, (m, m), nb, three)
    with pytest.raises(ValueError, match="PlannerConfig.planner: unknown planner 'plug_in'"):
        F.fused_expected_entropy(key, (m, m), nb, 0, 0, 0, PC("plug_in"))
    with pytest.raises(ValueError, match="detector index d=2 out of range"):
        F.detector_mixture((m, m), nb, 2, 0)


# ------------------------------------------------------------------------------------------------
# expected entropy after running all detectors


def brute_fused_expected_entropy(models, kind, obs, view, objective, grid=801):
    """E_{f1, f2}[H] on a fine 2-D trapezoid grid, with the joint of all responses computed directly.

    p(o, theta, F, f_1, f_2) ∝ prod_d p_d(F_d, f_d | o, theta) (uniform prior); p_d is a product of
    marginal predictives (naive Bayes) or a mean over draws of a multivariate normal whose covariance
    carries the instance effect, diag(sigma^2) + tau^2 11' (instance-aware).
    """
    f_prev, phi, ee, ss = obs
    allphi, alle, alls = np.r_[phi, view[0]], np.r_[ee, view[1]], np.r_[ss, view[2]]
    params = [np_params(m) for m in models]
    sds = [np.sqrt(sg**2 + t[..., None, None, None] ** 2) for _, sg, t in params]
    lo = min((mu - 8 * sd).min() for (mu, _, _), sd in zip(params, sds, strict=True))
    hi = max((mu + 8 * sd).max() for (mu, _, _), sd in zip(params, sds, strict=True))
    fgrid = np.linspace(lo, hi, grid)
    per_det = []
    for d, (mu, sigma, tau) in enumerate(params):
        n_n, n_o, n_a = mu.shape[:3]
        x = np.c_[np.broadcast_to(f_prev[:, d], (grid, len(phi))), fgrid]  # (G, K + 1)
        lp = np.zeros((n_o, n_a, grid))
        for o in range(n_o):
            for th in range(n_a):
                a = (allphi - th) % n_a
                m_vec = mu[:, o, a, alle, alls]  # (N, K + 1)
                sd = sigma[:, o, a, alle, alls]
                if kind == "naive_bayes":
                    marg = np.sqrt(sd**2 + tau[:, o, None] ** 2)
                    dens = stats.norm.pdf(x[:, None, :], m_vec[None], marg[None]).mean(axis=1)
                    lp[o, th] = np.log(dens).sum(axis=-1)
                else:
                    vals = [
                        stats.multivariate_normal(
                            m_vec[n], np.diag(sd[n] ** 2) + tau[n, o] ** 2
                        ).logpdf(x)
                        for n in range(n_n)
                    ]
                    lp[o, th] = logsumexp(np.stack(vals), axis=0) - np.log(n_n)
        per_det.append(lp)
    joint = per_det[0][:, :, :, None] + per_det[1][:, :, None, :]  # (O, A, G, G)
    log_pf = logsumexp(joint, axis=(0, 1))
    post = np.exp(joint - log_pf)
    if objective == "class":
        post = post.sum(1, keepdims=True)
    elif objective == "pose":
        post = post.sum(0, keepdims=True)
    h = -np.sum(np.where(post > 0, post * np.log(np.where(post > 0, post, 1.0)), 0.0), axis=(0, 1))
    dens = np.exp(log_pf - log_pf.max())  # p(f1, f2 | F) up to a constant, normalised below
    z = integrate.trapezoid(integrate.trapezoid(dens, fgrid, axis=1), fgrid)
    return integrate.trapezoid(integrate.trapezoid(dens * h, fgrid, axis=1), fgrid) / z


@pytest.mark.parametrize("kind", B.FILTERS)
@pytest.mark.parametrize("objective", ["joint", "class"])
def test_fused_quadrature_equals_brute_force_grid(rng, kind, objective):
    models = (random_model(rng, n=2, a=3, e=1), random_model(rng, n=1, a=3, e=1, tau=0.5))
    obs = observations(rng, 1, 2, 3, 1, 1)
    b = fuse(kind, models, obs)
    got = float(
        F.fused_expected_entropy(None, models, b, 2, 0, 0, PC("quadrature", objective, order=24))
    )
    want = brute_fused_expected_entropy(models, kind, obs, (2, 0, 0), objective)
    np.testing.assert_allclose(got, want, atol=2e-4)


@pytest.mark.parametrize("kind", B.FILTERS)
def test_running_all_detectors_never_does_worse_than_one(rng, kind):
    models = (random_model(rng, n=2), random_model(rng, n=2), random_model(rng, n=1))
    b = fuse(kind, models, observations(rng, 2, 3, 4, 2, 1))
    for view in ((0, 0, 0), (3, 1, 0)):
        fused = float(F.fused_expected_entropy(None, models[:2], b_two(kind, models, b), *view))
        for d in range(2):
            mix = F.detector_mixture(models, b, d, *view)
            single = float(P.quadrature_expected_entropy(mix, "joint", 16))
            assert fused <= single + 1e-4, (view, d, fused, single)
        all3 = float(F.fused_expected_entropy(None, models, b, *view, PC("quadrature", order=8)))
        assert all3 <= fused + 1e-3


def b_two(kind, models, b):
    """The same belief restricted to the first two detectors (the third one's evidence kept in the prior)."""
    if kind == "naive_bayes":
        return b
    log_prior = F.fused_joint_log_belief(F.FusedInstanceBelief(b.log_prior, b.parts[2:]))
    return F.FusedInstanceBelief(log_prior, b.parts[:2])


def test_uninformative_second_detector_gives_the_single_detector_value(rng):
    models = (random_model(rng, n=2), constant_model())
    for kind in B.FILTERS:
        b = fuse(kind, models, observations(rng, 2, 2, 4, 2, 1))
        both = float(F.fused_expected_entropy(None, models, b, 1, 1, 0, PC("quadrature", order=16)))
        mix = F.detector_mixture(models, b, 0, 1, 1, 0)
        one = float(P.quadrature_expected_entropy(mix, "joint", 32))
        np.testing.assert_allclose(both, one, atol=2e-4)


def test_sampled_fused_converges_to_quadrature(rng, key):
    models = (random_model(rng, n=2), random_model(rng, n=2))
    b = fuse("instance", models, observations(rng, 1, 2, 4, 2, 1))
    exact = float(F.fused_expected_entropy(None, models, b, 2, 0, 0, PC("quadrature", order=24)))
    f = F._sample_fused(jax.random.fold_in(key, 1), models, b, 2, 0, 0, 8192)
    h = np.asarray(F.fused_posterior_entropy(models, b, f, 2, 0, 0))
    # the sample's own mean is within 4 standard errors of the exact value
    assert abs(h.mean() - exact) < 4 * h.std() / np.sqrt(h.size)
    errors = {}
    for m in (32, 4096):
        keys = jax.random.split(jax.random.fold_in(key, m), 6)
        est = np.array(
            [
                F.fused_expected_entropy(k, models, b, 2, 0, 0, PC("sampled", n_samples=m))
                for k in keys
            ]
        )
        assert np.all(np.abs(est - exact) < 5 * h.std() / np.sqrt(m) + 1e-4), (m, est, exact)
        errors[m] = float(np.sqrt(np.mean((est - exact) ** 2)))
    assert errors[4096] < errors[32]
