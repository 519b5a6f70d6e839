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
    mu = np.asarray(env["mu"])[0, :, :, 0, 0]  # (O, A)
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
        env["planning"].expected_entropies(None, env["model"], env["b"], views, "quadrature")
    )
    assert exact[int(env["view"][0])] <= exact[1:].min() + 1e-4
