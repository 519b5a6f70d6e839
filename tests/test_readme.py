import re
from pathlib import Path

import numpy as np


def test_readme_library_example_runs():
    text = (Path(__file__).parents[1] / "README.md").read_text()
    block = re.search(r"## Using the library\n\n```python\n(.*?)```", text, re.S).group(1)
    env: dict = {}
    exec(compile(block, "README.md", "exec"), env)  # noqa: S102 - the README's own example
    p = np.asarray(env["belief"].class_marginal(env["b"]))
    assert p.shape == (2,) and np.isclose(p.sum(), 1.0)
    assert bool(env["found"]) and int(env["view"][0]) != 0  # never the view already visited
