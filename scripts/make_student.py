"""Write student copies of the exercise notebooks: every solution replaced by a stub, outputs cleared.

The exercise notebooks in ``notebooks/`` are the single source of the exercises (the book shows them,
solutions in dropdowns, through the ``book/exercises`` link). Each exercise is written with
sphinx-exercise's gated directives::

    ```{exercise-start} Relative azimuth (easy)
    :label: ex-2-1
    ```
    (the statement, and any code cells that give inputs)
    ```{exercise-end}
    ```
    ```{solution-start} ex-2-1
    :class: dropdown
    ```
    (code cells tagged `solution`: the answer; code cells tagged `check`: the call to scrppl.exercises.check;
     markdown and untagged code cells: the worked discussion)
    ```{solution-end}
    ```

The student copy keeps everything outside the solution blocks (with the directives turned into plain
headings ``### Exercise 2.1: Relative azimuth (easy)`` and MyST roles into plain text), and of each
solution block keeps only

* a *stub* for every ``solution`` cell, derived from its code: each top-level function keeps its
  signature and docstring and gets the body ``raise NotImplementedError("Exercise 2.1: ...")``; each
  top-level assignment becomes ``name = ...``; everything else (imports, statements, comments) is
  dropped;
* the ``check`` cells, unchanged.

The discussion, the directives and every output are dropped, so no solution text reaches the copy
(``tests/test_exercises_notebooks.py`` checks this, and that the copies fail their checks).

Usage::

    python scripts/make_student.py [NOTEBOOK.md ...] [--out build/student] [--format ipynb|md]

Without notebooks, every ``notebooks/NN-*.md`` is converted.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import jupytext
import nbformat

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"

#: The opening line of a fenced MyST directive: ```{name} argument (backticks, tildes or colons).
FENCE = re.compile(r"^(?P<fence>`{3,}|~{3,}|:{3,})\{(?P<name>[A-Za-z0-9_-]+)\}\s*(?P<arg>.*?)\s*$")
GATED = ("exercise-start", "exercise-end", "solution-start", "solution-end")
LABEL = re.compile(r"^ex-(\d+)-(\d+)$")
ROLE = re.compile(r"\{(?P<role>[a-z:-]+)\}`(?P<text>[^`]*)`")
SOLUTION_TAG = "solution"
CHECK_TAG = "check"
STUB_TAG = "answer"


class ExerciseFormatError(ValueError):
    """A notebook does not follow the exercise format (see ``notebooks/README.md``)."""


@dataclass
class Directive:
    """One gated sphinx-exercise directive found in a markdown cell."""

    name: str
    arg: str
    options: dict[str, str]
    start: int  # first line (the opening fence)
    end: int  # line after the closing fence


def find_directives(lines: list[str]) -> list[Directive]:
    """The gated exercise/solution directives in the lines of one markdown cell, in order."""
    out = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m or m.group("name") not in GATED:
            i += 1
            continue
        fence = m.group("fence")
        options: dict[str, str] = {}
        j = i + 1
        while j < len(lines) and lines[j].strip() != fence:
            opt = re.match(r"^:([A-Za-z_-]+):\s*(.*)$", lines[j].strip())
            if opt:
                options[opt.group(1)] = opt.group(2)
            elif lines[j].strip():
                raise ExerciseFormatError(
                    f"the {m.group('name')} directive may hold only options (`:label: ...`); "
                    f"found {lines[j]!r} before its closing {fence}"
                )
            j += 1
        if j == len(lines):
            raise ExerciseFormatError(f"the {m.group('name')} directive is not closed with {fence}")
        out.append(Directive(m.group("name"), m.group("arg"), options, i, j + 1))
        i = j + 1
    return out


def exercise_id(label: str) -> str:
    """``"ex-2-1"`` -> ``"2.1"``."""
    m = LABEL.match(label.strip())
    if not m:
        raise ExerciseFormatError(
            f"exercise labels look like ex-<chapter>-<number> (e.g. ex-2-1), got {label!r}"
        )
    return f"{int(m.group(1))}.{int(m.group(2))}"


def plain_roles(text: str) -> str:
    """MyST roles as plain text: {doc}`../chapters/02-dataset` -> the chapter name, {cite}`x` -> [x]."""

    def repl(m: re.Match) -> str:
        role, body = m.group("role"), m.group("text")
        target = re.match(r"^(?P<title>.*?)\s*<(?P<target>[^>]+)>$", body)
        if target:
            return target.group("title")
        if role == "doc":
            return f"chapter {body.rstrip('/').split('/')[-1]} of the book"
        if role == "cite":
            return f"[{body}]"
        return f"`{body}`" if role in ("code", "py:func", "func", "mod") else body

    return ROLE.sub(repl, text)


# -- stubs ------------------------------------------------------------------------------------------
def stub_source(source: str, ex_id: str) -> str:
    """The stub of one solution cell: signatures and docstrings of its functions, ``name = ...``.

    Parameters
    ----------
    source
        The solution cell's code.
    ex_id
        The exercise id, for the messages in the stub.
    """
    try:
        tree = ast.parse(source)
    except SyntaxError as err:
        raise ExerciseFormatError(
            f"exercise {ex_id}: the solution cell does not parse: {err}"
        ) from err
    lines = source.splitlines()
    out: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            body0 = node.body[0]
            if body0.lineno == node.lineno:
                raise ExerciseFormatError(
                    f"exercise {ex_id}: write the body of {node.name}() on its own lines"
                )
            header = [lines[first - 1]] + [
                ln for ln in lines[first : body0.lineno - 1] if not ln.strip().startswith("#")
            ]
            indent = " " * body0.col_offset
            doc = []
            if (
                isinstance(body0, ast.Expr)
                and isinstance(body0.value, ast.Constant)
                and isinstance(body0.value.value, str)
            ):
                doc = lines[body0.lineno - 1 : body0.end_lineno]
            if out:
                out += ["", ""]
            out += header + doc
            out.append(
                f'{indent}raise NotImplementedError("Exercise {ex_id}: write {node.name}()")'
            )
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
            for name in names:
                out.append(f"{name} = ...  # Exercise {ex_id}: your answer")
        # imports, loops, expressions, comments: part of the answer, dropped
    if not out:
        out = [f"# Exercise {ex_id}: your code here"]
    return "\n".join(out) + "\n"


# -- notebooks --------------------------------------------------------------------------------------
def _tags(cell) -> list[str]:
    return list(cell.get("metadata", {}).get("tags", []))


def student_notebook(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """The student copy of an exercise notebook (a new notebook; ``nb`` is not changed)."""
    cells = []
    in_solution: str | None = None  # the id of the open solution block
    in_exercise: str | None = None
    seen_solution_cell = seen_check_cell = False
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            lines = cell.source.splitlines()
            keep: list[str] = []
            pos = 0
            for d in find_directives(lines):
                if in_solution is None:
                    keep += lines[pos : d.start]
                pos = d.end
                if d.name == "exercise-start":
                    if in_exercise or in_solution:
                        raise ExerciseFormatError("an exercise starts inside another exercise")
                    if "label" not in d.options:
                        raise ExerciseFormatError(f"exercise {d.arg!r} has no :label:")
                    in_exercise = exercise_id(d.options["label"])
                    keep.append(f"### Exercise {in_exercise}: {d.arg}")
                elif d.name == "exercise-end":
                    if not in_exercise:
                        raise ExerciseFormatError("exercise-end without exercise-start")
                    in_exercise = None
                elif d.name == "solution-start":
                    if in_solution or in_exercise:
                        raise ExerciseFormatError(
                            "a solution starts inside an exercise or another solution"
                        )
                    in_solution = exercise_id(d.arg)
                    seen_solution_cell = seen_check_cell = False
                else:  # solution-end
                    if not in_solution:
                        raise ExerciseFormatError("solution-end without solution-start")
                    if not seen_solution_cell or not seen_check_cell:
                        raise ExerciseFormatError(
                            f"the block of exercise {in_solution} needs a code cell tagged "
                            f"'{SOLUTION_TAG}' and one tagged '{CHECK_TAG}'"
                        )
                    in_solution = None
            if in_solution is None:
                keep += lines[pos:]
            text = plain_roles("\n".join(keep)).strip("\n")
            text = re.sub(r"\n{3,}", "\n\n", text)
            if text.strip():
                cells.append(nbformat.v4.new_markdown_cell(text))
        elif cell.cell_type == "code":
            tags = _tags(cell)
            if in_solution is None:
                if SOLUTION_TAG in tags:
                    raise ExerciseFormatError(
                        f"a cell tagged '{SOLUTION_TAG}' outside a solution block:\n{cell.source}"
                    )
                cells.append(_code(cell.source, tags))
            elif SOLUTION_TAG in tags:
                seen_solution_cell = True
                cells.append(_code(stub_source(cell.source, in_solution), [STUB_TAG]))
            elif CHECK_TAG in tags:
                seen_check_cell = True
                cells.append(_code(cell.source, [CHECK_TAG]))
            # other code cells in a solution block belong to the worked discussion: dropped
        else:  # raw cells
            if in_solution is None:
                cells.append(nbformat.v4.new_raw_cell(cell.source))
    if in_solution or in_exercise:
        raise ExerciseFormatError(
            f"exercise {in_solution or in_exercise}: a block is not closed at the end of the notebook"
        )
    out = nbformat.v4.new_notebook()
    out.metadata = {k: v for k, v in nb.metadata.items() if k in ("kernelspec", "language_info")}
    out.cells = cells
    return out


def solution_text(nb: nbformat.NotebookNode) -> tuple[list[str], list[str]]:
    """The lines of an exercise notebook inside solution blocks, and the lines outside them.

    Inside: the code of ``solution`` cells and of the discussion's code cells, and the discussion's
    markdown (the directives themselves excluded). Outside: everything else, including the ``check``
    cells (which the student copy keeps). Used to test that no solution text reaches a student copy.
    """
    inside: list[str] = []
    outside: list[str] = []
    open_block = False
    for cell in nb.cells:
        lines = cell.source.splitlines()
        if cell.cell_type == "markdown":
            pos = 0
            for d in find_directives(lines):
                (inside if open_block else outside).extend(lines[pos : d.start])
                pos = d.end
                if d.name == "solution-start":
                    open_block = True
                elif d.name == "solution-end":
                    open_block = False
            (inside if open_block else outside).extend(lines[pos:])
        elif open_block and CHECK_TAG not in _tags(cell):
            inside.extend(lines)
        else:
            outside.extend(lines)
    return inside, outside


def _code(source: str, tags: list[str]) -> nbformat.NotebookNode:
    keep = [t for t in tags if t not in (SOLUTION_TAG,)]
    cell = nbformat.v4.new_code_cell(source.rstrip("\n"))
    if keep:
        cell.metadata["tags"] = keep
    return cell


def student_copy(path: Path) -> nbformat.NotebookNode:
    """Read an exercise notebook (MyST markdown or ipynb) and return its student copy."""
    nb = jupytext.read(path)
    try:
        student = student_notebook(nb)
    except ExerciseFormatError as err:
        raise ExerciseFormatError(f"{path}: {err}") from None
    intro = nbformat.v4.new_markdown_cell(
        f"*Student copy of `notebooks/{path.name}` (made by `make student`). Write your answer in the "
        "cell under each exercise (replace the `raise NotImplementedError(...)` lines and the `...`), "
        "then run the `check(...)` cell after it.*"
    )
    student.cells.insert(
        1 if student.cells and student.cells[0].cell_type == "markdown" else 0, intro
    )
    return student


def write(nb: nbformat.NotebookNode, path: Path, fmt: str) -> Path:
    """Write a student copy as ``.ipynb`` (default) or MyST markdown ``.md``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "ipynb":
        target = path.with_suffix(".ipynb")
        nbformat.validate(nb)
        nbformat.write(nb, target)
    else:
        target = path.with_suffix(".md")
        jupytext.write(nb, target, fmt="md:myst")
    return target


def exercise_notebooks(folder: Path = NOTEBOOKS) -> list[Path]:
    """The exercise notebooks of ``folder``: ``NN-name.md`` (or ``.ipynb``), in order."""
    return sorted(p for p in folder.iterdir() if re.match(r"^\d\d-.*\.(md|ipynb)$", p.name))


def _rel(path: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebooks", nargs="*", type=Path, help="default: notebooks/NN-*.md")
    parser.add_argument("--out", type=Path, default=ROOT / "build" / "student")
    parser.add_argument("--format", choices=("ipynb", "md"), default="ipynb")
    args = parser.parse_args(argv)
    sources = args.notebooks or exercise_notebooks()
    if not sources:
        print("make_student: no exercise notebooks found", file=sys.stderr)
        return 1
    for src in sources:
        try:
            nb = student_copy(src)
        except ExerciseFormatError as err:
            print(f"make_student: {err}", file=sys.stderr)
            return 1
        target = write(nb, args.out / src.stem, args.format)
        n = sum("check" in c.get("metadata", {}).get("tags", []) for c in nb.cells)
        print(f"make_student: {_rel(src)} -> {_rel(target)} ({n} exercises)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
