"""Downloads: every notebook page offers its ``.ipynb``, every exercise page also its student copy.

sphinx-book-theme's download menu (the arrow at the top of a page) offers the page's source (``.md``)
and a print-to-PDF; it offers an ``.ipynb`` only when the page context names one (``ipynb_source``),
which MyST-NB does not do for MyST-markdown notebooks. This extension, for every page MyST-NB executed
as a notebook (a ``jupyter_execute/<page>.ipynb`` exists):

* copies that notebook -- the page's code and its outputs, as the page shows them -- to
  ``_sources/<page>.ipynb`` in the HTML output and names it in ``ipynb_source``, so that the theme's
  menu offers it (".ipynb");
* for the exercise pages (``scrppl_student_pages``, default ``exercises/``), writes the student copy
  (every solution replaced by a stub, outputs cleared) with ``scripts/make_student.py``, the code of
  ``make student``, to ``_sources/<page>-student.ipynb``, and adds it to the menu ("student .ipynb").

The files are served from the built book, offline; ``scripts/check_book.py`` fetches one chapter's and
one exercise page's links and checks they are valid notebooks.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import nbformat
from sphinx.util import logging

LOGGER = logging.getLogger(__name__)
STUDENT_SUFFIX = "-student"


def _make_student_module(srcdir: Path):
    """``scripts/make_student.py`` of the checkout the book is in (found above the source folder)."""
    for folder in [srcdir, *srcdir.parents]:
        script = folder / "scripts" / "make_student.py"
        if script.is_file():
            spec = importlib.util.spec_from_file_location("scrppl_make_student", script)
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module  # its dataclasses look their module up
            spec.loader.exec_module(module)
            return module
    return None


def _executed_notebook(app, pagename: str) -> Path | None:
    path = Path(app.outdir).parent / "jupyter_execute" / f"{pagename}.ipynb"
    return path if path.is_file() else None


def add_downloads(app, pagename, templatename, context, doctree):
    """Before the theme's buttons (priority 500): copy the notebook and name it in the page context."""
    if app.builder.format != "html" or doctree is None:
        return
    executed = _executed_notebook(app, pagename)
    if executed is None:
        return
    target = Path(app.outdir) / "_sources" / f"{pagename}.ipynb"
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(executed, target)
    context["ipynb_source"] = f"{pagename}.ipynb"
    if not any(pagename.startswith(p) for p in app.config.scrppl_student_pages):
        return
    source = Path(app.env.doc2path(pagename))
    module = getattr(app, "_scrppl_make_student", None)
    if module is None:
        module = _make_student_module(Path(app.srcdir).resolve())
        app._scrppl_make_student = module
    if module is None:
        LOGGER.warning("scripts/make_student.py not found above %s: no student copy", app.srcdir)
        return
    student = module.student_copy(source)
    nbformat.validate(student)
    out = Path(app.outdir) / "_sources" / f"{pagename}{STUDENT_SUFFIX}.ipynb"
    nbformat.write(student, out)
    context["scrppl_student_ipynb"] = f"{pagename}{STUDENT_SUFFIX}.ipynb"


def add_student_button(app, pagename, templatename, context, doctree):
    """After the theme's buttons (priority 502): the student copy in the download menu."""
    name = context.get("scrppl_student_ipynb")
    if not name:
        return
    for group in context.get("header_buttons", []):
        if group.get("label") == "download-buttons":
            group["buttons"].insert(
                1,
                {
                    "type": "link",
                    "url": f"{context['pathto']('_sources', 1)}/{name}",
                    "text": "student .ipynb",
                    "icon": "fas fa-pencil-alt",
                    "tooltip": "Download the student copy: answers to write, outputs cleared",
                    "label": "download-student-button",
                },
            )
            return


def setup(app):
    app.add_config_value("scrppl_student_pages", ["exercises/"], "html")
    app.connect("html-page-context", add_downloads, priority=500)
    app.connect("html-page-context", add_student_button, priority=502)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
