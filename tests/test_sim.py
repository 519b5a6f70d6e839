"""Simulator, trial runner, metrics and the paired experiment on a small synthetic response table."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from scrppl import sim
from scrppl.models.io import ViewpointModel
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig as PC
from scrppl.responses import empty_response_table
from scrppl.sim import metrics as M
from scrppl.views import ViewGrid

A, E, S = 8, 2, 1
CHUNK = 16  # one chunk shape for every test, so that compiled runners are shared between tests
CATS = ["car", "bike", "shoe"]
N_INST = 4


def mu_present():
    # the target is recognisable from the side (a = 2, 6), barely from the front and back
    return 3.0 * np.abs(np.sin(2 * np.pi * np.arange(A) / A))[:, None, None] * np.ones((A, E, S))


@pytest.fixture(scope="module")
def table():
    rng = np.random.default_rng(7)
    split = np.array([["test", "test", "fit", "test"]] * len(CATS), dtype=object)
    ds = empty_response_table(
        ["dpm"], ["car"], CATS, N_INST, ViewGrid(A, (10.0, 30.0), (1.0,)), split
    )
    score = rng.normal(0.0, 0.5, size=ds["score"].shape)
    score[0, 0, 0] += mu_present()
    score[0, 0, 1, 3, :, 1] = np.nan  # bike 3 lacks the upper elevation
    score[0, 0, 2, 1, 5, 0] = np.nan  # shoe 1 lacks one view of the lower ring
    ds["score"][:] = score
    return ds


@pytest.fixture(scope="module")
def model():
    mu = np.stack([np.zeros((A, E, S)), mu_present()])[None]
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, 0.5, jnp.float32), jnp.zeros((1, 2))
    )


def test_make_trials_is_deterministic_and_draws_held_out_instances(table, key):
    t1 = sim.make_trials(key, table, "dpm", "car", 41, positive_fraction=0.25)
    t2 = sim.make_trials(key, table, "dpm", "car", 41, positive_fraction=0.25)
    for a, b in zip(t1, t2, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    label = np.asarray(t1.label)
    assert label.sum() == round(0.25 * 41)
    cat, inst = np.asarray(t1.category), np.asarray(t1.instance)
    np.testing.assert_array_equal(label, cat == 0)
    split = table["split"].values
    assert np.all(split[cat, inst] == "test")
    start = np.asarray(t1.start)
    assert start[:, 0].min() >= 0 and start[:, 0].max() < A
    # the start ring is complete for the chosen instance
    raw = table["score"].values[0, 0]
    for t in range(41):
        assert not np.isnan(raw[cat[t], inst[t], :, start[t, 1], start[t, 2]]).any()
    # missing views are flagged, never filled with a number that could be used
    avail = np.asarray(t1.available)
    np.testing.assert_array_equal(avail, ~np.isnan(raw[cat, inst]))
    other = sim.make_trials(
        jax.random.fold_in(key, 1), table, "dpm", "car", 41, positive_fraction=0.25
    )
    assert not np.array_equal(np.asarray(other.pose), np.asarray(t1.pose))


def test_make_trials_applies_transform(table, key):
    t_raw = sim.make_trials(key, table, "dpm", "car", 10)
    t_tr = sim.make_trials(key, table, "dpm", "car", 10, transform=lambda x: 2.0 * x + 1.0)
    ok = np.asarray(t_raw.available)
    np.testing.assert_allclose(
        np.asarray(t_tr.responses)[ok],
        2.0 * np.asarray(t_raw.responses)[ok] + 1.0,
        rtol=1e-6,
        atol=1e-6,
    )


def test_observe_returns_the_response_at_the_relative_azimuth(table, key):
    trials = sim.make_trials(key, table, "dpm", "car", 12)
    raw = table["score"].sel(detector="dpm", target="car")
    for t in range(12):
        c = CATS[int(trials.category[t])]
        i = int(trials.instance[t])
        for phi in range(A):
            rel = (phi - int(trials.pose[t])) % A
            want = float(raw.sel(category=c, instance=i, azimuth=rel, elevation=0, scale=0))
            if np.isnan(want):
                with pytest.raises(ValueError, match="has no image"):
                    sim.observe(trials, t, (phi, 0, 0))
            else:
                np.testing.assert_allclose(sim.observe(trials, t, (phi, 0, 0)), want, rtol=1e-6)
    with pytest.raises(ValueError, match="outside the view grid"):
        sim.observe(trials, 0, (A, 0, 0))


def test_bad_simulator_input(table, key, model):
    with pytest.raises(ValueError, match="target 'plane' is not in the response table"):
        sim.make_trials(key, table, "dpm", "plane", 4)
    with pytest.raises(ValueError, match="no positive instances"):
        sim.make_trials(key, table, "dpm", "car", 4, split="train")
    with pytest.raises(ValueError, match="non-finite"):
        sim.make_trials(key, table, "dpm", "car", 4, transform=lambda x: np.where(x > 1, np.inf, x))
    trials = sim.make_trials(key, table, "dpm", "car", 4)
    other_grid = ResponseModel(*(x[:, :, :4] if x.ndim == 5 else x for x in model))
    with pytest.raises(ValueError, match="view grid"):
        sim.run_trials(key, other_grid, trials)
    with pytest.raises(ValueError, match="n_steps"):
        sim.run_trials(key, model, trials, n_steps=A + 1)
    start = np.asarray(trials.start[0])
    rel = (start[0] - int(trials.pose[0])) % A
    hole = trials._replace(available=trials.available.at[0, rel, start[1], start[2]].set(False))
    with pytest.raises(ValueError, match="starts at a missing view"):
        sim.run_trials(key, model, hole)
    # indices outside the grid would be clamped (JAX) or wrapped (NumPy) into some other view
    with pytest.raises(ValueError, match="trial poses must be integer azimuth bins 0..7"):
        sim.run_trials(key, model, trials._replace(pose=trials.pose.at[2].set(A)))
    with pytest.raises(ValueError, match="start elevation index out of the view grid"):
        sim.run_trials(key, model, trials._replace(start=trials.start.at[1, 1].set(E)))
    with pytest.raises(ValueError, match="start azimuth index out of the view grid"):
        sim.run_trials(key, model, trials._replace(start=trials.start.at[3, 0].set(-1)))
    with pytest.raises(ValueError, match=r"trials.available has shape \(4, 8, 1, 1\)"):
        sim.run_trials(key, model, trials._replace(available=trials.available[:, :, :1]))
    with pytest.raises(ValueError, match="mu contains NaN"):
        sim.run_trials(key, model._replace(mu=model.mu.at[0, 1, 2, 0, 0].set(np.nan)), trials)


def brute_force_log_belief(model, views, f):
    """Naive Bayes by enumeration, in NumPy, from the recorded views and responses."""
    mu = np.asarray(model.mu, float)[0]
    sd = np.asarray(model.sigma, float)[0]
    logp = np.zeros((2, A))
    for (phi, e, s), fk in zip(views, f, strict=True):
        for theta in range(A):
            a = (phi - theta) % A
            logp[:, theta] += stats.norm.logpdf(fk, mu[:, a, e, s], sd[:, a, e, s])
    return logp - logsumexp(logp)


@pytest.mark.parametrize("planner", ["sampled", "random"])
def test_runner_records_are_consistent(table, model, key, planner):
    trials = sim.make_trials(key, table, "dpm", "car", 6)
    rec = sim.run_trials(key, model, trials, PC(planner, n_samples=64), chunk_size=CHUNK)
    views = np.asarray(rec.views)
    assert views.shape == (6, A, 3) and np.asarray(rec.observed).all()
    for t in range(6):
        # the start view comes first, azimuths are never repeated, elevation and scale stay put
        np.testing.assert_array_equal(views[t, 0], np.asarray(trials.start[t]))
        assert sorted(views[t, :, 0].tolist()) == list(range(A))
        assert np.all(views[t, :, 1:] == views[t, 0, 1:])
        f = [sim.observe(trials, t, v) for v in views[t]]
        np.testing.assert_allclose(np.asarray(rec.responses[t]), f, rtol=1e-6)
        for k in (0, 3, A - 1):
            ref = brute_force_log_belief(model, views[t, : k + 1], f[: k + 1])
            got = np.asarray(rec.log_belief[t, k])
            keep = ref > -30
            np.testing.assert_allclose(got[keep], ref[keep], atol=2e-3)
    # the same key gives the same trial, whatever else is in the batch
    again = sim.run_trials(
        key,
        model,
        sim.select_trials(trials, slice(0, 3)),
        PC(planner, n_samples=64),
        chunk_size=CHUNK,
    )
    np.testing.assert_array_equal(np.asarray(again.views), views[:3])
    np.testing.assert_array_equal(np.asarray(again.log_belief), np.asarray(rec.log_belief)[:3])
    # nor on how many phases (scans scoring only the views that can be left) a trial is split into
    # (large batches of random trials run in one phase, other large batches in several)
    phased = jax.jit(
        jax.vmap(
            lambda k, r, a, p, st: sim.run_trial(
                k, model, r, a, p, st, config=PC(planner, n_samples=64), phases=3
            )
        )
    )(
        jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(6)),
        trials.responses,
        trials.available,
        trials.pose,
        trials.start,
    )
    np.testing.assert_array_equal(np.asarray(phased.views), views)
    np.testing.assert_allclose(np.asarray(phased.log_belief), np.asarray(rec.log_belief), atol=1e-5)
    if planner == "sampled":
        # nor on how the batch is cut: several chunks (the last one padded), vectorised pairs, one
        # device instead of two
        cut = sim.run_trials(
            key, model, trials, PC(n_samples=64), chunk_size=4, batch_size=2, devices=1
        )
        np.testing.assert_array_equal(np.asarray(cut.views), views)
        np.testing.assert_allclose(
            np.asarray(cut.log_belief), np.asarray(rec.log_belief), atol=1e-5
        )
    if planner == "random":
        # nor on how many CPU devices the trials are split over
        one = sim.run_trials(key, model, trials, PC(planner), chunk_size=CHUNK, devices=1)
        np.testing.assert_array_equal(np.asarray(one.views), views)


def test_trial_draws_are_distinct_keyed_and_leave_small_models_alone(model, key):
    from scrppl.sim.runner import trial_draws

    n = 40
    many = ResponseModel(
        model.mu + jnp.arange(n, dtype=jnp.float32)[:, None, None, None, None],
        jnp.repeat(model.sigma, n, axis=0),
        jnp.arange(n, dtype=jnp.float32)[:, None] * jnp.ones((1, 2)),
    )
    picks = []
    for i in range(20):
        sub = trial_draws(jax.random.fold_in(key, i), many, 5)
        idx = np.asarray(sub.tau[:, 0]).astype(int)  # tau[n] = n: which draws were kept
        assert sub.mu.shape == (5, 2, A, E, S) and len(set(idx.tolist())) == 5
        assert ((0 <= idx) & (idx < n)).all()
        # every field takes the same draws
        np.testing.assert_array_equal(np.asarray(sub.mu[:, 0, 0, 0, 0]), idx.astype(np.float32))
        again = trial_draws(jax.random.fold_in(key, i), many, 5)
        np.testing.assert_array_equal(np.asarray(again.tau), np.asarray(sub.tau))
        picks.append(frozenset(idx.tolist()))
    assert len(set(picks)) == 20  # other trials, other draws
    # over many trials every draw is read about equally often
    counts = np.zeros(n)
    for i in range(400):
        counts[
            np.asarray(trial_draws(jax.random.fold_in(key, i), many, 5).tau[:, 0]).astype(int)
        ] += 1
    assert stats.chisquare(counts).pvalue > 1e-3
    for k in (None, n, n + 3):
        assert trial_draws(key, many, k) is many


def test_each_trial_filters_with_its_own_draws(table, model, key):
    from scrppl.sim.runner import trial_draws

    # five draws far apart: a trial's beliefs tell which single draw its filter read
    shifts = jnp.asarray([0.0, 1.5, -1.0, 2.5, 0.7], jnp.float32)
    many = ResponseModel(
        model.mu
        + shifts[:, None, None, None, None] * jnp.asarray([0.0, 1.0])[None, :, None, None, None],
        jnp.repeat(model.sigma, 5, axis=0),
        jnp.zeros((5, 2)),
    )
    trials = sim.make_trials(key, table, "dpm", "car", 8)
    rec = sim.run_trials(key, many, trials, PC("sampled", n_samples=64), chunk_size=CHUNK,
                         draws_per_trial=1)  # fmt: skip
    rand = sim.run_trials(key, many, trials, PC("random"), chunk_size=CHUNK, draws_per_trial=1)
    used = set()
    for t in range(8):
        own = trial_draws(jax.random.fold_in(key, t), many, 1)
        used.add(float(own.mu[0, 1, 0, 0, 0] - model.mu[0, 1, 0, 0, 0]))
        for r in (rec, rand):  # both planners of a trial read the same draw
            views = np.asarray(r.views[t])
            f = [sim.observe(trials, t, v) for v in views]
            ref = brute_force_log_belief(own, views, f)
            got = np.asarray(r.log_belief[t, -1])
            keep = ref > -30
            np.testing.assert_allclose(got[keep], ref[keep], atol=2e-3)
    assert len(used) >= 2
    with pytest.raises(ValueError, match="draws_per_trial must be at least 1"):
        sim.run_trials(key, many, trials, PC("random"), draws_per_trial=0)
    with pytest.raises(
        ValueError, match="draws_per_trial must be a whole number of draws, got 2.5"
    ):
        sim.run_trials(key, many, trials, PC("random"), draws_per_trial=2.5)


def test_runner_never_observes_missing_views_in_all_view_mode(table, model, key):
    trials = sim.make_trials(key, table, "dpm", "car", 24, positive_fraction=0.0)
    n_steps = A * E * S
    rec = sim.run_trials(key, model, trials, PC("random", mode="all"), n_steps=n_steps)
    avail = np.asarray(trials.available)
    pose = np.asarray(trials.pose)
    obs = np.asarray(rec.observed)
    views = np.asarray(rec.views)
    for t in range(24):
        n_avail = int(avail[t].sum())
        assert obs[t].sum() == n_avail  # steps without a candidate are flagged, not observed
        seen = views[t][obs[t]]
        assert len({tuple(v) for v in seen}) == n_avail
        rel = (seen[:, 0] - pose[t]) % A
        assert avail[t][rel, seen[:, 1], seen[:, 2]].all()
        f = np.asarray(rec.responses[t])
        np.testing.assert_allclose(f[obs[t]], [sim.observe(trials, t, v) for v in seen], rtol=1e-6)
        # the belief after each step is naive Bayes over the views observed so far, and only those:
        # a step that found no view (observed = False) leaves it unchanged. Every state is compared
        # (the beliefs are concentrated: an extra update would change only the improbable states)
        for k in range(n_steps):
            keep = obs[t, : k + 1]
            ref = brute_force_log_belief(model, views[t, : k + 1][keep], f[: k + 1][keep])
            got = np.asarray(rec.log_belief[t, k])
            np.testing.assert_allclose(
                got, ref, rtol=1e-4, atol=2e-3, err_msg=f"trial {t} step {k}"
            )


def test_metrics_against_hand_computation():
    # two trials, two steps, O = 2, A = 4
    p = np.zeros((2, 2, 2, 4))
    p[0, 0, 1, 1] = 0.6
    p[0, 0, 0, 3] = 0.4  # trial 0 step 1: p(present) = 0.6, MAP pose 1
    p[0, 1, 1, 2] = 0.97
    p[0, 1, 0, 0] = 0.03
    p[1, :, 0, 0] = 0.5
    p[1, :, 1, 3] = 0.5  # trial 1: undecided at both steps
    with np.errstate(divide="ignore"):
        logb = np.log(p)
    resp = np.array([[1.0, 2.0], [0.5, -1.0]])
    met = M.trial_metrics(logb, resp, np.ones((2, 2), bool), label=[1, 0], pose=[2, 1])
    np.testing.assert_allclose(met["p_true"], [[0.6, 0.97], [0.5, 0.5]])
    np.testing.assert_allclose(
        met["class_entropy"][0], [stats.entropy([0.4, 0.6]), stats.entropy([0.03, 0.97])]
    )
    np.testing.assert_array_equal(met["correct"], [[True, True], [True, True]])  # tie -> class 0
    np.testing.assert_array_equal(met["pose_error"][0], [1, 0])
    np.testing.assert_array_equal(met["views_to_confidence"], [2, 3])  # censored at K + 1
    np.testing.assert_allclose(met["response_sum"], [[1.0, 3.0], [0.5, -0.5]])
    np.testing.assert_allclose(M.tp_minus_tn(met["response_sum"], [1, 0]), [0.5, 3.5])


def test_calibration_and_bootstrap(rng):
    # perfectly calibrated predictions have a small ECE; a constant 0.8 for always-true events has 0.2
    p = rng.uniform(size=20000)
    y = rng.uniform(size=20000) < p
    assert M.expected_calibration_error(p, y) < 0.02
    np.testing.assert_allclose(M.expected_calibration_error(np.full(50, 0.8), np.ones(50)), 0.2)
    x = rng.normal(1.0, 2.0, size=400)
    mean, lo, hi = M.bootstrap_mean(3, x, n_boot=2000)
    se = x.std() / np.sqrt(400)
    np.testing.assert_allclose([lo, hi], [mean - 1.96 * se, mean + 1.96 * se], atol=0.05)
    d, dlo, dhi = M.paired_bootstrap_difference(3, x + 0.5, x, n_boot=200)
    np.testing.assert_allclose([d, dlo, dhi], 0.5)  # identical pairs: no spread


def test_bootstrap_resamples_are_the_loops_resamples(rng):
    """The blocked bootstrap draws the same resamples as the plain loop written here (same seed, same
    order of draws), for every block boundary: a mean per resample, and positives then negatives."""
    x = rng.normal(size=(150, 3))
    label = rng.uniform(size=150) < 0.4
    for n_boot in (1, 63, 64, 65, 200):
        g = np.random.default_rng(9)
        boots = np.stack([x[g.integers(0, 150, 150)].mean(0) for _ in range(n_boot)])
        lo, hi = np.quantile(boots, [0.025, 0.975], axis=0)
        np.testing.assert_allclose(M.bootstrap_mean(9, x, n_boot)[1:], [lo, hi], rtol=1e-12)
        g = np.random.default_rng(9)
        pos, neg = x[label], x[~label]
        diff = [
            pos[g.integers(0, len(pos), len(pos))].mean(0) - neg[g.integers(0, len(neg), len(neg))].mean(0)
            for _ in range(n_boot)
        ]  # fmt: skip
        lo, hi = np.quantile(np.stack(diff), [0.025, 0.975], axis=0)
        np.testing.assert_allclose(
            M.bootstrap_tp_minus_tn(9, x, label, n_boot)[1:], [lo, hi], rtol=1e-12
        )


def test_calibration_bins_are_floored_half_open_intervals():
    """Catches calibration bins placed by rounding ``p * n_bins`` instead of flooring it: bin ``b`` of ten
    is ``[b / 10, (b + 1) / 10)`` (the last one closed at 1). By hand: 0.06 lies in bin 0, 0.14 in bin 1,
    so ECE = 1/2 |0.06 - 1| + 1/2 |0.14 - 0| = 0.54 (rounding would pool both in bin 1: 0.4)."""
    mean_p, frac, count = M.reliability([0.06, 0.14], [1, 0], n_bins=10)
    np.testing.assert_array_equal(count, [1, 1, 0, 0, 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(mean_p[:2], [0.06, 0.14])
    np.testing.assert_array_equal(frac[:2], [1.0, 0.0])
    assert np.isnan(mean_p[2:]).all() and np.isnan(frac[2:]).all()
    assert M.expected_calibration_error([0.06, 0.14], [1, 0]) == pytest.approx(0.54)
    # five bins of width 0.2: 0 and 0.19 in the first, 0.21 and 0.39 in the second, 0.99 and 1 in the last
    _, _, count = M.reliability([0.0, 0.19, 0.21, 0.39, 0.99, 1.0], [0, 1, 0, 1, 1, 1], n_bins=5)
    np.testing.assert_array_equal(count, [2, 2, 0, 0, 2])
    # ECE by hand: |0.095 - 0.5| / 3 + |0.3 - 0.5| / 3 + |0.995 - 1| / 3
    got = M.expected_calibration_error([0.0, 0.19, 0.21, 0.39, 0.99, 1.0], [0, 1, 0, 1, 1, 1], 5)
    assert got == pytest.approx((0.405 + 0.2 + 0.005) / 3)


def test_bootstrap_intervals_have_the_stated_level(rng):
    # The mean of 400 normal values is normal, so a percentile-bootstrap interval at level q has the
    # half-width z_q * se. 5 % of it is tighter than the gap between levels (a 90 % interval is 16 %
    # narrower than a 95 % one; the resampling error here is about 2 %).
    x = rng.normal(1.0, 2.0, size=400)
    y = rng.normal(0.0, 1.0, size=400)
    label = np.arange(400) % 3 == 0
    se = {
        "mean": x.std() / np.sqrt(400),
        "paired": (x - y).std() / np.sqrt(400),
        "tp_minus_tn": np.hypot(
            x[label].std() / np.sqrt(label.sum()), x[~label].std() / np.sqrt((~label).sum())
        ),
    }
    for level in (None, 0.95, 0.9, 0.5):
        z = stats.norm.ppf(0.5 + (0.95 if level is None else level) / 2)
        opt = {} if level is None else {"level": level}
        got = {
            "mean": M.bootstrap_mean(3, x, 4000, **opt),
            "paired": M.paired_bootstrap_difference(3, x, y, 4000, **opt),
            "tp_minus_tn": M.bootstrap_tp_minus_tn(3, x, label, 4000, **opt),
        }
        for name, (value, lo, hi) in got.items():
            np.testing.assert_allclose((hi - lo) / 2, z * se[name], rtol=0.05, err_msg=name)
            assert abs((hi + lo) / 2 - value) < 0.1 * se[name], name


def test_experiment_entropy_planner_beats_random(table, model, key, tmp_path):
    trials = sim.make_trials(key, table, "dpm", "car", 48)
    methods = {
        "naive_bayes": sim.Method(model, "naive_bayes", trials),
        "instance": sim.Method(model, "instance", trials),
    }
    planners = [PC("sampled", n_samples=64), PC("random")]
    ds = sim.run_experiment(key, methods, planners, category_names=CATS, chunk_size=CHUNK)
    assert ds["class_entropy"].dims == ("method", "planner", "trial", "step")
    assert list(ds["planner"].values) == ["sampled", "random"]
    assert json.loads(ds.attrs["planner_configs"])["sampled"]["n_samples"] == 64
    comp = sim.compare_planners(ds)
    # informative side views exist: entropy planning reaches confidence sooner, on the same trials
    assert comp["naive_bayes"]["views_to_confidence_difference"]["hi"] < 0
    # with one draw and tau = 0 the instance-aware filter is naive Bayes
    np.testing.assert_allclose(
        ds["p_present"].sel({"method": "instance"}),
        ds["p_present"].sel({"method": "naive_bayes"}),
        atol=1e-4,
    )
    summ = sim.summarise(ds, n_boot=100)
    # after all A views both planners have seen the same views: same TP-minus-TN and entropy
    last = summ.isel(step=-1)
    np.testing.assert_allclose(
        last["tp_minus_tn"].values[:, 0], last["tp_minus_tn"].values[:, 1], rtol=1e-5
    )
    assert np.all(summ["class_entropy_lo"] <= summ["class_entropy"] + 1e-12)
    # Fig. 5 drawn straight from the trials: the class-entropy panel shows the trial means
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_planner_comparison

    fig = plot_planner_comparison(ds, "instance")
    means = ds["class_entropy"].sel({"method": "instance"}).mean("trial")
    for line, planner in zip(fig.axes[1].lines, ds["planner"].values, strict=True):
        np.testing.assert_allclose(line.get_ydata(), means.sel(planner=planner).values, rtol=1e-6)
    plt.close(fig)
    with pytest.raises(ValueError, match="choose one target"):
        plot_planner_comparison(ds.expand_dims(target=["car", "bike"]))
    cal = sim.calibration(ds)
    assert 0 <= cal["naive_bayes"]["ece"] < 0.2
    path = sim.save_trials(ds, tmp_path / "trials.nc")
    back = sim.load_trials(path)
    np.testing.assert_array_equal(
        back["views_to_confidence"].values, ds["views_to_confidence"].values
    )
    assert list(back["category"].values[:3]) == list(ds["category"].values[:3])


def test_load_trials_renames_the_old_filter_dimension_and_rejects_other_files(tmp_path):
    # trials.nc written before the methods' dimension was named "method" had it as "filter"
    import xarray as xr

    rng = np.random.default_rng(0)
    vtc = rng.integers(1, 9, size=(2, 2, 5))
    old = xr.Dataset(
        {
            "views_to_confidence": (("filter", "planner", "trial"), vtc),
            "p_present": (("filter", "planner", "trial", "step"), rng.uniform(size=(2, 2, 5, 3))),
        },
        coords={
            "filter": ["gaussian+naive_bayes", "hierarchical+instance"],
            "planner": ["sampled", "random"],
            "trial": np.arange(5),
            "step": np.arange(1, 4),
            "filter_kind": ("filter", ["naive_bayes", "instance"]),
            "label": ("trial", [0, 1, 1, 0, 1]),
        },
    )
    old.to_netcdf(tmp_path / "old.nc", engine="h5netcdf")
    back = sim.load_trials(tmp_path / "old.nc")
    assert back["p_present"].dims == ("method", "planner", "trial", "step")
    assert "filter" not in back.dims
    assert list(back["method"].values) == ["gaussian+naive_bayes", "hierarchical+instance"]
    assert list(back["filter_kind"].values) == ["naive_bayes", "instance"]
    got = back["views_to_confidence"].sel({"method": "hierarchical+instance", "planner": "random"})
    np.testing.assert_array_equal(got.values, vtc[1, 1])
    # the readers work on it: per-method calibration and summaries
    assert set(sim.calibration(back)) == {"gaussian+naive_bayes", "hierarchical+instance"}
    # a file with trial results under the new name loads unchanged
    sim.save_trials(back, tmp_path / "new.nc")
    xr.testing.assert_identical(sim.load_trials(tmp_path / "new.nc"), back)
    # a netCDF file that holds no trial results (e.g. a response table) is refused, naming the file
    xr.Dataset({"score": (("x",), np.zeros(3))}).to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    with pytest.raises(ValueError, match=r"other\.nc holds no trial results"):
        sim.load_trials(tmp_path / "other.nc")


def test_experiment_planners_are_named_planner_configs(table, model, key):
    from scrppl.sim.experiment import planner_configs

    # a sequence is named by the planner field, a mapping keeps its names
    assert list(planner_configs([PC("sampled"), PC("random")])) == ["sampled", "random"]
    both = planner_configs({"M=16": PC(n_samples=16), "M=64": PC(n_samples=64)})
    assert {k: v.n_samples for k, v in both.items()} == {"M=16": 16, "M=64": 64}
    with pytest.raises(ValueError, match="distinct names"):
        planner_configs([PC(n_samples=16), PC(n_samples=64)])
    with pytest.raises(ValueError, match="at least one planner"):
        planner_configs([])
    with pytest.raises(ValueError, match="a sequence of PlannerConfig"):
        planner_configs(("sampled", "random")[0])
    with pytest.raises(ValueError, match="PlannerConfig.order"):
        planner_configs({"q": PC("quadrature", order=0)})
    with pytest.raises(ValueError, match="got planner='random'"):
        sim.study.study_planners(PC("random"))
    # the old keyword arguments are refused with a pointer to the config
    trials = sim.make_trials(key, table, "dpm", "car", 2)
    with pytest.raises(ValueError, match="n_samples: planner settings travel in the planners"):
        sim.run_experiment(key, {"nb": sim.Method(model, "naive_bayes", trials)}, n_samples=8)


@pytest.mark.slow
def test_simulate_command_end_to_end(table, model, tmp_path, monkeypatch):
    import json

    import scrppl.models as models
    from scrppl.cli import main
    from scrppl.responses import save_response_table

    save_response_table(table, tmp_path / "responses.nc")
    calls = []

    def fake_loader(models_dir, kind, detector, target, n_draws=None):
        # the models stage is tested elsewhere; here only its contract matters
        calls.append((kind, detector, target, n_draws))
        if kind != "gaussian":
            raise FileNotFoundError(f"no {kind} model in {models_dir}")
        return ViewpointModel(model, kind, detector, target, "identity", None)

    monkeypatch.setattr(models, "load_response_model", fake_loader, raising=False)
    argv = ["simulate", "--out", str(tmp_path), "--profile", "quick", "--trials", "12"]
    argv += ["--large-trials", "16", "--n-samples", "64", "--quiet"]
    argv += ["--max-draws", "6", "--large-max-draws", "3"]
    assert main(argv) == 0
    # the paper's experiment keeps --max-draws posterior draws; the large one loads them all (each
    # of its trials reads --large-max-draws of them)
    assert [c for c in calls if c[0] == "gaussian"] == [
        ("gaussian", "dpm", "car", 6),
        ("gaussian", "dpm", "car", None),
    ]
    summary = json.loads((tmp_path / "simulate-summary.json").read_text())
    headline = summary["targets"]["car"]["paper_experiment"]["gaussian+naive_bayes"]
    assert set(headline["views_to_confidence"]) == {"sampled", "random"}
    ds = sim.load_trials(tmp_path / "trials.nc")
    assert ds.sizes["trial"] == 12 and ds.sizes["step"] == A
    assert sim.load_trials(tmp_path / "trials-large.nc").sizes["trial"] == 16
    figures = {p.name for p in (tmp_path / "figures").iterdir()}
    assert {"fig4-car.png", "fig5-car-gaussian-naive_bayes.png", "calibration.png"} <= figures
    # a notebook calling the library gets the command's numbers for the same seed
    study = sim.run_study(
        0, table, tmp_path / "models", "dpm", ["car"], trials=12, config=PC(n_samples=64),
        max_draws=6,
    )  # fmt: skip
    assert study.large is None
    for var in ("views_to_confidence", "p_true", "azimuth"):
        np.testing.assert_array_equal(study.trials[var].values, ds[var].values)
    # a missing response table is a clear error, not a traceback
    assert main(["simulate", "--out", str(tmp_path / "nowhere"), "--quiet"]) == 1


def test_simulate_gives_the_large_experiment_its_own_posterior_draws(
    table, model, tmp_path, monkeypatch
):
    # Fast (no trial is compiled): every run of the trial runner is recorded and answered with a
    # stand-in record, and the number of posterior draws of the model it is given is checked. With the
    # old bug the large experiment ran with --max-draws draws instead of --large-max-draws.
    import scrppl.models as models
    import scrppl.sim.experiment
    import scrppl.sim.runner
    from scrppl.cli import main
    from scrppl.responses import save_response_table

    save_response_table(table, tmp_path / "responses.nc")
    many = ResponseModel(*(jnp.repeat(x, 10, axis=0) for x in model))  # 10 posterior draws

    def fake_loader(models_dir, kind, detector, target, n_draws=None):
        if kind != "hierarchical":
            raise FileNotFoundError(f"no {kind} model in {models_dir}")
        keep = np.round(np.linspace(0, 9, min(n_draws or 10, 10))).astype(int)
        thinned = ResponseModel(*(x[keep] for x in many))
        return ViewpointModel(thinned, kind, detector, target, "identity", None)

    runs = []

    def fake_run_trials(
        key, model, trials, config=None, *, filter="naive_bayes", n_steps=None, **kw
    ):
        runs.append((trials.n_trials, filter, model.mu.shape[0], kw.get("draws_per_trial")))
        n, k = trials.n_trials, A if n_steps is None else n_steps
        views = jnp.broadcast_to(jnp.asarray(trials.start)[:, None], (n, k, 3))
        return sim.TrialRecord(
            views, jnp.zeros((n, k)), jnp.ones((n, k), bool), jnp.full((n, k, 2, A), -np.log(2 * A))
        )

    monkeypatch.setattr(models, "load_response_model", fake_loader, raising=False)
    monkeypatch.setattr(scrppl.sim.experiment, "run_trials", fake_run_trials)
    monkeypatch.setattr(scrppl.sim.runner, "run_trials", fake_run_trials)
    argv = ["simulate", "--out", str(tmp_path), "--profile", "quick", "--trials", "12"]
    argv += ["--large-trials", "16", "--kinds", "hierarchical", "--quiet"]
    argv += ["--max-draws", "6", "--large-max-draws", "3"]
    assert main(argv) == 0
    paper = {(f, d, k) for t, f, d, k in runs if t == 12}
    large = {(f, d, k) for t, f, d, k in runs if t == 16}
    assert paper == {("naive_bayes", 6, None), ("instance", 6, None)}
    # the large experiment gets every draw, and each of its trials reads its own 3
    assert large == {("naive_bayes", 10, 3), ("instance", 10, 3)}
