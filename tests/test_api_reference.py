"""The book's API reference: every public name of every public module has a docstring and a place in it.

The reference is generated (``book/_ext/scrppl_api.py``): one page per module of ``scrppl_api_modules``
(``book/_config.yml``), each documenting the names of the module's ``__all__`` it is home to and listing
the others. The fast tests check the pages, the table of contents and the docstrings; the slow one builds
the reference with Sphinx (warnings are errors, nitpicky) and reads every documented name back from its
inventory, together with a chapter-style page whose links must resolve (and one whose link must not).
"""

import re
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
BOOK = ROOT / "book"
sys.path.insert(0, str(BOOK / "_ext"))

import scrppl_api  # noqa: E402

import scrppl  # noqa: E402

CONFIG = yaml.safe_load((BOOK / "_config.yml").read_text())
MODULES = CONFIG["sphinx"]["config"]["scrppl_api_modules"]
DIRECTIVE = re.compile(r"^\.\. scrppl-api:: (\S+)\s*$", re.M)


def _pages() -> dict[str, str]:
    """``{module: page}`` of the reference pages in book/api/."""
    out = {}
    for page in sorted((BOOK / "api").glob("*.md")):
        found = DIRECTIVE.findall(page.read_text())
        assert len(found) == 1, f"{page} documents {found}"
        out[found[0]] = f"api/{page.stem}"
    return out


def _toc_files() -> list[str]:
    files = []

    def walk(entries):
        for e in entries or []:
            if "file" in e:
                files.append(e["file"])
            walk(e.get("sections"))
            walk(e.get("chapters"))

    for part in yaml.safe_load((BOOK / "_toc.yml").read_text())["parts"]:
        walk(part["chapters"])
    return files


def test_every_public_module_has_a_page_in_the_table_of_contents():
    pages = _pages()
    assert sorted(pages) == sorted(MODULES)
    toc = _toc_files()
    missing = [p for p in pages.values() if p not in toc]
    assert not missing, f"reference pages missing from book/_toc.yml: {missing}"
    # the package and every subpackage it names, plus the cluster executor
    expected = {"scrppl", "scrppl.parallel"} | {
        f"scrppl.{n}" for n in scrppl.__all__ if scrppl_api.kind_of(getattr(scrppl, n)) == "module"
    }
    assert set(MODULES) == expected


@pytest.mark.parametrize("module", MODULES)
def test_every_public_name_has_a_docstring_and_a_home(module):
    undocumented, homeless = [], []
    for name, obj in scrppl_api.public_names(module):
        if not scrppl_api.docstring_of(module, name, obj):
            undocumented.append(name)
        kind = scrppl_api.kind_of(obj)
        if kind == "module":
            continue
        home = module if kind == "data" else scrppl_api.home_of(obj, MODULES)
        rst = "\n".join(scrppl_api.module_rst(home, MODULES))
        entry = (
            f".. py:data:: {name}\n   :module: {home}" if kind == "data" else f":: {home}.{name}\n"
        )
        if entry not in rst:
            homeless.append(f"{name} (home {home})")
        # listed in its own module's table, linking to the home
        assert f"   ~{home}.{name}\n" in "\n".join(scrppl_api.module_rst(module, MODULES)) + "\n"
    assert not undocumented, f"{module}: no docstring (or #: comment) for {undocumented}"
    assert not homeless, f"{module}: not documented anywhere in the reference: {homeless}"


def test_home_is_where_a_name_is_defined():
    assert scrppl_api.home_of(scrppl.ViewGrid, MODULES) == "scrppl.views"
    assert scrppl_api.home_of(scrppl.example_model, MODULES) == "scrppl.examples"
    from scrppl.models import ResponseModel

    assert scrppl_api.home_of(ResponseModel, MODULES) == "scrppl.models"
    assert scrppl_api.data_doc("scrppl.models", "MODEL_VERSION", scrppl.models.MODEL_VERSION)


# -- the reference built by Sphinx -------------------------------------------------------------------
CHAPTER = """# A chapter

The filter is {py:func}`scrppl.belief.instance_update`; a model loads with
{py:func}`scrppl.models.io.load_response_model` or {py:func}`~scrppl.example_model`, and
{py:class}`~scrppl.models.ResponseModel` is what it holds.
"""


def _inventory(path: Path) -> set[str]:
    data = path.read_bytes()
    body = zlib.decompress(data.split(b"\n", 4)[4]).decode()
    return {line.split(" ", 1)[0] for line in body.splitlines() if line}


def _build(src: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-b",
            "html",
            "-W",
            "-n",
            "--keep-going",
            "-q",
            str(src),
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )


def _project(tmp_path: Path, chapter: str) -> Path:
    src = tmp_path / "src"
    shutil.copytree(BOOK / "api", src / "api")
    shutil.copytree(BOOK / "_ext", src / "_ext", ignore=shutil.ignore_patterns("__pycache__"))
    (src / "chapter.md").write_text(chapter)
    toc = "\n".join(f"api/{p.stem}" for p in sorted((BOOK / "api").glob("*.md")))
    (src / "index.md").write_text(f"# Test\n\n```{{toctree}}\nchapter\n{toc}\n```\n")
    cfg = CONFIG["sphinx"]["config"]
    prefixes = (
        "scrppl_",
        "nitpick",
        "autodoc",
        "autosummary",
        "autoclass",
        "napoleon",
        "add_module",
    )
    keep = {k: v for k, v in cfg.items() if k.startswith(prefixes)}
    (src / "conf.py").write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(src / '_ext')!r})\n"
        "extensions = ['myst_parser', 'sphinx.ext.autodoc', 'sphinx.ext.autosummary', "
        "'sphinx.ext.napoleon', 'scrppl_api']\n"
        "myst_enable_extensions = ['dollarmath', 'colon_fence']\n"
        "exclude_patterns = ['_build']\n" + "".join(f"{k} = {v!r}\n" for k, v in keep.items())
    )
    return src


@pytest.mark.slow
def test_reference_builds_without_warnings_and_holds_every_name(tmp_path):
    src = _project(tmp_path, CHAPTER)
    proc = _build(src, tmp_path / "html")
    assert proc.returncode == 0, proc.stderr[-5000:]
    documented = _inventory(tmp_path / "html" / "objects.inv")
    missing = []
    for module in MODULES:
        assert module in documented
        for name, obj in scrppl_api.public_names(module):
            kind = scrppl_api.kind_of(obj)
            if kind == "module":
                target = obj.__name__
            elif kind == "data":
                target = f"{module}.{name}"
            else:
                target = f"{scrppl_api.home_of(obj, MODULES)}.{name}"
            if target not in documented:
                missing.append(f"{module}.{name} -> {target}")
    assert not missing, missing
    chapter = (tmp_path / "html" / "chapter.html").read_text()
    for anchor in (
        'href="api/belief.html#scrppl.belief.instance_update"',
        'href="api/models.html#scrppl.models.load_response_model"',
        'href="api/examples.html#scrppl.examples.example_model"',
        'href="api/models.html#scrppl.models.ResponseModel"',
    ):
        assert anchor in chapter, anchor


@pytest.mark.slow
def test_a_chapter_link_to_no_documented_name_fails_the_build(tmp_path):
    src = _project(tmp_path, "# A chapter\n\nSee {py:func}`scrppl.belief.no_such_filter`.\n")
    for page in (src / "api").glob("*.md"):
        if page.stem not in ("index", "belief"):
            page.unlink()
    (src / "index.md").write_text("# Test\n\n```{toctree}\nchapter\napi/index\napi/belief\n```\n")
    proc = _build(src, tmp_path / "html")
    assert proc.returncode != 0
    assert "scrppl.belief.no_such_filter" in proc.stderr
