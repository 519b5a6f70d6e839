"""The decomposition of views to confidence (scrppl.sim.decomposition, ``scrppl decompose``).

A tiny results folder is written by hand (A = 4 views, one Gaussian fit, a simulate summary). The fast
tests run the cheap rows of the ladder on it once (random, greedy eq. 5, the clairvoyant bound; their
compiled runners are then shared by every test):

* the clairvoyant bound is at most every row on every trial;
* the rows are paired: ``random`` and ``greedy_joint`` are the experiment's ``random`` and ``sampled``
  results for the same key and trials;
* a row against itself (random vs random) has the interval exactly [0, 0]; shares are 0 and 1 at the ends;
* the same seed gives the same numbers;
* the command writes the same numbers into the folder, and says what is missing from a folder.

The slow tests compile the other planners (about 10 s on two cores): the whole ladder on the tiny folder
(bound below every row, the two-step row is :func:`run_two_step_trials` with the same key), and
``scrppl simulate`` then ``scrppl decompose`` on a folder made of the shipped example models (both
filters), checked against ``trials.nc``; and the ladder in the filter world with the model-optimal
bracket beside it. Fast tests check the filter world's draws (views independent, the marginal predictive)
and the model-optimal summary against numbers by hand.
"""

import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from scrppl.cli import main
from scrppl.confident import CONFIDENT_PLANNER, view_information
from scrppl.models.io import save_gaussian
from scrppl.models.response import ResponseModel
from scrppl.planning import PlannerConfig as PC
from scrppl.responses import empty_response_table, load_response_table, save_response_table
from scrppl.sim import Trials, robot_frame, run_experiment
from scrppl.sim import decomposition as D
from scrppl.sim import metrics as M
from scrppl.sim.study import load_methods
from scrppl.views import ViewGrid

A = 4
TRIALS = 12
SEED = 3
#: small planners: the test is about pairing and bookkeeping, not about which planner wins
OPTIONS = dict(n_samples=8, lookahead_samples=4, lookahead_outer=4)
CONFIDENT = CONFIDENT_PLANNER._replace(n_samples=4)
CLI_OPTIONS = ["--lookahead-samples", "4", "--lookahead-outer", "4", "--confident-samples", "4"]
#: the rows the fast tests run (the others compile for about 10 s)
FAST_ROWS = ("random", "greedy_joint", "clairvoyant")


def tiny_model():
    """Two classes on A = 4 views: the target shows at views 0 and 2, weakly elsewhere."""
    mu = np.zeros((1, 2, A, 1, 1))
    mu[0, 1, :, 0, 0] = [2.4, 0.3, 1.6, -0.4]
    mu[0, 0, :, 0, 0] = [0.0, 0.5, -0.3, 0.2]
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, 0.7, jnp.float32), jnp.zeros((1, 2))
    )


def write_folder(out, *, summary=True, model=True, kinds=("gaussian",)):
    """A results folder as `scrppl simulate` leaves it, made by hand."""
    rng = np.random.default_rng(11)
    cats = ["car", "bike"]
    split = np.array([["fit", "test", "test", "test"]] * 2, dtype=object)
    table = empty_response_table(["dpm"], ["car"], cats, 4, ViewGrid(A, (20.0,), (1.0,)), split)
    mu = np.asarray(tiny_model().mu)[0, :, :, 0, 0]  # (class, A)
    score = rng.normal(0.0, 0.6, size=table["score"].shape)
    score[0, 0, 0] += mu[1][None, :, None, None]
    score[0, 0, 1] += mu[0][None, :, None, None]
    table["score"][:] = score
    out.mkdir(parents=True, exist_ok=True)
    save_response_table(table, out / "responses.nc")
    if model:
        save_gaussian(
            out / "models" / "gaussian-dpm-car.nc",
            tiny_model(),
            np.full((2, A, 1, 1), 3),
            {"detector": "dpm", "target": "car", "transform": "identity"},
        )
    if summary:
        simulated = {"detector": "dpm", "settings": {"trials": TRIALS, "n_samples": 8}}
        simulated["targets"] = {"car": {"transforms": {k: "identity" for k in kinds}}}
        (out / "simulate-summary.json").write_text(json.dumps(simulated))
    return out


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_folder(tmp_path_factory.mktemp("results"))


def decompose(folder, seed=SEED, rows=FAST_ROWS):
    table = load_response_table(folder / "responses.nc")
    return D.decompose_target(
        seed, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
        kinds=["gaussian"], confident=CONFIDENT, rows=rows, n_boot=200, **OPTIONS,
    )  # fmt: skip


@pytest.fixture(scope="module")
def ladder(folder):
    return decompose(folder)


def experiment_methods(folder, seed=SEED):
    """The experiment's methods and planner key for target 0 (scrppl.sim.run_study's keys)."""
    k_trials, k_run = D.study_keys(seed, 0)
    table = load_response_table(folder / "responses.nc")
    methods, _ = load_methods(k_trials, folder / "models", table, "dpm", "car", TRIALS)
    return methods, k_run


def check_bound_below_every_row(ds, entry, rows):
    assert ds["row"].values.tolist() == list(rows) and rows[-1] == "clairvoyant"
    v = ds["views_to_confidence"].values  # (method, row, trial)
    assert v.shape == (ds.sizes["method"], len(rows), TRIALS)
    assert np.all(v[:, -1:] <= v)
    assert np.all((v >= 1) & (v <= A + 1))  # never confident counts A + 1
    for m in entry["methods"].values():
        bound = m["rows"]["clairvoyant"]["views_to_confidence"]
        assert list(m["rows"]) == list(rows)
        assert all(bound <= r["views_to_confidence"] for r in m["rows"].values())


def test_clairvoyant_bound_is_below_every_row_on_every_trial(ladder):
    check_bound_below_every_row(*ladder, FAST_ROWS)


def test_rows_are_the_experiments_results_on_the_same_trials(folder, ladder):
    ds, _ = ladder
    methods, k_run = experiment_methods(folder)
    planners = {"random": PC("random"), "sampled": PC("sampled", n_samples=OPTIONS["n_samples"])}
    exp = run_experiment(k_run, methods, planners)
    for row, planner in (("random", "random"), ("greedy_joint", "sampled")):
        np.testing.assert_array_equal(
            ds["views_to_confidence"].sel(row=row).values,
            exp["views_to_confidence"].sel(planner=planner).values,
        )
    for coord in ("label", "pose", "start_azimuth"):
        np.testing.assert_array_equal(ds[coord].values, exp[coord].values)


@pytest.mark.slow
def test_whole_ladder_is_paired_and_above_the_bound(folder, ladder):
    ds, entry = decompose(folder, rows=D.ROWS)
    rows = [r for r in D.ROWS if r not in D.ORACLE_ROWS]  # no oracle models given: left out
    check_bound_below_every_row(ds, entry, rows)
    # the rows the fast tests ran are the same in the whole ladder: one key, the same trials
    for row in FAST_ROWS:
        np.testing.assert_array_equal(
            ds["views_to_confidence"].sel(row=row), ladder[0]["views_to_confidence"].sel(row=row)
        )
    # the two-step row: the two-step runner with the same key on the same trials
    methods, k_run = experiment_methods(folder)
    meth = methods["gaussian+naive_bayes"]
    config = D.decomposition_planners(OPTIONS["n_samples"], lookahead_samples=4)["two_step"]
    rec = D.run_two_step_trials(k_run, meth.model, meth.trials, config, n_outer=4)
    trials = meth.trials
    met = M.trial_metrics(rec.log_belief, rec.responses, rec.observed, trials.label, trials.pose)
    np.testing.assert_array_equal(
        met["views_to_confidence"], ds["views_to_confidence"].sel(row="two_step").values[0]
    )
    views = np.asarray(rec.views)
    assert np.asarray(rec.observed).all()
    np.testing.assert_array_equal(views[:, 0], np.asarray(trials.start))
    for t in range(TRIALS):  # every azimuth once, and the response seen is the one at that view
        assert sorted(views[t, :, 0].tolist()) == list(range(A))
        resp_r, _ = robot_frame(trials.responses[t], trials.available[t], trials.pose[t])
        want = np.asarray(resp_r)[views[t, :, 0], views[t, :, 1], views[t, :, 2]]
        np.testing.assert_array_equal(np.asarray(rec.responses[t]), want)


def test_intervals_of_a_row_against_itself_are_zero_and_shares_run_from_0_to_1(ladder):
    ds, entry = ladder
    m = entry["methods"]["gaussian+naive_bayes"]
    zero = {"mean": 0.0, "lo": 0.0, "hi": 0.0}
    assert m["rows"]["random"]["difference_vs_random"] == zero
    assert m["rows"]["random"]["difference_vs_previous"] == zero
    v = ds["views_to_confidence"].values[0].astype(float)
    for j, row in enumerate(FAST_ROWS):
        assert M.paired_bootstrap_difference(0, v[j], v[j], 200) == (0.0, 0.0, 0.0)
        want = M.paired_bootstrap_difference(SEED, v[j], v[0], 200)
        assert m["rows"][row]["difference_vs_random"] == dict(
            zip(("mean", "lo", "hi"), want, strict=True)
        )
        if j:
            want = M.paired_bootstrap_difference(SEED, v[j], v[j - 1], 200)
            assert m["rows"][row]["difference_vs_previous"] == dict(
                zip(("mean", "lo", "hi"), want, strict=True)
            )
    room = v[0] - v[-1]
    assert m["room"]["mean"] == pytest.approx(room.mean())
    assert room.mean() > 0  # the tiny folder leaves room for planning
    assert m["rows"]["random"]["share_of_room"] == zero
    assert m["rows"]["clairvoyant"]["share_of_room"] == {"mean": 1.0, "lo": 1.0, "hi": 1.0}
    for j, row in enumerate(FAST_ROWS):
        share = m["rows"][row]["share_of_room"]
        assert share["mean"] == pytest.approx((v[0] - v[j]).mean() / room.mean())
        assert share["lo"] <= share["mean"] <= share["hi"]


def test_same_seed_same_numbers(folder, ladder):
    ds, entry = ladder
    again, entry2 = decompose(folder)
    np.testing.assert_array_equal(again["views_to_confidence"], ds["views_to_confidence"])
    assert entry2["methods"] == entry["methods"]
    # another seed draws other trials (same compiled runners)
    other, _ = decompose(folder, seed=SEED + 1)
    assert not np.array_equal(other["pose"].values, ds["pose"].values)


def test_view_information_per_kind(ladder):
    _, entry = ladder
    info = entry["view_information"]["gaussian"]
    assert np.shape(info["nats"]) == (1, 1, A)
    np.testing.assert_allclose(info["nats"][0][0], view_information(tiny_model()), rtol=1e-6)
    assert info["prior_entropy"] == pytest.approx(np.log(2))
    assert np.all(np.asarray(info["nats"]) <= np.log(2) + 1e-6)
    # views 0 and 2 separate the classes, 1 and 3 barely
    assert min(info["nats"][0][0][0], info["nats"][0][0][2]) > max(info["nats"][0][0][1::2])


def test_bad_settings_are_refused():
    for rows in (
        ("greedy_joint", "random"),
        ("random", "clairvoyant", "two_step"),
        ("random", "x"),
    ):
        with pytest.raises(ValueError, match="starting with 'random'"):
            D.run_decomposition(None, {}, rows=rows)
    with pytest.raises(ValueError, match="planner='confident'"):
        D.decomposition_planners(confident=PC("sampled"))
    with pytest.raises(ValueError, match="PlannerConfig.n_samples"):
        D.decomposition_planners(0)


def test_command_writes_the_tables_into_the_results_folder(folder, ladder, capsys):
    _, entry = ladder
    argv = ["decompose", "--results", str(folder), "--seed", str(SEED), "--n-boot", "200"]
    argv += ["--rows", ",".join(FAST_ROWS), "--quiet"]
    assert main(argv) == 0
    result = json.loads((folder / "decomposition.json").read_text())
    assert result["settings"]["trials"] == TRIALS and result["settings"]["n_samples"] == 8
    assert result["settings"]["rows"] == list(FAST_ROWS)
    assert result["targets"]["car"]["methods"] == entry["methods"]
    text = (folder / "decomposition.md").read_text()
    assert text.count("| gaussian |") == 1 and "clairvoyant bound" in text
    assert "(room " in text and "greedy, H(o, theta) (eq. 5)" in text
    # a table per method (header + rows) and the view-information table (header + one kind)
    assert len([line for line in text.splitlines() if line.startswith("| ")]) == 1 + 3 + 2
    assert not list(folder.glob(".decomposition*"))  # written atomically: no temporary left


def test_command_names_what_the_folder_lacks(tmp_path, capsys):
    def error(folder, *extra):
        assert main(["decompose", "--out", str(folder), "--quiet", *extra]) == 1
        return capsys.readouterr().err

    assert "results folder not found" in error(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    assert "scrppl detect" in error(tmp_path / "empty")
    assert "scrppl fit" in error(write_folder(tmp_path / "unfitted", model=False))
    assert "scrppl simulate" in error(write_folder(tmp_path / "unsimulated", summary=False))
    both = write_folder(tmp_path / "half", kinds=("gaussian", "hierarchical"))
    err = error(both)
    assert "no fitted hierarchical model" in err and "scrppl fit" in err
    assert "was not simulated" in error(both, "--targets", "bike")
    assert "--trials must be at least 1" in error(both, "--trials", "0")
    assert "starting with 'random'" in error(both, "--kinds", "gaussian", "--rows", "greedy_joint")
    assert "--model-world and --oracle" in error(both, "--model-world", "--oracle")
    assert "give it with --model-world" in error(both, "--world", "filter")
    err = error(both, "--model-optimal", "--rows", "random,greedy_joint")
    assert "--model-optimal needs the rows 'random' and 'clairvoyant'" in err
    (both / "simulate-summary.json").write_text("{not json")
    err = error(both)
    assert "simulate summary" in err and "unreadable" in err


@pytest.mark.slow
def test_decompose_after_simulate_on_the_example_models(tmp_path):
    """Both filters: simulate, then decompose; the rows agree with trials.nc and the bound."""
    from scrppl.examples import DATA_DIR, simulated_table
    from scrppl.sim import load_trials

    out = tmp_path / "run"
    (out / "models").mkdir(parents=True)
    save_response_table(simulated_table(), out / "responses.nc")
    for path in DATA_DIR.glob("*-dpm-car.nc"):
        shutil.copy(path, out / "models" / path.name)
    argv = ["--out", str(out), "--seed", "1", "--quiet"]
    simulate = ["simulate", "--profile", "quick", "--targets", "car", "--trials", "10"]
    simulate += ["--large-trials", "0", "--n-samples", "16", "--max-draws", "4"]
    assert main(simulate + argv) == 0
    # a row of each kind (the planners on the experiment's filter, the told planners' own filter, the
    # bound): every row of the default ladder compiles its own programs, three methods over
    rows = "random,greedy_joint,confident,pose_greedy,clairvoyant"
    assert main(["decompose", "--n-boot", "100", "--rows", rows, *CLI_OPTIONS, *argv]) == 0
    result = json.loads((out / "decomposition.json").read_text())
    assert result["settings"]["max_draws"] == 4 and result["settings"]["n_samples"] == 16
    ds = load_trials(out / "trials.nc").sel(target="car")
    methods = result["targets"]["car"]["methods"]
    assert set(methods) == {
        "gaussian+naive_bayes",
        "hierarchical+naive_bayes",
        "hierarchical+instance",
    }
    for name, m in methods.items():
        v = ds["views_to_confidence"].sel({"method": name})
        assert m["rows"]["random"]["views_to_confidence"] == pytest.approx(
            float(v.sel(planner="random").mean())
        )
        assert m["rows"]["greedy_joint"]["views_to_confidence"] == pytest.approx(
            float(v.sel(planner="sampled").mean())
        )
        bound = m["rows"]["clairvoyant"]["views_to_confidence"]
        assert list(m["rows"]) == rows.split(",")
        assert all(bound <= r["views_to_confidence"] for r in m["rows"].values())
        assert m["filter"] == name.split("+")[1]
    assert set(result["targets"]["car"]["view_information"]) == {"gaussian", "hierarchical"}
    assert "hierarchical+instance" in (out / "decomposition.md").read_text()


@pytest.mark.slow  # seven rows of the ladder, three methods
def test_oracle_row_is_the_confident_planner_with_the_oracle_models(folder):
    """With the run's own models as the 'oracle' the oracle rows are the random and confident rows,
    trial by trial: they change the model and nothing else."""
    methods, k_run = experiment_methods(folder)
    rows = (
        "random", "greedy_joint", "confident", "oracle_greedy", "oracle_confident", "oracle_random",
        "oracle",
    )  # fmt: skip
    ds = D.run_decomposition(
        k_run, methods, rows=rows, oracle_methods=methods, confident=CONFIDENT, **OPTIONS
    )
    assert ds["row"].values.tolist() == list(rows)
    v = ds["views_to_confidence"]
    np.testing.assert_array_equal(v.sel(row="oracle").values, v.sel(row="confident").values)
    np.testing.assert_array_equal(v.sel(row="oracle_random").values, v.sel(row="random").values)
    np.testing.assert_array_equal(
        v.sel(row="oracle_greedy").values, v.sel(row="greedy_joint").values
    )
    # a one-draw model: the confident planner's moment matching is exact, so the same views
    np.testing.assert_array_equal(
        v.sel(row="oracle_confident").values, v.sel(row="confident").values
    )
    # without oracle methods the rows are left out
    ds = D.run_decomposition(k_run, methods, rows=rows, confident=CONFIDENT, **OPTIONS)
    assert ds["row"].values.tolist() == ["random", "greedy_joint", "confident"]


def oracle_of(model):
    """A model that disagrees with ``model``: the target shows at views 1 and 3 instead, and it has
    two draws."""
    mu = np.asarray(model.mu)
    mu = np.concatenate([mu[:, :, ::-1], mu[:, :, [1, 2, 3, 0]] + 0.2])
    return ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, 0.5, jnp.float32), jnp.zeros((2, 2))
    )


# eq. 5's replay in make test; the confident planner's (about 27 s) in make test-slow (CI)
@pytest.mark.parametrize("filter", ["naive_bayes", "instance"])
@pytest.mark.parametrize("row", ["greedy_joint", pytest.param("confident", marks=pytest.mark.slow)])
def test_oracle_predictive_rows_replayed_step_by_step(folder, filter, row):
    """The oracle_greedy and oracle_confident trials replayed in Python: at every step the view is the
    unvisited argmin of the method's expected entropy (or the confident planner's step costs) over the
    oracle's responses, both filters updated with what was seen, the method's belief recorded; and
    another oracle changes the views."""
    from scrppl import belief as B
    from scrppl.confident import predictive_confident_scores
    from scrppl.planning import predictive_expected_entropies
    from scrppl.sim.runner import TrialRecord

    methods, k_run = experiment_methods(folder)
    meth = methods["gaussian+naive_bayes"]
    model = meth.model._replace(tau=jnp.full((1, 2), 0.3, jnp.float32))
    oracle = oracle_of(model)
    m = OPTIONS["n_samples"]
    config = D.decomposition_planners(m, confident=CONFIDENT)[row]
    rec = D.run_oracle_predictive_trials(k_run, model, oracle, meth.trials, config, filter=filter)
    assert isinstance(rec, TrialRecord) and rec.views.shape == (TRIALS, A, 3)
    own = D.run_oracle_predictive_trials(k_run, model, model, meth.trials, config, filter=filter)
    assert not np.array_equal(np.asarray(own.views), np.asarray(rec.views))
    for i in range(TRIALS):
        key = jax.random.fold_in(k_run, i)
        resp_r, avail_r = robot_frame(
            meth.trials.responses[i], meth.trials.available[i], meth.trials.pose[i]
        )
        view = np.asarray(meth.trials.start[i])
        b, bo = B.init_belief(filter, model), B.init_belief(filter, oracle)
        visited = np.zeros(A, bool)
        for t in range(A):
            if t > 0:
                views = jnp.asarray([[phi, 0, 0] for phi in range(A)])
                k = jax.random.fold_in(key, t)
                if row == "confident":
                    h = np.array(
                        predictive_confident_scores(
                            k, model, b, oracle, bo, views, ~visited, n_samples=CONFIDENT.n_samples
                        )
                    )
                else:
                    h = np.array(predictive_expected_entropies(k, model, b, oracle, bo, views, m))
                h[visited] = np.inf
                view = np.array([int(np.argmin(h)), 0, 0])
            np.testing.assert_array_equal(np.asarray(rec.views[i, t]), view)
            f = resp_r[view[0], view[1], view[2]]
            b = B.update(model, b, f, *(int(x) for x in view))
            bo = B.update(oracle, bo, f, *(int(x) for x in view))
            visited[view[0]] = True
            np.testing.assert_allclose(
                np.asarray(rec.log_belief[i, t]), np.asarray(B.joint_log_belief(b)), atol=1e-5
            )


def test_oracle_greedy_refuses_another_planner_or_grid(folder):
    methods, k_run = experiment_methods(folder)
    meth = methods["gaussian+naive_bayes"]
    with pytest.raises(ValueError, match="planner 'sampled' or 'confident'"):
        D.run_oracle_predictive_trials(k_run, meth.model, meth.model, meth.trials, PC("random"))
    mu = np.zeros((1, 2, A, 2, 1), np.float32)
    other = ResponseModel(jnp.asarray(mu), jnp.ones_like(jnp.asarray(mu)), jnp.zeros((1, 2)))
    with pytest.raises(ValueError, match="grid"):
        D.run_oracle_predictive_trials(k_run, meth.model, other, meth.trials)


def beacon_world(n=24, seed=5, n_draws=1):
    """A model whose target shows at one relative azimuth only (2: mean 4, noise sd 0.5, 0 elsewhere and
    for the other class), and trials drawn from it: a planner told the true state knows where it shows."""
    rng = np.random.default_rng(seed)
    mu = np.zeros((n_draws, 2, A, 1, 1))
    mu[:, 1, 2] = 4.0
    model = ResponseModel(
        jnp.asarray(mu, jnp.float32), jnp.full(mu.shape, 0.5, jnp.float32),
        jnp.full((n_draws, 2), 0.2, jnp.float32),
    )  # fmt: skip
    label, pose = rng.integers(0, 2, n), rng.integers(0, A, n)
    start = np.zeros((n, 3), np.int64)
    start[:, 0] = rng.integers(0, A, n)
    f = mu[0, label, :, 0, 0] + 0.5 * rng.normal(size=(n, A))  # object frame: f[t, a]
    trials = Trials(
        jnp.asarray(f[:, :, None, None], jnp.float32), jnp.ones((n, A, 1, 1), bool),
        jnp.asarray(label), jnp.asarray(pose), jnp.asarray(start, jnp.int32),
        jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32),
    )  # fmt: skip
    return model, trials


@pytest.mark.parametrize("filter", ["naive_bayes", "instance"])
@pytest.mark.parametrize("row", ["greedy_joint", pytest.param("confident", marks=pytest.mark.slow)])
def test_state_rows_look_first_where_the_true_state_shows_itself(filter, row):
    """Told the class and the pose, eq. 5 and the confident planner look next at the robot azimuth
    ``pose + 2`` where a present target shows (relative azimuth 2, by the view convention ``a = phi -
    theta``), unless the trial started there; not told, the same trials do not all go there; told the
    pose only, they go there for either class. The method's filter is untouched: its first belief is
    the uniform prior's update with the start response."""
    from scrppl import belief as B

    model, trials = beacon_world()
    config = D.decomposition_planners(64, confident=CONFIDENT)[row]
    key = jax.random.key(2)
    told = D.run_oracle_predictive_trials(
        key, model, model, trials, config, filter=filter, known_state="state"
    )
    blind = D.run_oracle_predictive_trials(key, model, model, trials, config, filter=filter)
    label, pose, start = (np.asarray(x) for x in (trials.label, trials.pose, trials.start[:, 0]))
    beacon = (pose + 2) % A
    present = (label == 1) & (start != beacon)
    assert present.sum() >= 5
    first = np.asarray(told.views[:, 1, 0])
    np.testing.assert_array_equal(first[present], beacon[present])
    assert np.any(np.asarray(blind.views[:, 1, 0])[present] != beacon[present])
    # told the pose only, the view that tells a present target from an absent one is the same for
    # every trial: pose + 2 goes first whatever the class
    pose_only = D.run_oracle_predictive_trials(
        key, model, model, trials, config, filter=filter, known_state="pose"
    )
    away = start != beacon
    np.testing.assert_array_equal(np.asarray(pose_only.views[away, 1, 0]), beacon[away])
    for i in range(3):
        resp_r, _ = robot_frame(trials.responses[i], trials.available[i], trials.pose[i])
        b = B.update(model, B.init_belief(filter, model), resp_r[start[i], 0, 0], int(start[i]))
        np.testing.assert_allclose(
            np.asarray(told.log_belief[i, 0]), np.asarray(B.joint_log_belief(b)), atol=1e-5
        )


def test_state_rows_run_without_oracle_models_and_refuse_labels_outside_the_classes(folder):
    """``pose_greedy`` and ``state_greedy`` need no oracle: they are the runner with ``known_state``
    ``"pose"`` and ``"state"`` and the method's own model, for every method; a label the model has no
    class for is refused by name."""
    methods, k_run = experiment_methods(folder)
    rows = ("random", "pose_greedy", "state_greedy", "clairvoyant")
    ds = D.run_decomposition(k_run, methods, rows=rows, **OPTIONS)
    assert ds["row"].values.tolist() == list(rows)
    config = D.decomposition_planners(OPTIONS["n_samples"])["greedy_joint"]
    for name, meth in methods.items():
        for row, told in (("pose_greedy", "pose"), ("state_greedy", "state")):
            rec = D.run_oracle_predictive_trials(
                k_run, meth.model, meth.model, meth.trials, config, filter=meth.filter,
                known_state=told,
            )  # fmt: skip
            met = M.trial_metrics(
                rec.log_belief, rec.responses, rec.observed, meth.trials.label, meth.trials.pose
            )
            np.testing.assert_array_equal(
                ds["views_to_confidence"].sel({"method": name, "row": row}).values,
                met["views_to_confidence"],
            )
    meth = methods["gaussian+naive_bayes"]
    bad = meth.trials._replace(label=jnp.full_like(meth.trials.label, 2))
    with pytest.raises(ValueError, match="labels must index the oracle model's 2 classes"):
        D.run_oracle_predictive_trials(k_run, meth.model, meth.model, bad, known_state="state")
    with pytest.raises(ValueError, match="known_state must be one of"):
        D.run_oracle_predictive_trials(k_run, meth.model, meth.model, meth.trials, known_state=True)


def test_oracle_methods_must_be_the_methods_on_the_same_trials(folder):
    methods, k_run = experiment_methods(folder)
    table = load_response_table(folder / "responses.nc")
    other, _ = load_methods(
        D.study_keys(SEED + 1, 0)[0], folder / "models", table, "dpm", "car", TRIALS
    )
    with pytest.raises(ValueError, match="other trials"):
        D.run_decomposition(k_run, methods, rows=("random", "oracle"), oracle_methods=other)
    renamed = {f"{k}-x": v for k, v in methods.items()}
    with pytest.raises(ValueError, match="oracle methods must be"):
        D.run_decomposition(k_run, methods, rows=("random", "oracle"), oracle_methods=renamed)


@pytest.mark.slow
def test_oracle_models_are_fitted_on_the_test_instances_and_run_as_a_row(folder, tmp_path):
    import jax

    from scrppl.models.data import extract_view_data
    from scrppl.models.gaussian import fit_gaussian
    from scrppl.models.io import load_response_model
    from scrppl.models.mcmc import SamplerConfig

    table = load_response_table(folder / "responses.nc")
    oracle = tmp_path / "oracle"
    config = SamplerConfig(num_warmup=150, num_samples=150, num_chains=2)
    report = D.fit_oracle(jax.random.key(0), table, oracle, "dpm", "car", config)
    assert "ok" in report
    # the oracle Gaussian is the Gaussian of the test split, not of the fit split
    fitted = load_response_model(oracle, "gaussian", "dpm", "car").response_model
    want, _ = fit_gaussian(extract_view_data(table, "dpm", "car", split="test")[0])
    np.testing.assert_allclose(np.asarray(fitted.mu), np.asarray(want.mu), rtol=1e-6)
    not_want, _ = fit_gaussian(extract_view_data(table, "dpm", "car", split="fit")[0])
    assert not np.allclose(np.asarray(fitted.mu), np.asarray(not_want.mu))
    ds, entry = D.decompose_target(
        SEED, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
        kinds=["gaussian"], confident=CONFIDENT, rows=("random", "confident", "oracle", "clairvoyant"),
        oracle_models_dir=oracle, n_boot=200,
        **OPTIONS,
    )  # fmt: skip
    v = ds["views_to_confidence"]
    assert ds["row"].values.tolist() == ["random", "confident", "oracle", "clairvoyant"]
    assert "oracle" in entry["methods"]["gaussian+naive_bayes"]["rows"]
    # the clairvoyant row bounds the run's model; the oracle row is bounded by the oracle model's own
    k_trials, _ = D.study_keys(SEED, 0)
    methods, _ = load_methods(k_trials, oracle, table, "dpm", "car", TRIALS, kinds=["gaussian"])
    meth = methods["gaussian+naive_bayes"]
    bound = D.clairvoyant_bound(meth.model, meth.trials, filter=meth.filter)
    assert np.all(bound <= v.sel(row="oracle").values[0])


# ------------------------------------------------------------------------------------------------
# the model world


def random_world(seed, tau_range, every, view, n=40_000, n_draws=3):
    """A random model of 3 draws and 2 classes, and n trials of it; view `view` missing in every
    `every`-th trial. Returns the arrays (mu, sigma, tau, label, available) and the model and trials."""
    rng = np.random.default_rng(seed)
    mu = rng.normal(0.0, 1.0, size=(n_draws, 2, A, 1, 1))
    sigma = rng.uniform(0.3, 0.8, size=mu.shape)
    tau = rng.uniform(*tau_range, size=(n_draws, 2))
    model = ResponseModel(*(jnp.asarray(x, jnp.float32) for x in (mu, sigma, tau)))
    label = rng.integers(0, 2, n)
    available = np.ones((n, A, 1, 1), bool)
    available[::every, view] = False  # a missing view stays missing
    trials = Trials(
        jnp.zeros((n, A, 1, 1), jnp.float32), jnp.asarray(available), jnp.asarray(label),
        jnp.asarray(rng.integers(0, A, n)), jnp.zeros((n, 3), jnp.int32),
        jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32),
    )  # fmt: skip
    return (mu, sigma, tau, label, available), model, trials


def test_model_world_trials_are_the_models_generative_process():
    """Per class and relative view the drawn responses have the model's mean and variance
    (mixed over draws), views of one trial covary by tau^2, and the trials keep everything else."""
    (mu, sigma, tau, label, available), model, trials = random_world(4, (0.2, 0.6), 7, 3)
    world = D.model_world_trials(jax.random.key(1), model, trials)
    for field in ("available", "label", "pose", "start", "category", "instance"):
        np.testing.assert_array_equal(getattr(world, field), getattr(trials, field))
    f = np.asarray(world.responses, np.float64)[..., 0, 0]
    assert np.all(f[::7, 3] == 0.0)
    for o in (0, 1):
        rows = (label == o) & available[:, 3, 0, 0]
        m, s, t = mu[:, o, :, 0, 0], sigma[:, o, :, 0, 0], tau[:, o]
        mean = m.mean(0)  # uniform over draws
        var = (s**2 + t[:, None] ** 2 + m**2).mean(0) - mean**2
        se = np.sqrt(var / rows.sum())
        np.testing.assert_array_less(np.abs(f[rows].mean(0) - mean), 5 * se)
        np.testing.assert_allclose(f[rows].var(0), var, rtol=0.05)
        # two views of one trial share the instance effect (and the draw): cov = E[tau^2] + cov of mu
        cov = ((t**2) + m[:, 0] * m[:, 1]).mean() - mean[0] * mean[1]
        np.testing.assert_allclose(np.cov(f[rows, 0], f[rows, 1])[0, 1], cov, atol=0.03)


def test_model_world_ladder_runs_and_is_written_beside_the_real_one(folder):
    table = load_response_table(folder / "responses.nc")
    ds, entry = D.decompose_target(
        SEED, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
        kinds=["gaussian"], confident=CONFIDENT, rows=FAST_ROWS, n_boot=200, model_world=True,
        **OPTIONS,
    )  # fmt: skip
    check_bound_below_every_row(ds, entry, FAST_ROWS)
    # same key, same model world: the same numbers
    again, _ = D.decompose_target(
        SEED, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
        kinds=["gaussian"], confident=CONFIDENT, rows=FAST_ROWS, n_boot=200, model_world=True,
        **OPTIONS,
    )  # fmt: skip
    np.testing.assert_array_equal(
        again["views_to_confidence"].values, ds["views_to_confidence"].values
    )
    out = folder / "world"
    out.mkdir()
    result = {"settings": {"model_world": True, "trials": TRIALS, "n_samples": 8,
                           "lookahead_outer": 4, "lookahead_samples": 4,
                           "confident": CONFIDENT._asdict(), "max_draws": None,
                           "confidence_threshold": M.CONFIDENCE, "n_boot": 200},
              "detector": "dpm", "seed": SEED, "targets": {"car": entry}}  # fmt: skip
    written = D.save_decomposition(result, out)
    assert [p.name for p in written] == [
        "decomposition-model-world.json",
        "decomposition-model-world.md",
    ]
    assert "in the model's own world" in written[1].read_text()


def test_filter_world_draws_every_view_independently():
    """independent=True: per class and view the marginal predictive's mean and variance, and two views
    of one trial uncorrelated (the shared draw and instance effect of the model world are gone)."""
    (mu, sigma, tau, label, available), model, trials = random_world(5, (0.4, 0.8), 5, 1)
    world = D.model_world_trials(jax.random.key(2), model, trials, independent=True)
    f = np.asarray(world.responses, np.float64)[..., 0, 0]
    assert np.all(f[::5, 1] == 0.0)
    for o in (0, 1):
        rows = (label == o) & available[:, 1, 0, 0]
        m, s, t = mu[:, o, :, 0, 0], sigma[:, o, :, 0, 0], tau[:, o]
        mean = m.mean(0)
        var = (s**2 + t[:, None] ** 2 + m**2).mean(0) - mean**2
        se = np.sqrt(var / rows.sum())
        np.testing.assert_array_less(np.abs(f[rows].mean(0) - mean), 5 * se)
        np.testing.assert_allclose(f[rows].var(0), var, rtol=0.05)
        # the same trials in the model world covary by about E[tau^2] > 0.16; here they do not
        corr = np.corrcoef(f[rows, 0], f[rows, 2])[0, 1]
        assert abs(corr) < 5 / np.sqrt(rows.sum()), corr


def test_model_optimal_summary_against_numbers_by_hand():
    """The model-optimal entry: means, paired differences and shares of the room from the arrays."""
    import xarray as xr

    views = np.array([[[3, 4, 2, 5], [2, 4, 2, 4], [1, 2, 1, 3]]])  # (method, row, trial)
    ds = xr.Dataset(
        {"views_to_confidence": (("method", "row", "trial"), views)},
        coords={"method": ["m"], "row": ["random", "greedy_joint", "clairvoyant"]},
    )
    bracket = np.array([[1.5, 2.0], [3.0, 3.5], [1.0, 1.5], [3.5, 4.5]])
    got = D.summarise_model_optimal(ds, {"m": bracket}, seed=0, n_boot=200)["m"]
    random, greedy, clair = (views[0, j].astype(float) for j in range(3))
    for k, bound in enumerate(("lower", "upper")):
        x = bracket[:, k]
        r = got[bound]
        assert r["views_to_confidence"] == pytest.approx(x.mean())
        assert r["difference_vs"]["random"]["mean"] == pytest.approx((x - random).mean())
        assert r["difference_vs"]["greedy_joint"]["mean"] == pytest.approx((x - greedy).mean())
        assert "clairvoyant" not in r["difference_vs"]
        share = (random - x).mean() / (random - clair).mean()
        assert r["share_of_room"]["mean"] == pytest.approx(share)
        assert r["share_of_room"]["lo"] <= share <= r["share_of_room"]["hi"]
    # the frame reads them back beside the ladder's means
    rows = {r: {"views_to_confidence": float(views[0, j].mean())}
            for j, r in enumerate(("random", "greedy_joint", "clairvoyant"))}  # fmt: skip
    result = {"targets": {"car": {"methods": {"m": {"rows": rows, "model_optimal": got}}}}}
    frame = D.model_optimal_frame(result)
    assert list(frame.columns) == list(D.MODEL_OPTIMAL_COLUMNS)
    row = frame.loc[("car", "m")]
    assert row["random"] == pytest.approx(random.mean()) and np.isnan(row["confident"])
    assert row["optimal_lower"] == pytest.approx(bracket[:, 0].mean())
    assert row["share_lower"] == got["upper"]["share_of_room"]["mean"]
    assert row["share_upper"] == got["lower"]["share_of_room"]["mean"]
    assert row["upper_minus_greedy"] == pytest.approx((bracket[:, 1] - greedy).mean())
    # the figure draws exactly these: the room from the bound to random, the bracket's bar
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_model_optimal

    fig = plot_model_optimal(result)
    segments = [np.asarray(c.get_segments()[0]) for c in fig.axes[0].collections]
    want = [
        [[clair.mean(), 0], [random.mean(), 0]],
        [[row["optimal_lower"], 0], [row["optimal_upper"], 0]],
    ]
    np.testing.assert_allclose(segments, want)
    plt.close(fig)
    del result["targets"]["car"]["methods"]["m"]["model_optimal"]
    with pytest.raises(ValueError, match="no model-optimal bracket"):
        D.model_optimal_frame(result)
    with pytest.raises(ValueError, match="the ladder 4 trials"):
        D.summarise_model_optimal(ds, {"m": bracket[:3]})
    with pytest.raises(ValueError, match="'clairvoyant' row"):
        D.summarise_model_optimal(ds.sel(row=["random", "greedy_joint"]), {"m": bracket})


@pytest.mark.slow
def test_filter_world_ladder_with_the_model_optimal_bracket(folder):
    """decompose_target(world="filter", model_optimal=...): the bracket's ends in order, between the
    clairvoyant bound's and a planner's reach (up to its Monte Carlo error), saved under its own name."""
    table = load_response_table(folder / "responses.nc")
    settings = {"naive_bayes": {"depth": 1, "n_samples": 8, "n_futures": 8}}
    ds, entry = D.decompose_target(
        SEED, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
        kinds=["gaussian"], confident=CONFIDENT, rows=FAST_ROWS, n_boot=200, model_world=True,
        world="filter", model_optimal=settings, **OPTIONS,
    )  # fmt: skip
    mo = entry["methods"]["gaussian+naive_bayes"]["model_optimal"]
    rows = entry["methods"]["gaussian+naive_bayes"]["rows"]
    assert mo["lower"]["views_to_confidence"] <= mo["upper"]["views_to_confidence"]
    assert 1.0 <= mo["lower"]["views_to_confidence"] and mo["upper"]["views_to_confidence"] <= A + 1
    assert set(mo["lower"]["difference_vs"]) == {"random", "greedy_joint"} and rows
    assert "model_optimal" in entry["seconds"]
    with pytest.raises(ValueError, match="unknown world"):
        D.decompose_target(
            SEED, table, folder / "models", "dpm", "car", trials=TRIALS, max_draws=None,
            kinds=["gaussian"], rows=FAST_ROWS, model_world=True, world="moon",
        )  # fmt: skip
    result = {"settings": {"model_world": True, "world": "filter", "trials": TRIALS,
                           "n_samples": 8, "lookahead_outer": 4, "lookahead_samples": 4,
                           "confident": CONFIDENT._asdict(), "max_draws": None,
                           "confidence_threshold": M.CONFIDENCE, "n_boot": 200},
              "detector": "dpm", "seed": SEED, "targets": {"car": entry}}  # fmt: skip
    out = folder / "filter-world"
    out.mkdir()
    written = D.save_decomposition(result, out)
    assert [p.name for p in written] == [
        "decomposition-filter-world.json",
        "decomposition-filter-world.md",
    ]
    text = written[1].read_text()
    assert "the world each filter assumes" in text and "Model-optimal policy" in text


def test_model_world_refuses_a_model_of_other_views():
    model = tiny_model()
    trials = Trials(
        jnp.zeros((2, A + 1, 1, 1)), jnp.ones((2, A + 1, 1, 1), bool), jnp.zeros(2, jnp.int32),
        jnp.zeros(2, jnp.int32), jnp.zeros((2, 3), jnp.int32), jnp.zeros(2, jnp.int32),
        jnp.zeros(2, jnp.int32),
    )  # fmt: skip
    with pytest.raises(ValueError, match="differ from the trials'"):
        D.model_world_trials(jax.random.key(0), model, trials)


def test_frame_and_figure_show_the_ladders_numbers(ladder):
    """decomposition_frame / view_information_frame read the saved numbers back, and the figures draw
    exactly those: each planner's marker at its paired mean, the black bar at minus the room, which is
    mean(random) - mean(clairvoyant) of the trials themselves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_decomposition, plot_view_information

    ds, entry = ladder
    result = {"settings": {"trials": TRIALS}, "targets": {"car": entry}}
    frame = D.decomposition_frame(result)
    rows = ds["row"].values.tolist()
    assert list(frame["row"]) == rows and set(frame["target"]) == {"car"}
    v = ds["views_to_confidence"].values[0].astype(float)  # (row, trial), the one method
    np.testing.assert_allclose(frame["views"], v.mean(1))
    room = v[rows.index("random")].mean() - v[rows.index("clairvoyant")].mean()
    np.testing.assert_allclose(frame["room"], room)
    assert (frame["lo"] <= frame["minus_random"]).all() and (
        frame["minus_random"] <= frame["hi"]
    ).all()
    assert frame.set_index("row").loc["clairvoyant", "share"] == pytest.approx(1.0)

    fig = plot_decomposition(result)
    ax = fig.axes[0]
    drawn = {
        round(float(line.get_ydata()[0]), 12)
        for line in ax.lines
        if line.get_marker() not in ("None", "", None, "_") and len(line.get_ydata()) == 1
    }
    planners = frame[~frame["row"].isin(["random", "clairvoyant"])]
    assert drawn == {round(float(x), 12) for x in planners["minus_random"]}
    bars = [c for c in ax.collections if c.get_linewidth()[0] == 2]
    assert len(bars) == 1
    np.testing.assert_allclose(bars[0].get_segments()[0][:, 1], -room)
    with pytest.raises(ValueError, match="rows .*two_step.* are not in the decomposition"):
        plot_decomposition(result, rows=["two_step"])
    plt.close(fig)

    info = D.view_information_frame(result)
    np.testing.assert_allclose(info.loc["car"], entry["view_information"]["gaussian"]["nats"][0][0])
    assert info.attrs["prior_entropy"] == pytest.approx(np.log(2))
    fig = plot_view_information(result)
    np.testing.assert_allclose(fig.axes[0].lines[0].get_ydata(), info.loc["car"])
    with pytest.raises(ValueError, match="no per-view information for model kind 'hierarchical'"):
        D.view_information_frame(result, "hierarchical")
    with pytest.raises(ValueError, match="expected a decomposition"):
        D.decomposition_frame({"trials": 3})
    plt.close(fig)


def test_record_keeps_the_decomposition_and_names_a_bad_file(ladder, tmp_path):
    """benchmarks/record_decomposition.py: the record holds the run's numbers unchanged, and a missing
    or corrupt decomposition is named."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).parents[1] / "benchmarks" / "record_decomposition.py"
    spec = importlib.util.spec_from_file_location("record_decomposition", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    _, entry = ladder
    result = {"seed": SEED, "settings": {"trials": TRIALS}, "targets": {"car": entry}}
    (tmp_path / "decomposition.json").write_text(json.dumps(result))
    out = tmp_path / "record.json"
    mod.main([str(tmp_path), "--out", str(out)])
    record = json.loads(out.read_text())
    assert record["real"] == json.loads((tmp_path / "decomposition.json").read_text())
    assert record["model_world"] is None and record["oracle"] is None
    assert record["filter_world"] is None
    assert record["machine"]["cores"] >= 1
    # filter-world runs of one target each are merged into the record, its other parts kept
    world = {"seed": SEED, "settings": {"trials": TRIALS, "world": "filter"}, "seconds_total": 2}
    for target in ("car", "bike"):
        (tmp_path / target).mkdir()
        (tmp_path / target / "decomposition-filter-world.json").write_text(
            json.dumps(dict(world, targets={target: entry}))
        )
    mod.main(
        ["--filter-world-from", str(tmp_path / "car"), str(tmp_path / "bike"), "--out", str(out)]
    )
    again = json.loads(out.read_text())
    assert again["real"] == record["real"] and list(again["filter_world"]["targets"]) == [
        "car",
        "bike",
    ]
    assert again["filter_world"]["seconds_total"] == 4
    with pytest.raises(SystemExit, match="already in another folder"):
        mod.main(
            ["--filter-world-from", str(tmp_path / "car"), str(tmp_path / "car"), "--out", str(out)]
        )
    # the rollout planner's runs: real responses and the filter world, each checked for its row
    rows = {"trials": TRIALS, "rows": ["random", "rollout"]}
    (tmp_path / "roll").mkdir()
    (tmp_path / "roll" / "decomposition.json").write_text(
        json.dumps({"seed": SEED, "settings": rows, "targets": {"car": entry}})
    )
    (tmp_path / "car" / "decomposition-filter-world.json").write_text(
        json.dumps(
            {"seed": SEED, "settings": dict(rows, world="filter"), "targets": {"car": entry}}
        )
    )
    mod.main(["--rollout-from", str(tmp_path / "roll"), "--out", str(out)])
    mod.main(["--rollout-filter-world-from", str(tmp_path / "car"), "--out", str(out)])
    third = json.loads(out.read_text())
    assert third["rollout"]["targets"] == {"car": entry} and third["rollout"]["settings"] == rows
    assert third["rollout_filter_world"]["settings"]["world"] == "filter"
    assert third["filter_world"] == again["filter_world"] and third["real"] == record["real"]
    # the bracket with another model goes to its own key, the one-effect model's is kept
    mod.main(
        [
            "--filter-world-from", str(tmp_path / "bike"),
            "--filter-world-key", "filter_world_azimuth_effect", "--model", "u + v",
            "--out", str(out),
        ]
    )  # fmt: skip
    fourth = json.loads(out.read_text())
    assert fourth["filter_world"] == again["filter_world"] and fourth["rollout"] == third["rollout"]
    assert list(fourth["filter_world_azimuth_effect"]["targets"]) == ["bike"]
    assert fourth["filter_world_azimuth_effect"]["model"] == "u + v"
    mod.main(
        ["--rollout-from", str(tmp_path / "roll"), "--out", str(out)]
    )  # later additions keep it
    assert (
        json.loads(out.read_text())["filter_world_azimuth_effect"]
        == fourth["filter_world_azimuth_effect"]
    )
    (tmp_path / "rollw").mkdir()
    (tmp_path / "rollw" / "decomposition.json").write_text(
        (tmp_path / "car" / "decomposition-filter-world.json").read_text()
    )
    with pytest.raises(SystemExit, match="not the world rollout expects"):
        mod.main(["--rollout-from", str(tmp_path / "rollw"), "--out", str(out)])
    with pytest.raises(SystemExit, match="has no rollout row"):
        mod.main(["--rollout-from", str(tmp_path), "--out", str(out)])
    # the oracle_greedy run: its own key with its model, the rest kept; a run without the row refused
    (tmp_path / "og").mkdir()
    og = {"seed": SEED, "settings": {"trials": TRIALS, "rows": ["random", "oracle_greedy"]}}
    (tmp_path / "og" / "decomposition.json").write_text(
        json.dumps(dict(og, targets={"car": entry}))
    )
    mod.main(["--oracle-greedy-from", str(tmp_path / "og"), "--model", "u + v", "--out", str(out)])
    fifth = json.loads(out.read_text())
    assert fifth["oracle_greedy"]["targets"] == {"car": entry}
    assert fifth["oracle_greedy"]["model"] == "u + v"
    assert fifth["filter_world_azimuth_effect"] == fourth["filter_world_azimuth_effect"]
    assert fifth["real"] == record["real"]
    mod.main(["--rollout-from", str(tmp_path / "roll"), "--out", str(out)])
    assert json.loads(out.read_text())["oracle_greedy"] == fifth["oracle_greedy"]
    with pytest.raises(SystemExit, match="has no oracle_greedy row"):
        mod.main(["--oracle-greedy-from", str(tmp_path / "roll"), "--out", str(out)])
    # the oracle_confident runs, one folder per target, merged into their own key
    for target in ("car", "bike"):
        (tmp_path / f"oc-{target}").mkdir()
        oc = {"seed": SEED, "settings": {"trials": TRIALS, "rows": ["random", "oracle_confident"]}}
        (tmp_path / f"oc-{target}" / "decomposition.json").write_text(
            json.dumps(dict(oc, targets={target: entry}))
        )
    mod.main(
        ["--oracle-confident-from", str(tmp_path / "oc-car"), str(tmp_path / "oc-bike"),
         "--out", str(out)]
    )  # fmt: skip
    sixth = json.loads(out.read_text())
    assert list(sixth["oracle_confident"]["targets"]) == ["car", "bike"]
    assert sixth["oracle_greedy"] == fifth["oracle_greedy"]
    with pytest.raises(SystemExit, match="has no oracle_confident row"):
        mod.main(["--oracle-confident-from", str(tmp_path / "og"), "--out", str(out)])
    # the state rows: their own keys, the oracle rows kept
    (tmp_path / "sg").mkdir()
    sg = {"seed": SEED, "settings": {"trials": TRIALS, "rows": ["random", "state_greedy"]}}
    (tmp_path / "sg" / "decomposition.json").write_text(
        json.dumps(dict(sg, targets={"car": entry}))
    )
    mod.main(["--state-greedy-from", str(tmp_path / "sg"), "--out", str(out)])
    seventh = json.loads(out.read_text())
    assert seventh["state_greedy"]["targets"] == {"car": entry}
    assert seventh["oracle_confident"] == sixth["oracle_confident"]
    assert "state_confident" not in seventh
    with pytest.raises(SystemExit, match="has no state_confident row"):
        mod.main(["--state-confident-from", str(tmp_path / "sg"), "--out", str(out)])
    with pytest.raises(SystemExit, match="has no oracle rows"):
        mod.main([str(tmp_path), "--oracle-from", str(tmp_path), "--out", str(out)])
    with pytest.raises(SystemExit, match="nowhere.*decomposition.json: not found"):
        mod.main([str(tmp_path / "nowhere"), "--out", str(out)])
    (tmp_path / "decomposition.json").write_text("{not json")
    with pytest.raises(SystemExit, match="decomposition.json: not a JSON file"):
        mod.main([str(tmp_path), "--out", str(out)])


def test_upper_policy_record_table_and_views_by_hand():
    """benchmarks/bench_upper_policy.py: views to confidence of a p(true) sequence, and the paired table
    of a hand-made record (differences by hand)."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).parents[1] / "benchmarks" / "bench_upper_policy.py"
    spec = importlib.util.spec_from_file_location("bench_upper_policy", script)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.views_to_confidence([0.5, 0.96, 0.2], 8) == 2
    assert mod.views_to_confidence([0.5, 0.95, 0.9], 3) == 4  # never above: A + 1
    record = {"runs": {"car": {"gaussian+naive_bayes": {
        "trial": [0, 1, 2, 3], "random": [3, 5, 2, 4], "eq5": [2, 5, 2, 3], "upper": [2, 4, 2, 2],
    }}}}  # fmt: skip
    (row,) = mod.paired_table(record, n_boot=500)
    assert row["trials"] == 4 and row["random"] == 3.5 and row["upper"] == 2.5
    assert row["upper - eq5"][0] == pytest.approx(-0.5) and row["eq5 - random"][0] == pytest.approx(
        -0.5
    )
    lo, hi = row["upper - random"][1:]
    assert -2 <= lo <= -1 <= hi <= 0
