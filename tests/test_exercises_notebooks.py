"""The exercise notebooks, checked both ways.

* Every solution notebook (``notebooks/NN-*.md``) executes, prints no stderr (the book is built with
  warnings as errors) and every check in it passes.
* Every student copy (``scripts/make_student.py``) executes up to its stubs, and every check fails with
  "not answered yet"; with deliberately wrong answers (``scrppl.exercises.wrong_answers``) in place of the
  stubs, every check fails with a hint (one kernel a copy: the wrong answers are probed after its last
  cell).
* No solution text or solution marker reaches a student copy.
* The notebooks follow the format (``notebooks/README.md``) and are wired into the book.

Each notebook execution starts a Jupyter kernel (a few seconds): ``benchmarks/bench_exercises.py``
records the time of the whole exercise suite. The solution notebooks' execution (about two and a half
CPU-minutes) runs with the slow tests (``make test-slow``, its own CI step); ``make book`` executes the
same pages as the book's exercise pages, where a failed check or a line on stderr fails the build.
"""

import ast
import importlib.util
import json
import re
import sys
from pathlib import Path

import jupytext
import nbformat
import pytest
import yaml
from nbclient import NotebookClient

from scrppl.exercises import get_exercise, list_exercises, wrong_answers

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("make_student", ROOT / "scripts" / "make_student.py")
make_student = importlib.util.module_from_spec(_spec)
sys.modules["make_student"] = make_student  # dataclasses look their module up
_spec.loader.exec_module(make_student)

NOTEBOOKS = make_student.exercise_notebooks(ROOT / "notebooks")
IDS = [p.stem for p in NOTEBOOKS]
TIMEOUT = 300  # per cell


def execute(nb: nbformat.NotebookNode, allow_errors: bool = False) -> nbformat.NotebookNode:
    client = NotebookClient(
        nb,
        timeout=TIMEOUT,
        kernel_name="python3",
        allow_errors=allow_errors,
        resources={"metadata": {"path": str(ROOT / "notebooks")}},
    )
    client.execute()
    return nb


def errors(cell) -> list:
    return [o for o in cell.get("outputs", []) if o.output_type == "error"]


def stdout(cell) -> str:
    return "".join(
        o.text for o in cell.get("outputs", []) if o.output_type == "stream" and o.name == "stdout"
    )


def is_check(cell) -> bool:
    return cell.cell_type == "code" and "check" in cell.get("metadata", {}).get("tags", [])


def check_calls(source: str) -> list[tuple[str, list[str]]]:
    """``check("2.1", a, b)`` calls in a cell: the id and the names of the answers."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "check":
            ex_id = node.args[0].value
            out.append((ex_id, [a.id for a in node.args[1:]]))
    return out


def test_there_are_exercise_notebooks_for_chapters_2_to_4():
    stems = {p.stem[:2] for p in NOTEBOOKS}
    assert {"02", "03", "04", "05", "06", "07", "08", "09", "10", "11"} <= stems
    assert sum(len(list_exercises(int(s))) for s in stems) >= 12


# -- the solution notebooks -------------------------------------------------------------------------
@pytest.mark.slow  # make book executes the same pages (an error or a stderr line fails it)
@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_solution_notebook_executes_and_its_checks_pass(path):
    nb = execute(jupytext.read(path))
    checks = [c for c in nb.cells if is_check(c)]
    assert checks, f"{path.name} has no check cell"
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        assert not errors(cell), f"{path.name}: cell failed:\n{cell.source}"
        stderr = [o for o in cell.outputs if o.output_type == "stream" and o.name == "stderr"]
        assert not stderr, f"{path.name}: stderr output (a build error in the book):\n{stderr}"
    for cell in checks:
        for ex_id, _ in check_calls(cell.source):
            assert f"✓ Exercise {ex_id}:" in stdout(cell), (
                f"{path.name}: check {ex_id} did not pass"
            )


# -- the student copies -----------------------------------------------------------------------------
@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_student_copy_stops_at_its_stubs_and_wrong_answers_fail(path):
    """One execution of the student copy, cell by cell, then a probe per known wrong answer.

    * Untouched, every check of the copy fails with "not answered yet", and nothing else fails.
    * After the last cell, each check is run again with its answers bound to each wrong answer of
      :func:`scrppl.exercises.wrong_answers` in turn: every one fails with a hint. (A check compares the
      answers it is given against the library on its own inputs, so where the probe runs does not matter;
      one kernel serves both halves.)
    """
    student = make_student.student_copy(path)
    n_own = len(student.cells)
    probes, expected = [], []
    for cell in student.cells:
        if not is_check(cell):
            continue
        for ex_id, names in check_calls(cell.source):
            for k in range(len(wrong_answers(ex_id))):
                bind = (
                    "from scrppl.exercises import wrong_answers as _wrong_answers\n"
                    f"({', '.join(names)},) = _wrong_answers({ex_id!r})[{k}]"
                )
                probes.append(nbformat.v4.new_code_cell(bind))
                probes.append(nbformat.v4.new_code_cell(f"check({ex_id!r}, {', '.join(names)})"))
                expected.append((n_own + len(probes) - 1, ex_id, k))
    student.cells = student.cells + probes
    nb = execute(student, allow_errors=True)
    own = nb.cells[:n_own]
    first_error = next(i for i, c in enumerate(own) if c.cell_type == "code" and errors(c))
    first_check = next(i for i, c in enumerate(own) if is_check(c))
    assert first_error == first_check, "the copy fails before its first check"
    for cell in own:
        if cell.cell_type != "code":
            continue
        if is_check(cell):
            (err,) = errors(cell)
            assert err.ename == "ExerciseNotAnswered", (cell.source, err.ename, err.evalue)
            assert "not answered yet" in err.evalue
        else:
            assert not errors(cell), f"{path.name}: a non-check cell failed:\n{cell.source}"
    assert expected
    for index, ex_id, k in expected:
        assert not errors(nb.cells[index - 1]), (ex_id, k, "binding the wrong answer failed")
        (err,) = errors(nb.cells[index])
        assert err.ename == "ExerciseFailed", (ex_id, k, err.ename, err.evalue)
        assert "not correct yet" in err.evalue
        assert "input" in err.evalue or "seed=" in err.evalue


@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_student_copy_contains_no_solution(path, tmp_path):
    source = jupytext.read(path)
    student = make_student.student_copy(path)
    target = make_student.write(student, tmp_path / path.stem, "ipynb")
    text = target.read_text()
    assert "solution" not in text.lower()  # no directive, tag or word
    sources = "\n".join(c.source for c in student.cells)
    assert not re.search(r"\{(exercise|solution)-(start|end)\}|:class: dropdown", sources)
    for cell in student.cells:
        assert not cell.get("outputs") and cell.get("execution_count") is None
    inside, outside = make_student.solution_text(source)
    allowed = {line.strip() for line in outside}
    stubs = [c for c in student.cells if "answer" in c.get("metadata", {}).get("tags", [])]
    allowed |= {line.strip() for c in stubs for line in c.source.splitlines()}
    leaked = [
        line.strip()
        for line in inside
        if len(line.strip()) >= 8 and line.strip() not in allowed and line.strip() in sources
    ]
    assert not leaked, f"solution lines in the student copy of {path.name}: {leaked}"


# -- the format -------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", NOTEBOOKS, ids=IDS)
def test_notebook_follows_the_exercise_format(path):
    nb = jupytext.read(path)
    assert nb.metadata["jupytext"]["text_representation"]["format_name"] == "myst"
    chapter = int(path.stem[:2])
    starts = [
        d
        for c in nb.cells
        if c.cell_type == "markdown"
        for d in make_student.find_directives(c.source.splitlines())
        if d.name == "exercise-start"
    ]
    ids = [make_student.exercise_id(d.options["label"]) for d in starts]
    # numbered by position, as the book numbers them (Exercise k on the page of chapter N is N.k)
    assert ids == [f"{chapter}.{k}" for k in range(1, len(ids) + 1)]
    assert len(ids) >= 3
    assert ids == [e.id for e in list_exercises(chapter)], (
        "every exercise needs its check and vice versa"
    )
    for d, ex_id in zip(starts, ids, strict=True):
        ex = get_exercise(ex_id)
        assert d.arg == f"{ex.title} ({ex.difficulty})", "title and difficulty as registered"
    checked = [i for c in nb.cells if is_check(c) for i, _ in check_calls(c.source)]
    assert checked == ids
    # the student copy is well-formed
    student = make_student.student_copy(path)
    nbformat.validate(student)
    headings = [
        line
        for c in student.cells
        if c.cell_type == "markdown"
        for line in c.source.splitlines()
        if line.startswith("### Exercise ")
    ]
    assert headings == [get_exercise(i).heading.replace("Exercise", "### Exercise", 1) for i in ids]


def test_exercise_pages_are_in_the_book_from_the_same_files():
    link = ROOT / "book" / "exercises"
    assert link.is_symlink() and (link.resolve() == (ROOT / "notebooks").resolve())
    toc = yaml.safe_load((ROOT / "book" / "_toc.yml").read_text())
    chapters = [c for part in toc["parts"] for c in part["chapters"]]
    for path in NOTEBOOKS:
        (entry,) = [c for c in chapters if c["file"] == f"chapters/{path.stem}"]
        assert {"file": f"exercises/{path.stem}"} in entry.get("sections", []), path.stem


# -- make_student itself ----------------------------------------------------------------------------
def test_stub_keeps_signatures_and_docstrings_only():
    source = '''import zlib


def f(x, y=1):
    """Say what f returns."""
    # a comment with a hint
    return zlib.crc32(x) + y


@staticmethod
def g(
    a,
    b,
):
    return a + b


answer = f(b"x") * 2
x, y = 1, 2
print(answer)
'''
    stub = make_student.stub_source(source, "9.1")
    assert stub == (
        'def f(x, y=1):\n    """Say what f returns."""\n'
        '    raise NotImplementedError("Exercise 9.1: write f()")\n\n\n'
        "@staticmethod\ndef g(\n    a,\n    b,\n):\n"
        '    raise NotImplementedError("Exercise 9.1: write g()")\n'
        "answer = ...  # Exercise 9.1: your answer\n"
        "x = ...  # Exercise 9.1: your answer\ny = ...  # Exercise 9.1: your answer\n"
    )
    assert make_student.stub_source("print(1)\n", "9.1") == "# Exercise 9.1: your code here\n"
    with pytest.raises(make_student.ExerciseFormatError, match="own lines"):
        make_student.stub_source("def f(x): return x\n", "9.1")


def _nb(*cells):
    nb = nbformat.v4.new_notebook()
    for kind, source, tags in cells:
        cell = (
            nbformat.v4.new_markdown_cell(source)
            if kind == "md"
            else nbformat.v4.new_code_cell(source, metadata={"tags": tags} if tags else {})
        )
        nb.cells.append(cell)
    return nb


GOOD = [
    (
        "md",
        "# T\n\nSee {doc}`../chapters/09-x` and {cite}`meger2010viewpoint`.\n\n"
        "```{exercise-start} Thing (easy)\n:label: ex-9-1\n```\n\nDo it.\n\n```{exercise-end}\n```\n\n"
        "```{solution-start} ex-9-1\n:class: dropdown\n```",
        None,
    ),
    ("code", "def f(x):\n    return 2 * x", ["solution"]),
    ("code", 'check("9.1", f)', ["check"]),
    ("md", "Because doubling.\n\n```{solution-end}\n```\n\nAfter the block.", None),
    ("code", "f(3)", None),
]


def test_student_notebook_on_a_small_example():
    student = make_student.student_notebook(_nb(*GOOD))
    sources = [c.source for c in student.cells]
    assert sources[0].startswith("# T\n\nSee chapter 09-x of the book and [meger2010viewpoint].")
    assert "### Exercise 9.1: Thing (easy)\n\nDo it." in sources[0]
    assert "solution" not in sources[0]
    assert sources[1] == 'def f(x):\n    raise NotImplementedError("Exercise 9.1: write f()")'
    assert sources[2] == 'check("9.1", f)'
    assert sources[3] == "After the block."  # the discussion before solution-end is dropped
    assert sources[4] == "f(3)"


@pytest.mark.parametrize(
    "cells, message",
    [
        ([GOOD[0], GOOD[2], GOOD[3]], "needs a code cell tagged 'solution'"),
        ([GOOD[0], GOOD[1], GOOD[3]], "tagged 'check'"),
        (GOOD[:3], "not closed"),
        ([("md", GOOD[0][1].replace(":label: ex-9-1\n", ""), None), *GOOD[1:]], "has no :label:"),
        ([("md", GOOD[0][1].replace("ex-9-1", "ex91"), None), *GOOD[1:]], "ex-<chapter>-<number>"),
        ([("code", "x = 1", ["solution"])], "outside a solution block"),
    ],
)
def test_format_errors_are_reported(cells, message):
    with pytest.raises(make_student.ExerciseFormatError, match=re.escape(message)):
        make_student.student_notebook(_nb(*cells))


def test_make_student_command_writes_copies(tmp_path, capsys):
    assert make_student.main(["--out", str(tmp_path)]) == 0
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == [p.stem + ".ipynb" for p in NOTEBOOKS]
    for p in tmp_path.iterdir():
        nb = nbformat.read(p, as_version=4)
        nbformat.validate(nb)
        assert "jupytext" not in nb.metadata and nb.metadata["kernelspec"]["name"] == "python3"
        assert json.loads(p.read_text())["nbformat"] == 4
    assert make_student.main([str(NOTEBOOKS[0]), "--out", str(tmp_path), "--format", "md"]) == 0
    md = (tmp_path / f"{NOTEBOOKS[0].stem}.md").read_text()
    assert "format_name: myst" in md and "solution" not in md.lower()
    assert "exercises" in capsys.readouterr().out
