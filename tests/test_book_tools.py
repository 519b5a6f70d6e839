"""The book's own tools: the claims record (scripts/book_claims.py), the code balance
(scripts/book_code_balance.py) and the stage-by-stage run comparison (scripts/compare_runs.py)."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

ROOT = Path(__file__).resolve().parent.parent


def _script(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


PAGE = """---
jupytext:
  text_representation:
    format_name: myst
kernelspec:
  display_name: Python 3
  language: python
  name: python3
---

# A page

```{code-cell} ipython3
%matplotlib inline
x = 3
assert x == 3  # holds
```

Some prose.

```{code-cell} ipython3
:tags: [remove-cell]
import numpy as np
for v in (1, 2):
    assert v < 2, "fails for the second value"
np.testing.assert_allclose(x, 3.0)
assert x == 3  # holds
x
```
"""


def test_claims_are_recorded_not_raised(tmp_path):
    """Every assert (and np.testing.assert_*) is found, executed, and recorded with whether it held in
    every evaluation, the page going on after a failed one; a duplicate assert gets its own entry."""
    claims = _script("book_claims")
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    nb, found = claims.instrument_page(page, "chapters/page")
    texts = [c["text"] for c in found]
    assert texts == [
        "assert x == 3",
        'assert v < 2, "fails for the second value"',
        "np.testing.assert_allclose(x, 3.0)",
        "assert x == 3",
    ]
    assert found[0]["id"] != found[3]["id"]  # the same text twice: two claims
    assert found[1]["line"] == PAGE.splitlines().index("    assert v < 2, \"fails for the second value\"") + 1
    run = tmp_path / "run"
    run.mkdir()
    rows = claims.run_page(nb, found, run, tmp_path / "log.jsonl", timeout=60)
    held = {r["text"] + str(i): r["held"] for i, r in enumerate(rows)}
    assert list(held.values()) == [True, False, True, True]
    assert "fails for the second value" in rows[1]["detail"]


def test_pages_run_in_parallel_kernels_each_with_its_run_and_log(tmp_path, monkeypatch):
    """--jobs 2: each page's kernel sees the run folder through its own environment (this process's is
    untouched), the record keeps the pages' order, and a failed claim on one page makes the exit 1."""
    claims = _script("book_claims")
    first = tmp_path / "a.md"
    first.write_text(PAGE)
    second = tmp_path / "b.md"
    second.write_text(
        PAGE.split("# A page")[0]
        + "# B\n\n```{code-cell} ipython3\nimport os\n"
        + "assert os.environ['SCRPPL_RESULTS'].endswith('run')\n```\n"
    )
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"profile": "book", "seed": 3}))
    monkeypatch.setattr(claims, "ROOT", tmp_path)
    (tmp_path / "book" / "chapters").mkdir(parents=True)
    pages = []
    for src in (first, second):
        dst = tmp_path / "book" / "chapters" / src.name
        dst.write_text(src.read_text())
        pages.append(str(dst))
    monkeypatch.delenv("SCRPPL_RESULTS", raising=False)
    out = tmp_path / "record.json"
    code = claims.main(
        ["--run", f"s3={run}", "--pages", *pages, "--jobs", "2", "--out", str(out), "--require-all"]
    )
    assert code == 1  # the second assert of the first page fails
    assert "SCRPPL_RESULTS" not in __import__("os").environ
    record = json.loads(out.read_text())
    assert [c["page"] for c in record["claims"]] == ["chapters/a"] * 4 + ["chapters/b"]
    assert [c["held_in"]["s3"] for c in record["claims"]] == [True, False, True, True, True]


def test_code_balance_counts_hidden_and_visible_lines(tmp_path):
    balance = _script("book_code_balance")
    page = tmp_path / "page.md"
    page.write_text(PAGE.replace(":tags: [remove-cell]", ":tags: [remove-input]")
                    + "\n```{code-cell} ipython3\n:tags: [hide-input]\ny = 1\n\nz = 2\n```\n")
    # visible: 3 lines of the first cell (magic included) + 2 of the hide-input cell; hidden: 6
    assert balance.balance(page) == {"visible": 5, "hidden": 6, "cells": 3}
    assert balance.main([str(page), "--check"]) == 1


def test_compare_runs_finds_the_first_stage_that_differs(tmp_path):
    compare = _script("compare_runs")
    runs = {}
    for name, pixel in (("a", 10), ("b", 10)):
        data, out = tmp_path / f"data-{name}", tmp_path / f"out-{name}"
        (data / "car").mkdir(parents=True)
        (data / "car" / "car_1.png").write_bytes(bytes([pixel]) * 16)
        out.mkdir()
        (out / "run.json").write_text(json.dumps({"profile": "book", "seed": 0,
                                                   "dataset_root": str(data)}))
        score = np.arange(6.0)
        if name == "b":
            score[4] += 1e-6  # one response rounded differently
        xr.Dataset({"score": ("cell", score)}).to_netcdf(out / "responses.nc")
        runs[name] = out
    result = compare.compare_runs(runs["a"], runs["b"])
    assert result["stages"]["dataset"]["identical"]
    assert result["first_difference"] == "detect"
    detect = result["stages"]["detect"]["variables"]["score"]
    assert detect["cells_differ"] == 1 and detect["max_abs_diff"] == pytest.approx(1e-6)
