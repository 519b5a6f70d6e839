import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from scipy import stats


def test_readme_library_example_runs():
    text = (Path(__file__).parents[1] / "README.md").read_text()
    block = re.search(r"## Using the library\n\n```python\n(.*?)```", text, re.S).group(1)
    env: dict = {}
    exec(compile(block, "README.md", "exec"), env)  # noqa: S102 - the README's own example
    # p(o | f = 0.9 at phi = 0) by Bayes' rule over (o, theta), written out: class 1 responds
    # mu[(0 - theta) mod 8] with sd 0.5, class 0 responds 0 with sd 0.5, uniform prior
    mu = np.asarray(env["model"].mu)[0, :, :, 0, 0]  # (O, A)
    np.testing.assert_array_equal(mu, [[0.0] * 8, [0.5, 1, 2, 1, 0.5, 1, 2, 1]])
    rel = (0 - np.arange(8)) % 8
    joint = stats.norm.pdf(0.9, mu[:, rel], 0.5)
    want = joint.sum(1) / joint.sum()
    p = np.asarray(env["belief"].class_marginal(env["b"]))
    np.testing.assert_allclose(p, want, rtol=1e-5)
    # the planner never returns the view already visited, and returns the best-scored one
    scores = np.asarray(env["scores"])
    assert bool(env["found"]) and int(env["view"][0]) == int(np.argmin(scores)) != 0
    assert np.isinf(scores[0]) and np.isfinite(scores[1:]).all()
    # which is also best by the exact expected entropy (sampling picked one of the tied optima)
    views = jnp.asarray([[phi, 0, 0] for phi in range(8)])
    exact = np.asarray(
        env["planning"].expected_entropies(
            None, env["model"], env["b"], views, env["planning"].PlannerConfig("quadrature")
        )
    )
    assert exact[int(env["view"][0])] <= exact[1:].min() + 1e-4


def test_readme_loading_example_runs_on_a_run_folder(tmp_path, monkeypatch, rng):
    """The README's loading lines, run as written on a small run folder of the same layout."""
    import matplotlib

    matplotlib.use("Agg")
    from scrppl.models.io import model_path, save_gaussian, save_posterior
    from scrppl.models.response import ResponseModel, log_prob
    from scrppl.responses import empty_response_table, save_response_table
    from scrppl.views import ViewGrid
    from tests.test_models_predictive import A, E, S, _posterior

    run = tmp_path / "results"
    grid = ViewGrid(A, (25.0, 35.0), (1.0,))
    split = np.array([["test"] * 2, ["test"] * 2])
    table = empty_response_table(["dpm"], ["car"], ["bicycle", "car"], 2, grid, split)
    table["score"][:] = rng.normal(size=table["score"].shape)
    save_response_table(table, run / "responses.nc")
    tree, _ = _posterior(rng)
    save_posterior(model_path(run / "models", "hierarchical", "dpm", "car"), tree)
    g = ResponseModel(
        jnp.asarray(rng.normal(size=(1, 2, A, E, S))), jnp.ones((1, 2, A, E, S)), jnp.zeros((1, 2))
    )
    meta = {"detector": "dpm", "target": "car", "transform": "identity"}
    save_gaussian(
        model_path(run / "models", "gaussian", "dpm", "car"), g, np.ones((2, A, E, S)), meta
    )

    text = (Path(__file__).parents[1] / "README.md").read_text()
    block = re.search(r"After\n`make reproduce`:\n\n```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    env: dict = {}
    exec(compile(block, "README.md", "exec"), env)  # noqa: S102 - the README's own example
    m, raw = env["m"], env["raw"]
    assert m.kind == "hierarchical" and m.transform == "identity" and m.grid.n_azimuth == A
    assert raw.shape == (2, A, E, S)
    # the README's log density is the predictive's at the same response and view
    want = log_prob(m.response_model, jnp.asarray(raw[0, 2, 0, 0]), 1, 2, 0, 0)
    np.testing.assert_allclose(np.asarray(env["m"].log_prob(raw[0, 2, 0, 0], o=1, a=2)), want)
    assert len(env["fig"].axes) == 2  # one row: positives and negatives


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, re.S)


def _quick_start(text: str) -> str:
    return re.search(r"## Quick start: [^\n]*\n.*?```python\n(.*?)```", text, re.S).group(1)


def test_readme_quick_start_runs(monkeypatch, tmp_path):
    """The quick start for importers: an example model, two responses filtered, the next view, a plot."""
    import matplotlib

    matplotlib.use("Agg")
    text = (Path(__file__).parents[1] / "README.md").read_text()
    block = _quick_start(text)
    assert len(block.strip().splitlines()) <= 20
    monkeypatch.chdir(tmp_path)  # the block must not need a run folder or any file
    env: dict = {}
    exec(compile(block, "README.md", "exec"), env)  # noqa: S102 - the README's own example
    p = np.asarray(env["belief"].class_marginal(env["b"]))
    assert 0.5 < p[1] < 1  # two car-like scores: more likely a car than not, not yet certain
    assert bool(env["found"]) and int(env["view"][0]) not in (0, 4)
    assert np.isinf(np.asarray(env["scores"])[[0, 4]]).all()
    assert len(env["history"]) == 3 and len(env["fig"].axes) >= 3


def test_readme_python_blocks_are_all_executed_or_explained():
    """Every Python block of the README is run by a test above, or named here with why it is not."""
    text = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = _python_blocks(text)
    executed = [
        _quick_start(text),
        re.search(r"## Using the library\n\n```python\n(.*?)```", text, re.S).group(1),
        re.search(r"After\n`make reproduce`:\n\n```python\n(.*?)```", text, re.S).group(1),
    ]
    not_run = {
        'open_dataset("3Dcategories"': "needs a copy of the Savarese dataset",
        "from dask_jobqueue import SLURMCluster": "needs a SLURM cluster (dask-jobqueue)",
    }
    for block in blocks:
        if block in executed:
            continue
        assert any(marker in block for marker in not_run), f"a README block no test runs:\n{block}"
    assert len(blocks) == len(executed) + len(not_run)


def test_readme_counts_the_exercises_there_are():
    """The README's exercise count and range per chapter are those of the notebooks and the registry."""
    from scrppl.exercises import list_exercises

    readme = (Path(__file__).parents[1] / "README.md").read_text()
    m = re.search(r"end with (\d+) exercises \((\w+) to (\w+) each\)", readme)
    assert m, "the README no longer states the number of exercises"
    words = ["zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine"]
    notebooks = sorted((Path(__file__).parents[1] / "notebooks").glob("[0-9][0-9]-*.md"))
    per_page = [p.read_text().count("{exercise-start}") for p in notebooks]
    assert int(m.group(1)) == sum(per_page) == len(list_exercises())
    assert (words.index(m.group(2)), words.index(m.group(3))) == (min(per_page), max(per_page))
