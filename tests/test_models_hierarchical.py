"""Hierarchical viewpoint model: closed-form marginal, bases, prior predictive, parameter recovery."""

import json
import warnings

import jax
import numpy as np
import pytest
from scipy import integrate, stats

from scrppl.models import transforms
from scrppl.models.data import extract_view_data, make_view_data
from scrppl.models.diagnostics import DiagnosticsWarning
from scrppl.models.fit import fit_hierarchical
from scrppl.models.hierarchical import (
    CENTERED_COEF_MIN_SNR,
    LOW_NOISE_RATIO,
    RELATIVE_NOISE_FLOOR,
    azimuth_profile_snr,
    choose_noncentered,
    choose_target_accept,
    fourier_basis,
    make_model,
    model_args,
    noise_floor,
    prior_predictive,
    sum_to_zero_basis,
)
from scrppl.models.marginal import instance_log_marginal, instance_log_marginal_stats, view_stats
from scrppl.models.mcmc import SamplerConfig
from scrppl.models.predictive import to_response_model
from scrppl.models.simulate import random_true_model, simulate_response_table
from scrppl.views import ViewGrid

#: Shared with tests/test_models_cli.py so that the compiled sampler is reused in one process.
RECOVERY_GRID = ViewGrid(8, (10.0,), (1.0,))
RECOVERY_SAMPLER = SamplerConfig(num_warmup=400, num_samples=400, num_chains=4, chunk=400)


def test_marginal_equals_quadrature_over_the_instance_effect(rng):
    n = 9
    y, m = rng.normal(size=n), rng.normal(size=n)
    sigma = rng.uniform(0.3, 1.2, n)
    observed = rng.random(n) > 0.3
    tau = 0.7

    def integrand(u):
        lp = stats.norm.logpdf(y[observed], m[observed] + u, sigma[observed]).sum()
        return np.exp(lp + stats.norm.logpdf(u, 0, tau))

    brute = np.log(integrate.quad(integrand, -12, 12, epsabs=0, epsrel=1e-11, limit=200)[0])
    got = instance_log_marginal(y[None], m[None], sigma[None], np.array([tau]), observed[None])
    np.testing.assert_allclose(float(got[0]), brute, rtol=1e-5)
    cov = np.diag(sigma[observed] ** 2) + tau**2
    dense = stats.multivariate_normal(m[observed], cov).logpdf(y[observed])
    np.testing.assert_allclose(float(got[0]), dense, rtol=1e-5)
    # tau = 0: the views are independent
    got0 = instance_log_marginal(y[None], m[None], sigma[None], np.zeros(1), observed[None])
    np.testing.assert_allclose(
        float(got0[0]), stats.norm.logpdf(y, m, sigma)[observed].sum(), rtol=1e-5
    )


def test_bases():
    for n_az in (2, 5, 8):
        basis, harmonic = fourier_basis(n_az)
        assert basis.shape == (n_az, n_az - 1) and harmonic.min() >= 1
        full = np.column_stack([np.ones(n_az), basis])
        assert np.linalg.matrix_rank(full) == n_az  # spans every function of A bins
        gram = full.T @ full
        np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0, atol=1e-9)  # orthogonal
    for n in (2, 3, 9):
        h = sum_to_zero_basis(n)
        np.testing.assert_allclose(h.T @ h, np.eye(n - 1), atol=1e-12)
        np.testing.assert_allclose(h.sum(0), 0, atol=1e-12)


def test_prior_predictive(key):
    rng = np.random.default_rng(0)
    y = rng.normal(2.0, 3.0, size=(6, 8, 2, 1))
    obs = np.ones(y.shape, bool)
    obs[0, 3] = False
    data = make_view_data(np.where(obs, y, np.nan), [1, 1, 1, 0, 0, 0], [0, 0, 0, 0, 1, 1], obs)
    draws = prior_predictive(key, data, n_draws=400)
    assert draws["y"].shape == (400, 6, 8, 2, 1) and draws["mu"].shape == (400, 2, 8, 2, 1)
    assert np.isnan(draws["y"][:, 0, 3]).all() and np.isfinite(draws["y"][:, 1:]).all()
    assert (draws["sigma"] > 0).all() and (draws["tau"] >= 0).all()
    # the responses scatter around the drawn means: E[y - mu[o]] = 0
    resid = draws["y"][:, 3:, :, 0, 0] - draws["mu"][:, 0, None, :, 0, 0]
    spread = np.sqrt(
        draws["sigma"][:, 0] ** 2 + draws["tau"][:, 0, None] ** 2 + draws["kappa"][:, None] ** 2
    )
    z = resid.mean(axis=(1, 2)) / (spread.mean(1) / np.sqrt(3))  # three instances, correlated views
    assert abs(z.mean()) < 4 / np.sqrt(400) * 3
    # standardised priors: the prior mean response sits at the data's location
    assert abs(np.median(draws["mu"]) - y.mean()) < 0.5 * y.std()


@pytest.mark.slow
def test_parameter_recovery():
    """True mu, sigma and tau lie inside their 90% posterior intervals at about the nominal rate."""
    inside, total = 0, 0
    for seed in (11, 12):
        truth = random_true_model(jax.random.key(seed), RECOVERY_GRID, kappa=0.0)
        table = simulate_response_table(
            jax.random.key(100 + seed),
            {("dpm", "c0"): truth},
            ["c0", "c1"],
            10,
            RECOVERY_GRID,
            {"fit": 6, "test": 4},
        )
        data, meta = extract_view_data(table, "dpm", "c0")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # short chains: diagnostics are checked below instead
            tree = fit_hierarchical(
                jax.random.key(seed),
                data,
                meta,
                RECOVERY_SAMPLER,
                retry_longer=None,
                progress=False,
            )
        post = tree["posterior"].to_dataset()
        assert int(tree["sample_stats"]["diverging"].values.sum()) <= 4
        assert float(post["mu"].std(("chain", "draw")).max()) > 0
        for name, true in (
            ("mu", truth.mu),
            ("sigma", truth.sigma[:, :, 0, 0]),
            ("tau", truth.tau),
        ):
            draws = np.asarray(post[name].values).reshape((-1,) + np.shape(true))
            lo, hi = np.quantile(draws, [0.05, 0.95], axis=0)
            inside += int(((true >= lo) & (true <= hi)).sum())
            total += np.size(true)
        model = to_response_model(tree)
        assert model.mu.shape == (1600, 2, 8, 1, 1)
    rate = inside / total
    assert 0.75 <= rate <= 1.0, rate


def test_marginal_from_sufficient_statistics_equals_the_dense_normal(rng):
    n_inst, n_az, n_el, n_sc = 7, 8, 3, 2
    z = rng.normal(1.0, 2.0, size=(n_inst, n_az, n_el, n_sc))
    observed = rng.random(z.shape) > 0.2
    o = np.array([0, 1, 0, 0, 1, 1, 0])
    mu = rng.normal(size=(2, n_az, n_el, n_sc))
    sigma = rng.uniform(0.3, 2.0, size=(2, n_az))
    tau = np.array([0.5, 1.3])
    offset = rng.normal(size=n_inst) * (o == 0)
    got = np.asarray(
        instance_log_marginal_stats(view_stats(z, observed, o), mu, sigma, tau, offset)
    )
    for i in range(n_inst):
        sel = observed[i]
        mean = (mu[o[i]] + offset[i])[sel]
        sd = np.broadcast_to(sigma[o[i]][:, None, None], sel.shape)[sel]
        cov = np.diag(sd**2) + tau[o[i]] ** 2
        dense = stats.multivariate_normal(mean, cov).logpdf(z[i][sel])
        np.testing.assert_allclose(got[i], dense, rtol=2e-5)


def _block_cov(sd, tau, omega, az):
    """Dense covariance: noise, the instance effect, the instance x azimuth effect within azimuths."""
    return np.diag(sd**2) + tau**2 + omega**2 * (az[:, None] == az[None, :])


def test_marginal_with_an_instance_by_azimuth_effect_equals_the_dense_normal(rng):
    n_inst, n_az, n_el, n_sc = 6, 5, 3, 2
    z = rng.normal(1.0, 2.0, size=(n_inst, n_az, n_el, n_sc))
    observed = rng.random(z.shape) > 0.25
    o = np.array([0, 1, 0, 1, 1, 0])
    mu = rng.normal(size=(2, n_az, n_el, n_sc))
    sigma = rng.uniform(0.3, 2.0, size=(2, n_az))
    tau, omega = np.array([0.5, 1.3]), np.array([0.8, 0.4])
    offset = rng.normal(size=n_inst) * (o == 0)
    az = np.broadcast_to(np.arange(n_az)[:, None, None], z.shape[1:])
    stats_form = np.asarray(
        instance_log_marginal_stats(view_stats(z, observed, o), mu, sigma, tau, offset, omega)
    )
    m = mu[o] + offset[:, None, None, None]
    sd = np.broadcast_to(sigma[o][:, :, None, None], z.shape)
    dense_form = np.asarray(instance_log_marginal(z, m, sd, tau[o], observed, omega=omega[o]))
    for i in range(n_inst):
        sel = observed[i]
        cov = _block_cov(sd[i][sel], tau[o[i]], omega[o[i]], az[sel])
        want = stats.multivariate_normal(m[i][sel], cov).logpdf(z[i][sel])
        np.testing.assert_allclose(stats_form[i], want, rtol=2e-5)
        np.testing.assert_allclose(dense_form[i], want, rtol=2e-5)
    # omega = 0 is the model without the effect; a larger omega is a different density
    zero = instance_log_marginal_stats(
        view_stats(z, observed, o), mu, sigma, tau, offset, 0 * omega
    )
    plain = instance_log_marginal_stats(view_stats(z, observed, o), mu, sigma, tau, offset)
    np.testing.assert_allclose(np.asarray(zero), np.asarray(plain), rtol=1e-6)
    assert np.all(np.abs(np.asarray(plain) - stats_form) > 1e-3)
    with pytest.raises(ValueError, match="azimuth axis"):
        instance_log_marginal(
            z[:, 0, 0, 0], m[:, 0, 0, 0], 1.0, tau[o], observed[:, 0, 0, 0], omega[o]
        )


def test_the_model_with_an_instance_by_azimuth_effect_has_the_block_normal_likelihood(rng):
    """make_model(azimuth_effect=True): with every parameter fixed, the marginal model's likelihood is
    the sum over instances of the dense normal with tau^2 everywhere and omega^2 within each azimuth
    (standardised scale), for the stats form and the plain form alike; the site azimuth_sd is sampled."""
    from numpyro.handlers import seed, substitute, trace

    grid = ViewGrid(4, (0.0, 20.0), (1.0,))
    table = simulate_response_table(
        jax.random.key(3),
        {("dpm", "c0"): random_true_model(jax.random.key(4), grid)},
        ["c0", "c1", "c2"],
        3,
        grid,
        {"fit": 3},
    )
    data, _ = extract_view_data(table, "dpm", "c0")
    args = model_args(data)
    loc, scale = float(args[4]), float(args[5])
    z = (np.asarray(data.y) - loc) / scale
    model = make_model(True, (), azimuth_effect=True)
    tr = trace(seed(model, 0)).get_trace(*args)
    assert "azimuth_sd" in tr and tr["omega"]["value"].shape == (2,)
    params = {k: tr[k]["value"] for k in tr if tr[k]["type"] == "sample"}
    plain = trace(substitute(model, data=params)).get_trace(*args[:7], None)
    got = {
        "stats": float(tr["likelihood"]["fn"].log_factor),
        "plain": float(plain["likelihood"]["fn"].log_factor),
    }
    mu = np.asarray((tr["mu"]["value"] - loc) / scale)
    sigma = np.asarray(tr["sigma"]["value"] / scale)
    tau = np.asarray(tr["tau"]["value"] / scale)
    omega = np.asarray(tr["omega"]["value"] / scale)
    o = np.asarray(data.o)
    offset = np.zeros(len(o))
    if "category_contrast" in tr:
        basis = sum_to_zero_basis(data.neg_onehot.shape[1])
        offset = np.asarray(data.neg_onehot) @ (
            basis @ np.asarray(tr["category_contrast"]["value"])
        )
    obs = np.asarray(data.observed)
    az = np.broadcast_to(np.arange(obs.shape[1])[:, None, None], obs.shape[1:])
    want = 0.0
    for i in range(len(o)):
        sel = obs[i]
        sd = np.broadcast_to(sigma[o[i]][:, None, None], sel.shape)[sel]
        cov = _block_cov(sd, tau[o[i]], omega[o[i]], az[sel])
        want += stats.multivariate_normal((mu[o[i]] + offset[i])[sel], cov).logpdf(z[i][sel])
    np.testing.assert_allclose(got["stats"], want, rtol=1e-4)
    np.testing.assert_allclose(got["plain"], want, rtol=1e-4)


def test_noise_floor_is_the_rounding_error_of_one_count():
    step = transforms.apply("anscombe", 1.0) - transforms.apply("anscombe", 0.0)
    assert transforms.resolution_sd("anscombe") == pytest.approx(step / np.sqrt(12))
    assert transforms.resolution_sd("identity") == 0.0
    with pytest.raises(ValueError, match="unknown response transform"):
        transforms.resolution_sd("sqrt")


def _potential_along_sigma(floor: float, log_sigmas) -> np.ndarray:
    """Potential energy of identical responses as the noise sd shrinks (all else fixed)."""
    from numpyro.infer.util import potential_energy

    y = np.full((8, 8, 1, 1), 1.2247)  # zero counts on the Anscombe scale, from every view
    y[:4] += 0.5
    data = make_view_data(y, [1, 1, 1, 1, 0, 0, 0, 0])
    args = model_args(data, loc=1.0, scale=1.0, floor=floor)
    model = make_model(True, ())
    out = []
    for ls in log_sigmas:
        params = {
            "alpha": np.array([0.2247, 0.7247]),
            "eta": np.array([1.0, 1.0]),
            "coef": np.zeros((2, 7)),
            "sigma_class": np.exp(np.array([ls, ls])),
            "sigma_spread": np.array([0.5, 0.5]),
            "log_sigma_contrast": np.zeros((2, 7)),
            "instance_sd": np.array([1e-9, 1e-9]),
        }
        out.append(float(potential_energy(model, args, {}, _unconstrain(model, args, params))))
    return np.array(out)


def _unconstrain(model, args, params):
    from numpyro.infer.util import unconstrain_fn

    return unconstrain_fn(model, args, {}, params)


def test_noise_floor_bounds_the_likelihood_of_identical_counts():
    log_sigmas = [-2.0, -4.0, -6.0, -8.0]
    without = _potential_along_sigma(0.0, log_sigmas)
    assert np.all(np.diff(without) < -10)  # an unbounded spike: sigma -> 0 is ever more likely
    floored = _potential_along_sigma(transforms.resolution_sd("anscombe"), log_sigmas)
    # with the floor the likelihood no longer changes; only the prior on sigma pulls it back
    assert np.all(np.diff(floored) > 0)


def test_noise_floor_is_on_the_response_scale_at_any_standardisation(rng):
    # The floor is the rounding error of one count on the *response* scale, while the model works on
    # responses standardised by `scale`: at scale 1 (the test above) a floor applied on the wrong
    # scale is invisible. At other scales the reported sd must still be sqrt((scale sigma)^2 + floor^2)
    # and the likelihood must be that of the responses under the reported parameters.
    from numpyro import handlers

    floor = transforms.resolution_sd("anscombe")
    y = rng.normal(1.0, 0.5, size=(6, 8, 1, 1))
    observed = rng.random(y.shape) > 0.2
    o = np.array([1, 1, 1, 0, 0, 0])
    data = make_view_data(np.where(observed, y, np.nan), o, observed=observed)
    model = make_model(True, ())
    for scale in (4.0, 0.25, 1.0):
        args = model_args(data, loc=0.7, scale=scale, floor=floor)
        for sigma_class in (1e-6, 0.3):  # on the standardised scale
            params = {
                "alpha": np.array([0.1, 0.6]),
                "eta": np.ones(2),
                "coef": rng.normal(0.0, 0.3, size=(2, 7)),
                "sigma_class": np.full(2, sigma_class),
                "sigma_spread": np.full(2, 0.5),
                "log_sigma_contrast": np.zeros((2, 7)),
                "instance_sd": np.array([0.2, 0.4]),
            }
            trace = handlers.trace(handlers.substitute(handlers.seed(model, 0), params))
            tr = trace.get_trace(*args)
            sigma = np.asarray(tr["sigma"]["value"], np.float64)  # (2, A), response scale
            want = np.sqrt((scale * sigma_class) ** 2 + floor**2)
            np.testing.assert_allclose(sigma, want, rtol=1e-5, err_msg=f"scale {scale}")
            mu = np.asarray(tr["mu"]["value"], np.float64)
            tau = np.asarray(tr["tau"]["value"], np.float64)
            dense = 0.0
            for i in range(len(o)):
                sel = observed[i]
                sd = np.broadcast_to(sigma[o[i]][:, None, None], sel.shape)[sel]
                cov = np.diag(sd**2) + tau[o[i]] ** 2
                dense += stats.multivariate_normal(mu[o[i]][sel], cov).logpdf(y[i][sel])
            site = tr["likelihood"]
            ll = float(site["fn"].log_prob(site["value"]))  # log density of the standardised y
            np.testing.assert_allclose(ll - observed.sum() * np.log(scale), dense, rtol=1e-5)


def test_choose_noncentered_per_class():
    def design(n_pos, n_neg, n_views):
        o = np.r_[np.ones(n_pos, int), np.zeros(n_neg, int)]
        y = np.zeros((n_pos + n_neg, 8, n_views, 1))
        return make_view_data(y, o)

    assert "coef" not in choose_noncentered(design(6, 30, 9))  # >= 50 responses per cell
    assert choose_noncentered(design(3, 30, 9))[-1] == "coef[1]"  # thin positives only
    assert choose_noncentered(design(3, 3, 1))[-1] == "coef"
    with pytest.raises(ValueError, match="cannot reparameterise"):
        make_model(True, ("coef[2]",))


def test_a_profile_lost_in_the_noise_is_non_centred_however_many_responses(rng):
    """Each cell of both classes has >= 50 responses; the absent class's profile is a cosine of
    amplitude ``amp`` in unit noise. Its signal-to-noise ratio is the sd of the 8 cell means over their
    standard error, known in closed form: sd of the cosine (amp / sqrt 2) times sqrt(n) per cell."""
    n_pos, n_neg, n_views = 6, 30, 9
    o = np.r_[np.ones(n_pos, int), np.zeros(n_neg, int)]
    az = np.cos(2 * np.pi * np.arange(8) / 8)
    noise = rng.normal(size=(n_pos + n_neg, 8, n_views, 1))

    def data(amp_neg, amp_pos=3.0):
        y = np.empty_like(noise)
        for cls, amp in ((0, amp_neg), (1, amp_pos)):
            part = noise[o == cls]  # each (class, azimuth) cell: mean exactly amp cos, sd exactly 1
            part = (part - part.mean(axis=(0, 2, 3), keepdims=True)) / part.std(
                axis=(0, 2, 3), keepdims=True
            )
            y[o == cls] = part + amp * az[None, :, None, None]
        return make_view_data(y, o)

    n_cell = n_neg * n_views
    for amp in (0.05, 0.3):
        np.testing.assert_allclose(
            azimuth_profile_snr(data(amp))[0], amp / np.sqrt(2) * np.sqrt(n_cell), rtol=1e-9
        )
    weak = CENTERED_COEF_MIN_SNR / 2 / np.sqrt(n_cell) * np.sqrt(2)  # half the threshold
    strong = 2 * CENTERED_COEF_MIN_SNR / np.sqrt(n_cell) * np.sqrt(2)  # twice it
    assert choose_noncentered(data(weak))[-1] == "coef[0]"
    assert "coef" not in "".join(choose_noncentered(data(strong)))
    assert choose_noncentered(data(weak, amp_pos=weak * np.sqrt(n_neg / n_pos)))[-1] == "coef"
    # noiseless classes: infinitely far above the threshold
    assert np.isinf(azimuth_profile_snr(make_view_data(np.zeros((4, 8, 1, 1)), [1, 1, 0, 0]))).all()


def test_noise_floor_is_the_larger_of_rounding_and_a_fraction_of_the_spread(rng):
    o = np.r_[np.ones(3, int), np.zeros(6, int)]
    y = rng.normal(0.0, 0.4, size=(9, 8, 1, 1))
    data = make_view_data(y, o)
    sd = float(y.std())
    # a real-valued score: 5 % of the responses' sd
    assert noise_floor(data, "identity") == pytest.approx(RELATIVE_NOISE_FLOOR * sd)
    # counts: the rounding floor, larger than 5 % of a spread of 0.4
    assert noise_floor(data, "anscombe") == transforms.resolution_sd("anscombe")
    big = make_view_data(y * 100.0, o)
    assert noise_floor(big, "anscombe") == pytest.approx(RELATIVE_NOISE_FLOOR * sd * 100.0)


def test_a_nearly_noiseless_cell_starts_the_fit_at_the_higher_acceptance_target(rng):
    o = np.r_[np.ones(3, int), np.zeros(6, int)]
    y = rng.normal(0.0, 1.0, size=(9, 8, 1, 1))
    noisy = make_view_data(y, o)
    assert choose_target_accept(noisy, 0.0, 0.95, 0.99) == 0.95
    quiet = y.copy()
    quiet[o == 1, 3] = 0.2 + 1e-3 * rng.normal(size=(3, 1, 1))  # one positive cell nearly constant
    data = make_view_data(quiet, o)
    assert choose_target_accept(data, 0.0, 0.95, 0.99) == 0.99
    # a floor as large as the threshold makes even that cell noisy enough
    overall = float(quiet.std())
    assert choose_target_accept(data, LOW_NOISE_RATIO * overall * 1.01, 0.95, 0.99) == 0.95
    # a cell with one response has no spread to measure: it does not count
    one = y.copy()
    observed = np.ones(y.shape, bool)
    observed[o == 1, 3] = False
    observed[np.flatnonzero(o == 1)[0], 3] = True
    assert choose_target_accept(make_view_data(one, o, observed=observed), 0.0, 0.95, 0.99) == 0.95


def test_partial_noncentring_keeps_the_prior(key):
    from numpyro.infer import Predictive

    data = make_view_data(np.zeros((4, 8, 1, 1)), [1, 1, 0, 0])
    args = model_args(data, loc=0.0, scale=1.0)
    k_harm = fourier_basis(8)[1]
    for noncentered in ((), ("coef[1]",), ("coef",)):
        draws = Predictive(make_model(True, noncentered), num_samples=4000)(key, *args)
        scaled = draws["coef"] / (draws["eta"][:, :, None] / k_harm)  # standard normal a priori
        np.testing.assert_allclose(scaled.std(axis=0), 1.0, atol=0.08)
        np.testing.assert_allclose(scaled.mean(axis=0), 0.0, atol=0.08)


def test_a_failed_fit_is_refitted_at_a_higher_acceptance_target_then_noncentred_then_longer(
    key, monkeypatch
):
    """The retry logic of fit_hierarchical, with the sampler replaced by prior draws."""
    from numpyro.infer import Predictive

    import scrppl.models.fit as fit_module

    data = make_view_data(np.random.default_rng(0).normal(size=(6, 8, 1, 1)), [1, 1, 1, 0, 0, 0])
    meta = {"detector": "dpm", "target": "c0", "transform": "identity"}
    model = make_model(True, choose_noncentered(data))
    prior = Predictive(model, num_samples=4 * 500)(key, *model_args(data))
    calls, lengths = [], []
    n_bad = [1]

    n_args = []

    def fake_run_nuts(key, model, args, config, progress=True, desc=""):
        calls.append(config.target_accept_prob)
        n_args.append(len(args))
        lengths.append((config.num_warmup, config.num_samples))
        samples = {k: np.asarray(v).reshape((4, 500) + v.shape[1:]) for k, v in prior.items()}
        if len(calls) <= n_bad[0]:  # chains stuck in different places: R-hat fails
            samples = {
                k: v + np.arange(4.0).reshape((4, 1) + (1,) * (v.ndim - 2))
                for k, v in samples.items()
            }
        stats = {
            name: np.zeros((4, 500), dtype)
            for name, dtype in (("diverging", bool), ("energy", float), ("n_steps", int))
        }
        stats["energy"] = np.random.default_rng(len(calls)).normal(size=(4, 500))
        return samples, stats

    monkeypatch.setattr(fit_module, "run_nuts", fake_run_nuts)
    config = SamplerConfig(num_warmup=10, num_samples=500, num_chains=4)
    tree = fit_hierarchical(key, data, meta, config, progress=False)
    assert calls == [config.target_accept_prob, fit_module.RETRY_ACCEPT]
    attempts = json.loads(tree.attrs["meta"])["attempts"]
    assert [a["ok"] for a in attempts] == [False, True]
    assert json.loads(tree.attrs["diagnostics"])["ok"]
    calls.clear()
    with pytest.warns(DiagnosticsWarning):  # without a retry the failure is reported
        fit_hierarchical(key, data, meta, config, retry_accept=None, progress=False)
    assert calls == [config.target_accept_prob]
    # a retry that fails too gets every coefficient non-centred, then longer chains, and no more; a split
    # parameterisation (one class non-centred) gets 0.99 and every coefficient non-centred at once.
    # Cases: (start parameterisation, failing attempts, attempts made, attempts before the switch)
    k = fit_module.RETRY_LONGER
    centred = fit_module.DEFAULT_NONCENTERED  # the azimuth coefficients centred
    split = centred + ("coef[1]",)
    cases = [
        (centred, 2, 3, 2),
        (centred, 3, 4, 2),
        (centred, 4, 4, 2),
        (split, 1, 2, 1),
        (split, 2, 3, 1),
    ]
    for start, bad, n_calls, n_start in cases:
        calls.clear(), lengths.clear()
        n_bad[0] = bad
        tree = fit_hierarchical(
            key, data, meta, config, noncentered=start, pool_noise=False, progress=False, warn=False
        )
        assert calls == [config.target_accept_prob] + [fit_module.RETRY_ACCEPT] * (n_calls - 1)
        n_short = n_start + 1  # the attempts before the longer chains
        assert lengths == [(10, 500)] * min(n_calls, n_short) + [(10 * k, 500 * k)] * max(
            0, n_calls - n_short
        )
        attempts = json.loads(tree.attrs["meta"])["attempts"]
        assert [a["ok"] for a in attempts] == [False] * (n_calls - 1) + [n_calls > bad]
        assert [sorted(a["noncentered"]) for a in attempts] == [sorted(start)] * n_start + [
            sorted(fit_module.RETRY_NONCENTERED)
        ] * (n_calls - n_start)
        # the saved parameterisation is that of the attempt returned
        assert sorted(json.loads(tree.attrs["meta"])["noncentered"]) == sorted(
            fit_module.RETRY_NONCENTERED
        )
    calls.clear()
    fit_hierarchical(
        key,
        data,
        meta,
        config,
        noncentered=centred,
        retry_longer=None,
        pool_noise=False,
        progress=False,
        warn=False,
    )
    assert len(calls) == 3
    # a fit already fully non-centred goes straight from the 0.99 retry to longer chains
    calls.clear(), lengths.clear()
    n_bad[0] = 3
    thin = choose_noncentered(data)
    assert sorted(thin) == sorted(fit_module.RETRY_NONCENTERED)
    fit_hierarchical(
        key, data, meta, config, noncentered=thin, pool_noise=False, progress=False, warn=False
    )
    assert lengths == [(10, 500), (10, 500), (10 * k, 500 * k)]
    # the last resort: one noise sd per class, with the longer chains, passed to the model as a mask
    calls.clear(), lengths.clear(), n_args.clear()
    n_bad[0] = 3
    tree = fit_hierarchical(key, data, meta, config, noncentered=thin, progress=False, warn=False)
    attempts = json.loads(tree.attrs["meta"])["attempts"]
    assert [a["pooled_noise"] for a in attempts] == [[], [], [], [0, 1]]
    assert [a["ok"] for a in attempts] == [False, False, False, True]
    assert lengths[-1] == (10 * k, 500 * k) and n_args == [8, 8, 8, 9]
    assert json.loads(tree.attrs["meta"])["pooled_noise"] == [0, 1]
    # a nearly noiseless cell: the first attempt already runs at the retry's target, and a failure goes
    # on to the next remedy (here longer chains) instead of repeating 0.99
    quiet = np.asarray(data.y).copy()
    quiet[:3, 2] = 0.5 + 1e-4 * np.arange(3)[:, None, None]
    quiet_data = make_view_data(quiet, [1, 1, 1, 0, 0, 0])
    calls.clear(), lengths.clear()
    n_bad[0] = 1
    tree = fit_hierarchical(key, quiet_data, meta, config, noncentered=thin, progress=False)
    assert calls == [fit_module.RETRY_ACCEPT, fit_module.RETRY_ACCEPT]
    assert lengths == [(10, 500), (10 * k, 500 * k)]
    assert json.loads(tree.attrs["meta"])["attempts"][0]["target_accept_prob"] == 0.99
    calls.clear()
    n_bad[0] = 0
    fit_hierarchical(key, quiet_data, meta, config, choose_accept=False, progress=False)
    assert calls == [config.target_accept_prob]


def test_azimuth_noise_mask_gives_a_class_one_noise_sd(key):
    """``azimuth_noise`` 0 for a class: its noise sd is the same at every azimuth (the last resort of the
    retry ladder); the other class keeps its azimuth-varying noise."""
    from numpyro.handlers import seed, substitute, trace

    data = make_view_data(np.random.default_rng(1).normal(size=(6, 8, 1, 1)), [1, 1, 1, 0, 0, 0])
    args = model_args(data)
    model = make_model(True, choose_noncentered(data))
    tr = trace(seed(model, key)).get_trace(*args)
    contrast = {"log_sigma_contrast": (np.full((2, 7), 0.3) * np.arange(1, 8)).astype(np.float32)}
    for mask, flat in (((1.0, 1.0), ()), ((1.0, 0.0), (1,)), ((0.0, 0.0), (0, 1))):
        sub = substitute(seed(make_model(True, ()), key), data=contrast)
        sigma = np.asarray(
            trace(sub).get_trace(*args, np.asarray(mask, np.float32))["sigma"]["value"]
        )
        for cls in (0, 1):
            assert (np.ptp(sigma[cls]) < 1e-6) == (cls in flat), (mask, cls)
    assert "sigma" in tr
