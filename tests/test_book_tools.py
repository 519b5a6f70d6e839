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
    assert (
        found[1]["line"]
        == PAGE.splitlines().index('    assert v < 2, "fails for the second value"') + 1
    )
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
    page.write_text(
        PAGE.replace(":tags: [remove-cell]", ":tags: [remove-input]")
        + "\n```{code-cell} ipython3\n:tags: [hide-input]\ny = 1\n\nz = 2\n```\n"
    )
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
        (out / "run.json").write_text(
            json.dumps({"profile": "book", "seed": 0, "dataset_root": str(data)})
        )
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


def _extension():
    spec = importlib.util.spec_from_file_location(
        "scrppl_preexecuted", ROOT / "book" / "_ext" / "scrppl_preexecuted.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_preexecuted_page_keeps_its_cache_key_and_is_told_to_read_the_cache(tmp_path):
    """make book executes the exercise pages beside the pipeline (scripts/pre_execute.py) into a
    jupyter-cache; the build finds them there only if the page it reads, with the cache mode written into
    its front matter (book/_ext/scrppl_preexecuted.py), has the key of the page that was executed."""
    from jupyter_cache import get_cache
    from myst_nb.core.read import read_myst_markdown_notebook

    pre, ext = _script("pre_execute"), _extension()
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    config = pre.md_config()
    assert {"colon_fence", "dollarmath"} <= set(config.enable_extensions)
    executed = pre.read_page(page, config)
    told = read_myst_markdown_notebook(
        ext.with_cache_mode(PAGE, str(tmp_path / "cache")), config=config, add_source_map=True
    )
    assert told.metadata["mystnb"] == {
        "execution_mode": "cache",
        "execution_cache_path": str(tmp_path / "cache"),
    }
    cache = get_cache(str(tmp_path / "cache"))
    assert cache.create_hashed_notebook(executed)[1] == cache.create_hashed_notebook(told)[1]
    # a changed code cell is another key: a stale output cannot be taken for a page that changed
    other = read_myst_markdown_notebook(PAGE.replace("x = 3", "x = 4"), config=config)
    assert cache.create_hashed_notebook(other)[1] != cache.create_hashed_notebook(executed)[1]
    assert ext.with_cache_mode("# no front matter\n", "c") == "# no front matter\n"


def test_reading_order_shares_the_execution_time_between_sphinx_slices():
    """Sphinx reads fixed slices of the page list, one process each: the order the extension gives puts
    about the same execution time in each slice and keeps every page exactly once."""
    from sphinx.util.parallel import make_chunks

    ext = _extension()
    costs = {
        f"chapters/{i:02d}": float(c)
        for i, c in enumerate([63, 60, 33, 27, 25, 24, 22, 20, 15, 15, 11])
    }
    docnames = (
        sorted(costs)
        + [f"api/{i:02d}" for i in range(18)]
        + [f"exercises/{i:02d}" for i in range(10)]
    )
    order = ext.balanced_order(sorted(docnames), 2, costs)
    assert sorted(order) == sorted(docnames)
    loads = [sum(costs.get(d, 0.0) for d in chunk) for chunk in make_chunks(order, 2)]
    naive = [sum(costs.get(d, 0.0) for d in chunk) for chunk in make_chunks(sorted(docnames), 2)]
    assert max(loads) - min(loads) <= 63  # no slice holds more than one extra page's worth
    assert max(loads) < max(naive)
    assert (
        ext.page_costs({"chapters/00"}).get("chapters/00", 0.0) == 0.0
    )  # a pre-executed page is free


@pytest.mark.slow  # starts Jupyter kernels (make test-slow, CI)
def test_pre_execute_caches_a_page_under_the_key_the_build_asks_for_and_fails_on_an_error(tmp_path):
    """scripts/pre_execute.py executes each page in a kernel: a page that runs is cached (with its outputs)
    under the key of the page the build reads, and listed in pages.json; one that raises is not, and the
    script fails."""
    from jupyter_cache import get_cache
    from myst_nb.core.read import read_myst_markdown_notebook

    pre, ext = _script("pre_execute"), _extension()
    page = PAGE.split("Some prose.")[0]  # its first cell only (the second fails on purpose)
    good, bad = tmp_path / "good.md", tmp_path / "bad.md"
    good.write_text(page)
    bad.write_text(page.replace("x = 3\n", "x = 3\nraise ValueError('no')\n", 1))
    cache_dir, times = tmp_path / "cache", tmp_path / "cache" / "pages.json"
    status = pre.main(["--cache", str(cache_dir), "--times", str(times), str(good), str(bad)])
    assert status == 1  # the build then executes the failing page itself and reports its error
    assert set(json.loads(times.read_text())) == {str(tmp_path / "good")}
    told = read_myst_markdown_notebook(
        ext.with_cache_mode(page, str(cache_dir)), config=pre.md_config(), add_source_map=True
    )
    cache = get_cache(str(cache_dir))
    _, merged = cache.merge_match_into_notebook(told)
    assert [c.execution_count for c in merged.cells if c.cell_type == "code"] == [1]  # it ran


@pytest.mark.slow  # starts Jupyter kernels (make test-slow, CI)
def test_pre_execute_stopped_mid_page_kills_its_kernel_and_caches_nothing_half_done(tmp_path):
    """build-book.sh stops the pre-execution when the pipeline ends (SIGUSR1): the pages already done stay
    listed in pages.json and cached; the page being executed is abandoned (its kernel, which runs in a
    session of its own, is killed too) and not listed, so the build executes it."""
    import os
    import signal
    import subprocess
    import time

    import psutil

    page = PAGE.split("Some prose.")[0]
    first, slow = tmp_path / "first.md", tmp_path / "slow.md"
    first.write_text(page)
    slow.write_text(page.replace("x = 3\n", "x = 3\nimport time\ntime.sleep(300)\n", 1))
    cache_dir, times = tmp_path / "cache", tmp_path / "cache" / "pages.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "scripts" / "pre_execute.py"),
            "--cache",
            str(cache_dir),
            "--times",
            str(times),
            str(first),
            str(slow),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 120
    kernels = []
    listed = {}
    while time.monotonic() < deadline and not listed:  # the first page is done and listed
        time.sleep(0.2)
        listed = json.loads(times.read_text()) if times.exists() else {}
    assert set(listed) == {str(tmp_path / "first")}, proc.communicate()[0]
    while time.monotonic() < deadline and not kernels:  # the slow page's kernel has started
        time.sleep(0.2)
        kernels = psutil.Process(proc.pid).children(recursive=True)
    assert kernels, "the second page's kernel never started"
    time.sleep(2)  # into its sleep (a page stopped before its kernel is up is not what this checks)
    kernels = psutil.Process(proc.pid).children(recursive=True)
    proc.send_signal(signal.SIGUSR1)
    output = proc.communicate(timeout=30)[0]
    assert proc.returncode == 143, output

    def alive(process):
        try:
            return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False

    # pre_execute waits for its kernels before it exits: none is left running, even on a busy machine
    assert not [k for k in kernels if alive(k)], output
    assert set(json.loads(times.read_text())) == {str(tmp_path / "first")}
    assert "slow" not in output  # never reported as done
    assert os.path.exists(cache_dir)


def test_lowest_priority_lowers_a_session_leader_and_its_session_but_never_the_callers_session():
    """A kernel leads its own session; where the scheduler groups by session (autogroups) only the
    session's nice value weighs it against the pipeline, so both are set to 19. A process in the caller's
    session gets nice 19 but the session (that of make book and the pipeline) is left alone."""
    import os
    import subprocess

    pre = _script("pre_execute")

    def autogroup(pid):
        """The session's nice value, or None where the system has no readable autogroups (some
        sandboxes show an empty ``/proc/<pid>/autogroup``)."""
        try:
            fields = Path(f"/proc/{pid}/autogroup").read_text().split()
        except OSError:
            return None
        return fields[-1] if fields else None

    mine = autogroup(os.getpid())
    leader = subprocess.Popen(["sleep", "30"], start_new_session=True)
    follower = subprocess.Popen(["sleep", "30"])
    try:
        pre.lowest_priority(leader.pid)
        pre.lowest_priority(follower.pid)
        assert os.getpriority(os.PRIO_PROCESS, leader.pid) == 19
        assert os.getpriority(os.PRIO_PROCESS, follower.pid) == 19
        if mine is not None:  # a kernel with autogroups
            assert autogroup(leader.pid) == "19"
            assert autogroup(follower.pid) == mine == autogroup(os.getpid())
    finally:
        for p in (leader, follower):
            p.kill()
            p.wait()
    pre.lowest_priority(leader.pid)  # a process that has gone: nothing raised


def test_longest_first_orders_by_recorded_cost_and_reads_a_missing_or_broken_record_as_none(
    tmp_path,
):
    """make book hands the pages left after the pipeline to two kernels most expensive first (longest
    processing time first); a page without a recorded time goes first (it may be the longest), and a
    missing or unreadable record gives no costs rather than an error."""
    pre = _script("pre_execute")
    book = pre.BOOK
    pages = [book / "chapters" / f"{n}.md" for n in ("01-a", "02-b", "03-c", "04-new")]
    costs = {"chapters/01-a": 5.0, "chapters/02-b": 60.0, "chapters/03-c": 20.0}
    order = [pre.page_name(p) for p in pre.longest_first(pages, costs)]
    assert order == ["chapters/04-new", "chapters/02-b", "chapters/03-c", "chapters/01-a"]
    assert pre.page_name(tmp_path / "x.md") == str(tmp_path / "x")  # outside the book: its path
    record = tmp_path / "book.json"
    assert pre.recorded_costs(record) == {}
    record.write_text("{not json")
    assert pre.recorded_costs(record) == {}
    record.write_text(json.dumps({"executed_pages_s": {"chapters/01-a": 3}}))
    assert pre.recorded_costs(record) == {"chapters/01-a": 3.0}
    # the record of this checkout names every page the book executes
    recorded = pre.recorded_costs()
    for page in sorted((ROOT / "book" / "chapters").glob("[0-9]*.md")):
        assert f"chapters/{page.stem}" in recorded


@pytest.mark.slow  # starts Jupyter kernels (make test-slow, CI)
def test_pre_execute_in_two_kernels_caches_every_page_and_keeps_the_pages_listed_before(tmp_path):
    """After the pipeline make book executes the remaining pages two at a time into the cache the
    background pass filled: every page is cached under the key the build asks for, the pages listed
    before stay listed, and --background (one page at a time) is refused with --jobs."""
    from jupyter_cache import get_cache
    from myst_nb.core.read import read_myst_markdown_notebook

    pre, ext = _script("pre_execute"), _extension()
    page = PAGE.split("Some prose.")[0]
    pages = []
    for i in range(3):
        p = tmp_path / f"page{i}.md"
        p.write_text(page.replace("x = 3\n", f"x = 3\ny = {i}\n", 1))
        pages.append(p)
    cache_dir, times = tmp_path / "cache", tmp_path / "cache" / "pages.json"
    cache_dir.mkdir()
    times.write_text(json.dumps({"exercises/earlier": 1.5}))
    status = pre.main(
        ["--jobs", "2", "--cache", str(cache_dir), "--times", str(times)] + [str(p) for p in pages]
    )
    assert status == 0
    listed = json.loads(times.read_text())
    assert set(listed) == {"exercises/earlier"} | {str(p.with_suffix("")) for p in pages}
    cache = get_cache(str(cache_dir))
    for p in pages:
        told = read_myst_markdown_notebook(
            ext.with_cache_mode(p.read_text(), str(cache_dir)),
            config=pre.md_config(),
            add_source_map=True,
        )
        _, merged = cache.merge_match_into_notebook(told)
        assert [c.execution_count for c in merged.cells if c.cell_type == "code"] == [1]
    # a page that cannot even be read fails the run (the build then shows why); the others still run
    missing = tmp_path / "missing.md"
    args = [
        "--jobs",
        "2",
        "--cache",
        str(cache_dir),
        "--times",
        str(times),
        str(missing),
        str(pages[0]),
    ]
    assert pre.main(args) == 1
    assert str(missing.with_suffix("")) not in json.loads(times.read_text())
    with pytest.raises(SystemExit):
        pre.main(["--jobs", "2", "--background", "--cache", str(cache_dir), str(pages[0])])
    with pytest.raises(SystemExit):
        pre.main(["--jobs", "0", "--cache", str(cache_dir), str(pages[0])])
