"""The book's downloads: each notebook page's .ipynb and each exercise page's student copy.

``book/_ext/scrppl_downloads.py`` puts them in the theme's download menu; ``scripts/check_book.py``
fetches the links of the built pages over loopback and checks they are notebooks (the page check of
``make book``). The check itself is tested here on hand-made pages; a small Sphinx build (slow) checks
the extension with the book's theme and the real exercise notebook of chapter 2.
"""

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_book", ROOT / "scripts" / "check_book.py")
check_book = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check_book)


def _link(href: str, label: str) -> str:
    return (
        f'<li><a href="{href}" target="_blank"\n   class="btn btn-sm btn-{label} dropdown-item"\n'
        f'   title="x" data-bs-placement="left" data-bs-toggle="tooltip">x</a></li>'
    )


def _notebook(outputs: bool, tags=()) -> str:
    cell = nbformat.v4.new_code_cell("x = 1", metadata={"tags": list(tags)} if tags else {})
    if outputs:
        cell.outputs = [nbformat.v4.new_output("stream", text="1\n")]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_markdown_cell("# t"), cell])
    return nbformat.writes(nb)


def test_check_downloads_fetches_and_validates(tmp_path):
    html = tmp_path / "html"
    (html / "chapters").mkdir(parents=True)
    (html / "exercises").mkdir()
    (html / "_sources" / "chapters").mkdir(parents=True)
    (html / "_sources" / "exercises").mkdir(parents=True)
    (html / "chapters" / "01-a.html").write_text(
        _link("../_sources/chapters/01-a.ipynb", "download-notebook-button")
    )
    (html / "_sources" / "chapters" / "01-a.ipynb").write_text(_notebook(outputs=True))
    (html / "exercises" / "01-a.html").write_text(
        _link("../_sources/exercises/01-a.ipynb", "download-notebook-button")
        + _link("../_sources/exercises/01-a-student.ipynb", "download-student-button")
    )
    (html / "_sources" / "exercises" / "01-a.ipynb").write_text(_notebook(outputs=True))
    (html / "_sources" / "exercises" / "01-a-student.ipynb").write_text(
        _notebook(outputs=False, tags=["answer"])
    )
    (html / "exercises" / "02-b.html").write_text(
        _link("../_sources/exercises/02-b.ipynb", "download-notebook-button")
    )
    (html / "_sources" / "exercises" / "02-b.ipynb").write_text("{not json")
    (html / "chapters" / "02-b.html").write_text("<p>no menu</p>")
    server, port = check_book.serve(html)
    try:
        problems, fetched = check_book.check_downloads(html, "chapters/01-a", port)
        assert problems == [] and fetched["download-notebook-button"]["cells"] == 2
        problems, fetched = check_book.check_downloads(html, "exercises/01-a", port)
        assert problems == [] and set(fetched) == {
            "download-notebook-button",
            "download-student-button",
        }
        problems, _ = check_book.check_downloads(html, "exercises/02-b", port)
        assert any("no download-student link" in p for p in problems)
        assert any("not a valid notebook" in p for p in problems)
        problems, _ = check_book.check_downloads(html, "chapters/02-b", port)
        assert problems == ["no download-notebook link"]
        # a student copy with outputs, or without an answer cell, is not one
        (html / "_sources" / "exercises" / "01-a-student.ipynb").write_text(_notebook(outputs=True))
        problems, _ = check_book.check_downloads(html, "exercises/01-a", port)
        assert any("has outputs" in p for p in problems)
        assert any("no answer cell" in p for p in problems)
        assert check_book.check_downloads(html, "notation", port) == ([], {})
    finally:
        server.shutdown()
        server.server_close()


CHAPTER = """---
jupytext:
  text_representation:
    format_name: myst
kernelspec:
  name: python3
  display_name: Python 3
---

# A chapter

```{code-cell} python
x = 1 + 1
```
"""


@pytest.mark.slow
def test_extension_offers_notebook_and_student_copy(tmp_path):
    src = tmp_path / "src"
    (src / "chapters").mkdir(parents=True)
    (src / "exercises").mkdir()
    (src / "chapters" / "01-a.md").write_text(CHAPTER)
    shutil.copy(ROOT / "notebooks" / "02-dataset.md", src / "exercises" / "02-dataset.md")
    shutil.copytree(
        ROOT / "book" / "_ext", src / "_ext", ignore=shutil.ignore_patterns("__pycache__")
    )
    # the extension finds scripts/make_student.py above the source folder
    shutil.copytree(
        ROOT / "scripts", tmp_path / "scripts", ignore=shutil.ignore_patterns("__pycache__")
    )
    (src / "index.md").write_text(
        "# Test\n\n```{toctree}\nchapters/01-a\nexercises/02-dataset\n```\n"
    )
    (src / "conf.py").write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(src / '_ext')!r})\n"
        "extensions = ['myst_nb', 'sphinx_exercise', 'scrppl_downloads']\n"
        "html_theme = 'sphinx_book_theme'\n"
        "html_theme_options = {'use_download_button': True}\n"
        "nb_execution_mode = 'off'\n"
        "myst_enable_extensions = ['dollarmath', 'colon_fence', 'amsmath']\n"
        "suppress_warnings = ['mystnb.unknown_mime_type']\n"
        "exclude_patterns = ['_build']\n"
    )
    out = tmp_path / "_build" / "html"
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-b", "html", "-q", str(src), str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert check_book.download_links(out, "chapters/01-a") == {
        "download-notebook-button": "../_sources/chapters/01-a.ipynb"
    }
    links = check_book.download_links(out, "exercises/02-dataset")
    assert links["download-student-button"] == "../_sources/exercises/02-dataset-student.ipynb"
    assert "download-notebook-button" not in check_book.download_links(out, "index")
    server, port = check_book.serve(out)
    try:
        for page in ("chapters/01-a", "exercises/02-dataset"):
            problems, _ = check_book.check_downloads(out, page, port)
            assert problems == [], (page, problems)
    finally:
        server.shutdown()
        server.server_close()
    # the student copy is make_student's: stubs instead of answers, no solution text
    student = json.loads((out / "_sources" / "exercises" / "02-dataset-student.ipynb").read_text())
    text = "".join("".join(c["source"]) for c in student["cells"])
    assert "NotImplementedError" in text and "solution-start" not in text
