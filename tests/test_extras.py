"""The extras: a feature whose optional dependency is missing says which extra to install.

``scrppl[render]`` (the synthetic renderer) and ``scrppl[dask]`` (the cluster) are optional; the core
(models, filters, planners, K-way, metrics, plotting, exercises) must import without them. A missing
package is simulated with ``sys.modules[name] = None`` in process, and by a site folder without the
extras' packages in a subprocess (the wheel in a clean environment: ``tests/test_dist.py``, slow).
"""

import os
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest

from scrppl._extras import EXTRAS, MissingExtraError, require

ROOT = Path(__file__).resolve().parents[1]


def test_require_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(ImportError, match=r'pip install "scrppl\[render\]"') as err:
        require("render", "pyvista")
    assert isinstance(err.value, MissingExtraError) and err.value.extra == "render"
    assert "renderer" in str(err.value)
    # a module below the missing one: the message names both (submodules another test imported in this
    # process are forgotten first, or the import would find them cached)
    for name in [m for m in sys.modules if m.startswith("vtkmodules.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "vtkmodules", None)
    with pytest.raises(
        MissingExtraError, match="needs vtkmodules.util.numpy_support.*no module named 'vtkmodules"
    ):
        require("render", "vtkmodules.util.numpy_support")
    with pytest.raises(ValueError, match="unknown extra"):
        require("gpu", "pyvista")
    assert require("dask", "json").__name__ == "json"  # present: just the module


def test_renderer_without_render_extra(monkeypatch):
    from scrppl.datasets.synthetic import backgrounds
    from scrppl.datasets.synthetic.render import SceneRenderer

    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(ImportError, match=r'pip install "scrppl\[render\]"'):
        SceneRenderer(32, 32)
    monkeypatch.setitem(sys.modules, "skimage.data", None)
    with pytest.raises(ImportError, match=r'pip install "scrppl\[render\]"'):
        backgrounds._photo.__wrapped__("astronaut")


def test_meshes_without_render_extra(monkeypatch):
    from scrppl.datasets.synthetic import shapes

    # the category modules import trimesh when first used: forget them for this test
    for name in [m for m in sys.modules if m.startswith("scrppl.datasets.synthetic.categories")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "trimesh", None)
    assert "car" in shapes.CATEGORIES  # the names need no extra
    with pytest.raises(ImportError, match=r'pip install "scrppl\[render\]"'):
        shapes.build_instance("car", 0)


def test_cluster_without_dask_extra(monkeypatch):
    from scrppl import parallel

    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ImportError, match=r'pip install "scrppl\[dask\]"'):
        with parallel.executor("tcp://127.0.0.1:1"):
            pass
    with parallel.executor(None) as ex:  # in process: no extra needed
        assert not ex.distributed


def test_cli_reports_the_missing_extra(monkeypatch, capsys):
    from scrppl.cli import main

    monkeypatch.setitem(sys.modules, "distributed", None)
    assert main(["fit", "--out", "nowhere", "--scheduler", "tcp://127.0.0.1:1"]) == 1
    err = capsys.readouterr().err
    assert 'pip install "scrppl[dask]"' in err and err.startswith("scrppl fit: error:")


# -- the core without the extras' packages, in a subprocess -----------------------------------------
#: Modules that need the render extra as soon as they are imported (they build meshes with trimesh).
RENDER_AT_IMPORT = {
    "scrppl.datasets.synthetic.categories._mesh",
    "scrppl.datasets.synthetic.categories.appliances",
    "scrppl.datasets.synthetic.categories.body",
    "scrppl.datasets.synthetic.categories.devices",
    "scrppl.datasets.synthetic.categories.vehicles",
}

CORE_SCRIPT = textwrap.dedent(
    """
    import importlib, json, pkgutil, sys
    import scrppl

    failed, imported = {}, []
    for info in pkgutil.walk_packages(scrppl.__path__, "scrppl."):
        if info.name.endswith("__main__"):  # runs the command
            continue
        try:
            importlib.import_module(info.name)
            imported.append(info.name)
        except ImportError as err:
            failed[info.name] = str(err)
    extras = sorted(
        m for m in sys.modules
        if m.split(".")[0] in {"pyvista", "vtk", "vtkmodules", "trimesh", "skimage", "dask", "distributed"}
    )
    # the command that renders: an error naming the extra, exit status 1
    from scrppl.cli import main
    status = main(["dataset", "make", "--profile", "tiny", "--root", "data", "--workers", "1",
                   "--no-progress"])
    print(json.dumps({"failed": failed, "imported": len(imported), "extras_loaded": extras,
                      "make_status": status}))
    """
)


def _core_site(tmp_path: Path) -> Path:
    """A site folder linking every installed package except those of the render and dask extras."""
    blocked_modules = {m for _, mods in EXTRAS.values() for m in mods}
    blocked_dists = {"pyvista", "vtk", "trimesh", "scikit_image", "dask", "distributed"}
    site = tmp_path / "site-packages"
    site.mkdir()
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        stem = entry.name.split(".")[0]
        dist = entry.name.split("-")[0].lower() if entry.name.endswith(".dist-info") else None
        if stem in blocked_modules or dist in blocked_dists or entry.suffix == ".pth":
            continue
        (site / entry.name).symlink_to(entry)
    return site


def test_core_modules_import_without_the_extras(tmp_path):
    site = _core_site(tmp_path)
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{site}", JAX_PLATFORMS="cpu")
    proc = subprocess.run(
        [sys.executable, "-S", "-c", CORE_SCRIPT],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    import json

    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["extras_loaded"] == []
    assert set(out["failed"]) == RENDER_AT_IMPORT, out["failed"]
    for name, message in out["failed"].items():
        assert 'pip install "scrppl[render]"' in message, (name, message)
    assert out["imported"] > 80
    assert out["make_status"] == 1 and 'pip install "scrppl[render]"' in proc.stderr
