"""The book's API reference, generated from the docstrings of scrppl's public modules.

``.. scrppl-api:: scrppl.belief`` (inside an ``{eval-rst}`` block of a page in ``book/api/``) expands
into the module's docstring (``automodule``), a summary table of every name in its ``__all__``
(``autosummary``) and each name's documentation (``autofunction``, ``autoclass``, ``py:data``), in the
order of ``__all__``. A name is documented once, on the page of its *home*: of the public modules
(``scrppl_api_modules`` in ``_config.yml``) whose ``__all__`` holds it, the one closest to where it is
defined (``scrppl.ViewGrid`` is documented as ``scrppl.views.ViewGrid``); other pages list it in their
table, linking there. A module in ``__all__`` that has no page of its own (``scrppl.models.transforms``)
is documented inline.

Cross-references: a ``py`` reference to any import path of a documented object resolves to it
(``scrppl.models.io.load_response_model`` links to ``scrppl.models.load_response_model``), in the
chapters as in the docstrings. In the reference pages, a docstring's reference to something that is
not public (a private helper, a submodule without a page) is shown as code, without a warning;
anywhere else an unresolved ``scrppl`` reference stays a warning, i.e. an error of the build.
Docstrings are numpy style (``sphinx.ext.napoleon``); ``tests/test_api_reference.py`` checks that every
public name has a docstring and a place here.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import make_refnode, nested_parse_with_titles

LOGGER = logging.getLogger(__name__)
API_PREFIX = "api/"
_MISSING = object()


# -- what is documented where ----------------------------------------------------------------------
def kind_of(obj: Any) -> str:
    """``"module"``, ``"exception"``, ``"class"``, ``"function"`` or ``"data"``."""
    if inspect.ismodule(obj):
        return "module"
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if callable(obj):
        return "function"
    return "data"


def public_names(module_name: str) -> list[tuple[str, Any]]:
    """``(name, object)`` of every name in the module's ``__all__``, in order."""
    module = importlib.import_module(module_name)
    names = getattr(module, "__all__", None)
    if names is None:
        raise ValueError(f"{module_name} has no __all__: its public names are not declared")
    return [(name, getattr(module, name)) for name in names]


def home_of(obj: Any, pages: list[str]) -> str | None:
    """The public module whose page documents ``obj`` (a class or function): see the module docstring."""
    holders = [m for m in pages if any(o is obj for _, o in public_names(m))]
    if not holders:
        return None
    defined = getattr(obj, "__module__", "") or ""

    def closeness(m: str) -> int:
        return len(m) if defined == m or defined.startswith(m + ".") else -1

    return max(holders, key=lambda m: (closeness(m), -pages.index(m)))


def data_doc(module_name: str, name: str, value: Any) -> list[str]:
    """The ``#:`` comment (or docstring after the assignment) of a module-level constant.

    Looked up in the module, then in the modules below it that hold the same object, then in every
    loaded ``scrppl`` module (a constant re-exported from where it is defined).
    """
    from sphinx.pycode import ModuleAnalyzer

    loaded = sorted(m for m in list(sys.modules) if m.startswith("scrppl."))
    below = [m for m in loaded if m.startswith(module_name + ".")]
    for candidate in [module_name, *below, *loaded]:
        mod = sys.modules.get(candidate)
        if mod is None or getattr(mod, name, _MISSING) is not value:
            continue
        try:
            docs = ModuleAnalyzer.for_module(candidate).find_attr_docs()
        except Exception:  # noqa: BLE001 - no source to analyse
            continue
        lines = [line for line in docs.get(("", name), []) if line is not None]
        if any(line.strip() for line in lines):
            return list(lines)
    return []


def docstring_of(module_name: str, name: str, obj: Any) -> str:
    """The documentation a public name shows in the reference (empty if it has none)."""
    kind = kind_of(obj)
    if kind == "data":
        return "\n".join(data_doc(module_name, name, obj)).strip()
    doc = obj.__doc__ if kind in ("class", "exception") else inspect.getdoc(obj)
    doc = (doc or "").strip()
    if kind in ("class", "exception") and doc.startswith(f"{obj.__name__}("):
        return ""  # the NamedTuple / dataclass signature Python writes when there is no docstring
    return doc


def _value_repr(value: Any, limit: int = 80) -> str | None:
    text = repr(value)
    return text if len(text) <= limit and "\n" not in text else None


# -- the generated reStructuredText ----------------------------------------------------------------
def module_rst(module_name: str, pages: list[str]) -> list[str]:
    """The rST of one module: its docstring, the summary table, then the entries of the names it is home to."""
    entries = public_names(module_name)
    out = [f".. automodule:: {module_name}", "   :no-members:", ""]
    # the table names each entry in full (its home may be another module): outside any module
    out += [".. currentmodule:: None", ""]
    out += [".. rubric:: Contents", "", ".. autosummary::", "   :nosignatures:", ""]
    body: list[str] = []
    for name, obj in entries:
        kind = kind_of(obj)
        if kind == "module":
            target = obj.__name__
            out.append(f"   ~{target}")
            if target not in pages:  # no page of its own: documented here
                body += [f".. rubric:: {target}", ""]
                body += module_rst(target, pages)
                body += [f".. currentmodule:: {module_name}", ""]
            continue
        if kind == "data":
            out.append(f"   ~{module_name}.{name}")
            body += data_rst(module_name, name, obj)
            continue
        home = home_of(obj, pages) or module_name
        if home == module_name:
            directive = {"class": "autoclass", "exception": "autoexception"}.get(
                kind, "autofunction"
            )
            body.append(f".. {directive}:: {module_name}.{name}")
            if kind in ("class", "exception"):
                body.append("   :members:")
            body.append("")
        out.append(f"   ~{home}.{name}")
    return [*out, "", f".. currentmodule:: {module_name}", "", *body]


def data_rst(module_name: str, name: str, value: Any) -> list[str]:
    """A module-level constant: ``py:data`` with its value (when short) and its ``#:`` comment."""
    out = [f".. py:data:: {name}", f"   :module: {module_name}"]
    shown = _value_repr(value)
    if shown is not None:
        out.append(f"   :value: {shown}")
    out.append("")
    doc = data_doc(module_name, name, value)
    out += [f"   {line}" if line.strip() else "" for line in doc] or ["   (constant)"]
    return [*out, ""]


class ScrpplApi(SphinxDirective):
    """``.. scrppl-api:: module`` -- the module's docstring, summary table and public names."""

    required_arguments = 1
    has_content = False

    def run(self) -> list[nodes.Node]:
        module_name = self.arguments[0].strip()
        pages = list(self.config.scrppl_api_modules)
        if module_name not in pages:
            raise self.error(f"{module_name} is not in scrppl_api_modules (book/_config.yml)")
        lines = module_rst(module_name, pages)
        node = nodes.container(classes=["scrppl-api"])
        source = StringList(lines, source=f"<scrppl-api {module_name}>")
        nested_parse_with_titles(self.state, source, node)
        self.env.note_dependency(importlib.import_module(module_name).__file__)
        return node.children


# -- references ------------------------------------------------------------------------------------
def _resolve_path(path: str) -> Any:
    """The object at a dotted path (a module, or attributes below one), or ``_MISSING``."""
    parts = path.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except Exception:  # noqa: BLE001 - not a module (or not importable): try a shorter prefix
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr, _MISSING)
            if obj is _MISSING:
                return _MISSING
        return obj
    return _MISSING


def _documented_index(env) -> dict[int, tuple[str, Any]]:
    """``id(object) -> (fullname, entry)`` of the documented modules, classes, functions and methods."""
    domain = env.get_domain("py")
    index: dict[int, tuple[str, Any]] = {}
    for fullname, entry in domain.objects.items():
        if entry.objtype not in ("module", "class", "exception", "function", "method"):
            continue
        obj = _resolve_path(fullname)
        if obj is _MISSING:
            continue
        key = id(obj)
        if key not in index or (index[key][1].aliased and not entry.aliased):
            index[key] = (fullname, entry)
    return index


def missing_reference(app, env, node, contnode):
    """Resolve a ``py`` reference to an import path of a documented object; quiet in the API pages."""
    in_reference = node.get("refdoc", "").startswith(API_PREFIX)
    target = node.get("reftarget", "")
    modname = node.get("py:module") or ""
    candidates = [target] if target.startswith("scrppl") else []
    if modname.startswith("scrppl") and not target.startswith("scrppl."):
        candidates.insert(0, f"{modname}.{target}")  # a name relative to the docstring's module
    if node.get("refdomain") != "py" or not candidates:
        # e.g. a docstring's :doc: link to a page the book does not have: text in the reference
        return contnode if in_reference and node.get("refdomain") in ("py", "std") else None
    cache = getattr(env, "_scrppl_api_index", None)
    if cache is None or cache[0] != len(env.get_domain("py").objects):
        cache = (len(env.get_domain("py").objects), _documented_index(env))
        env._scrppl_api_index = cache
    index = cache[1]
    for path in candidates:
        obj = _resolve_path(path)
        if obj is _MISSING or id(obj) not in index:
            continue
        fullname, entry = index[id(obj)]
        return make_refnode(
            app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, fullname
        )
    if in_reference:  # a docstring naming something that is not public: code, not a link
        return contnode
    return None


def data_docstring(app, what, name, obj, options, lines):
    """A re-exported constant's ``#:`` comment from where it is defined (for the summary tables)."""
    if what not in ("data", "attribute") or not name.startswith("scrppl."):
        return
    module_name, _, attr = name.rpartition(".")
    if module_name not in sys.modules:
        return
    doc = data_doc(module_name, attr, obj)
    if doc:
        lines[:] = doc


def skip_member(app, what, name, obj, skip, options):
    """Leave out the ``Alias for field number N`` attributes of NamedTuples (the docstring lists them)."""
    doc = getattr(obj, "__doc__", None) or ""
    if what == "class" and doc.startswith("Alias for field number"):
        return True
    return None


def setup(app):
    app.setup_extension("sphinx.ext.autodoc")
    app.setup_extension("sphinx.ext.autosummary")
    app.setup_extension("sphinx.ext.napoleon")
    app.add_config_value("scrppl_api_modules", [], "env")
    app.add_directive("scrppl-api", ScrpplApi)
    app.connect("missing-reference", missing_reference)
    app.connect("autodoc-skip-member", skip_member)
    app.connect("autodoc-process-docstring", data_docstring)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
