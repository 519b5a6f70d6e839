"""Multi-detector trials: same draws as the single-detector simulator, replayable records, fusion helps."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from scrppl import belief as B
from scrppl import sim
from scrppl.extensions import fusion as F
from scrppl.extensions import trials as XT
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig
from scrppl.responses import empty_response_table
from scrppl.views import ViewGrid

A, E, S = 8, 2, 1
CATS = ["car", "bike", "shoe"]
DETS = ["dpm", "bof", "sift"]
N_INST = 4


def mu_present(d):
    # each detector recognises the target from different sides
    phase = (0.0, np.pi / 4, np.pi / 2)[d]
    return (
        2.0
        * np.abs(np.sin(2 * np.pi * np.arange(A) / A + phase))[:, None, None]
        * np.ones((A, E, S))
    )


@pytest.fixture(scope="module")
def table():
    rng = np.random.default_rng(11)
    split = np.array([["test", "test", "fit", "test"]] * len(CATS), dtype=object)
    ds = empty_response_table(DETS, ["car"], CATS, N_INST, ViewGrid(A, (10.0, 30.0), (1.0,)), split)
    score = rng.normal(0.0, 0.6, size=ds["score"].shape)
    for d in range(len(DETS)):
        score[d, 0, 0] += mu_present(d)
    score[:, 0, 1, 3, :, 1] = np.nan  # bike 3 lacks the upper elevation (every detector)
    score[:, 0, 2, 1, 5, 0] = np.nan  # shoe 1 lacks one view of the lower ring
    score[2, 0, 1, 0, 2, 0] = np.nan  # sift alone failed on one view of bike 0
    ds["score"][:] = score
    return ds


def gaussian_model(d):
    mu = np.stack([np.zeros((A, E, S)), mu_present(d)])[None]
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, 0.6, jnp.float32), jnp.zeros((1, 2))
    )


def hierarchical_like(rng, d):
    """A model with several draws and an instance effect (for the instance-aware filter)."""
    base = np.stack([np.zeros((A, E, S)), mu_present(d)])
    mu = base[None] + rng.normal(0.0, 0.1, size=(3, *base.shape))
    return ResponseModel(
        jnp.asarray(mu, jnp.float32),
        jnp.full(mu.shape, 0.5, jnp.float32),
        jnp.full((3, 2), 0.3, jnp.float32),
    )


def test_one_detector_gives_the_simulators_trials(table, key):
    multi = XT.make_multi_trials(key, table, ["bof"], "car", 24, transforms=[np.tanh])
    single = sim.make_trials(key, table, "bof", "car", 24, transform=np.tanh)
    for name, got, want in zip(
        single._fields, XT.single_detector_trials(multi, 0), single, strict=True
    ):
        np.testing.assert_array_equal(got, want, err_msg=name)


def test_multi_trials_hold_every_detectors_responses(table, key):
    multi = XT.make_multi_trials(key, table, DETS, "car", 40)
    score = table["score"].values[:, 0]  # (D, C, I, A, E, S)
    assert multi.responses.shape == (40, 3, A, E, S) and multi.n_detectors == 3
    for t in range(40):
        c, i = int(multi.category[t]), int(multi.instance[t])
        raw = score[:, c, i]
        avail = ~np.isnan(raw).any(0)
        np.testing.assert_array_equal(multi.available[t], avail)
        np.testing.assert_allclose(
            np.asarray(multi.responses[t]), np.where(avail, raw, 0.0), rtol=1e-6
        )
        e0, s0 = int(multi.start[t, 1]), int(multi.start[t, 2])
        assert avail[:, e0, s0].all()  # the start ring is complete for every detector
        assert int(multi.label[t]) == int(CATS[c] == "car")
        assert table["split"].values[c, i] == "test"


@pytest.mark.parametrize("policy", XT.POLICIES)
@pytest.mark.parametrize(
    "kind,planner", [("naive_bayes", "sampled"), ("naive_bayes", "random"), ("instance", "sampled")]
)
def test_one_detector_reproduces_run_trials(table, key, policy, kind, planner):
    rng = np.random.default_rng(3)
    model = gaussian_model(1) if kind == "naive_bayes" else hierarchical_like(rng, 1)
    multi = XT.make_multi_trials(key, table, ["bof"], "car", 12)
    config = PlannerConfig(planner, n_samples=32)
    rec = XT.run_multi_trials(key, (model,), multi, config, policy=policy, filter=kind)
    want = sim.run_trials(
        key, model, XT.single_detector_trials(multi, 0), config, filter=kind, chunk_size=16
    )
    np.testing.assert_array_equal(rec.views, want.views)
    np.testing.assert_array_equal(rec.observed, want.observed)
    np.testing.assert_allclose(rec.log_belief, want.log_belief, atol=5e-4)
    np.testing.assert_allclose(rec.responses[..., 0], want.responses, atol=1e-6)


# one pair in make test, the other three in make test-slow (CI runs both): 14-25 s each
@pytest.mark.parametrize(
    "kind, policy",
    [
        pytest.param(k, p, marks=() if (p, k) == ("fuse", "instance") else pytest.mark.slow)
        for k in B.FILTERS
        for p in XT.POLICIES
    ],
)
def test_records_replay_through_the_fused_filter(table, key, kind, policy):
    rng = np.random.default_rng(5)
    models = tuple(
        gaussian_model(d) if kind == "naive_bayes" else hierarchical_like(rng, d) for d in range(3)
    )
    multi = XT.make_multi_trials(key, table, DETS, "car", 6)
    n_steps = 12 if policy == "choose" else 8
    rec = XT.run_multi_trials(
        key,
        models,
        multi,
        PlannerConfig(n_samples=16, order=8),
        policy=policy,
        filter=kind,
        n_steps=n_steps,
    )
    assert rec.detectors.shape == (6, n_steps, 3)
    for t in range(6):
        pose = int(multi.pose[t])
        b = F.fused_init(kind, models)
        seen = set()
        for k in range(n_steps):
            assert bool(rec.observed[t, k])
            phi, e, s = (int(v) for v in rec.views[t, k])
            a = (phi - pose) % A
            assert bool(multi.available[t, a, e, s])
            used = np.asarray(rec.detectors[t, k])
            if policy == "fuse":
                assert used.all() and (phi, e, s) not in seen
                seen.add((phi, e, s))
            else:
                assert used.sum() == 1
                pair = (phi, e, s, int(np.argmax(used)))
                assert pair not in seen
                seen.add(pair)
            f = np.asarray(multi.responses[t, :, a, e, s])
            np.testing.assert_allclose(rec.responses[t, k], np.where(used, f, 0.0), atol=1e-6)
            b = F.fused_update(models, b, jnp.asarray(f), phi, e, s, mask=used)
            np.testing.assert_allclose(rec.log_belief[t, k], F.fused_joint_log_belief(b), atol=2e-4)
        start = tuple(int(v) for v in multi.start[t])
        assert tuple(int(v) for v in rec.views[t, 0]) == start


def test_fusing_two_informative_detectors_beats_either_alone(table, key):
    multi = XT.make_multi_trials(jax.random.fold_in(key, 1), table, DETS[:2], "car", 64)
    models = (gaussian_model(0), gaussian_model(1))
    p_true = {}
    for name, ms, tr in (
        ("dpm", models[:1], XT.MultiTrials(multi.responses[:, :1], *multi[1:])),
        ("bof", models[1:], XT.MultiTrials(multi.responses[:, 1:], *multi[1:])),
        ("both", models, multi),
    ):
        rec = XT.run_multi_trials(key, ms, tr, PlannerConfig(n_samples=32), n_steps=3)
        p_true[name] = XT.multi_trial_metrics(rec, tr)["p_true"].mean(0)
    assert np.all(p_true["both"] > p_true["dpm"]) and np.all(p_true["both"] > p_true["bof"])


def test_bad_multi_trial_input(table, key):
    with pytest.raises(ValueError, match="not in the response table"):
        XT.make_multi_trials(key, table, ["dpm", "hog"], "car", 4)
    with pytest.raises(ValueError, match="transforms"):
        XT.make_multi_trials(key, table, DETS, "car", 4, transforms=[None])
    multi = XT.make_multi_trials(key, table, DETS[:2], "car", 4)
    models = (gaussian_model(0), gaussian_model(1))
    with pytest.raises(ValueError, match="2 detectors, 1 models"):
        XT.run_multi_trials(key, models[:1], multi)
    with pytest.raises(ValueError, match="unknown policy"):
        XT.run_multi_trials(key, models, multi, policy="vote")
    with pytest.raises(ValueError, match="n_steps"):
        XT.run_multi_trials(key, models, multi, n_steps=9)
    with pytest.raises(ValueError, match="costs"):
        XT.run_multi_trials(key, models, multi, policy="choose", costs=[1.0])
    # what the single-detector runner checks, checked here by the same functions
    with pytest.raises(ValueError, match="trial poses must be integer azimuth bins 0..7"):
        XT.run_multi_trials(key, models, multi._replace(pose=multi.pose.at[0].set(-1)))
    with pytest.raises(ValueError, match="start scale index out of the view grid"):
        XT.run_multi_trials(key, models, multi._replace(start=multi.start.at[2, 2].set(S)))
    with pytest.raises(ValueError, match=r"trials.available has shape \(4, 8, 1, 1\)"):
        XT.run_multi_trials(key, models, multi._replace(available=multi.available[:, :, :1]))
    nan = models[1]._replace(mu=models[1].mu.at[0, 1, 2, 0, 0].set(np.nan))
    with pytest.raises(ValueError, match="mu contains NaN"):
        XT.run_multi_trials(key, (models[0], nan), multi)
