"""The wheel alone, in a clean environment with only the core dependencies (slow: a venv and ~1 GB).

``benchmarks/bench_install.py`` builds the sdist and wheel (``scripts/build-dist.sh``, as ``make dist``),
installs ``environment-core.lock`` (hash-checked, the versions of ``environment.lock``) and the wheel
into a fresh virtual environment, and there runs the README's quick start, checks ``pip check``, that no
package of the render or dask extras is present and that their features name the extra to install,
and compares the environment's size with the full ``.venv``'s. Needs the package index the lock was
made with (PyPI).
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_core_lock_pins_the_full_locks_versions():
    """environment-core.lock is a subset of environment.lock: same versions, same hashes."""

    def pins(path: Path) -> dict[str, tuple[str, frozenset]]:
        out, name = {}, None
        for line in path.read_text().splitlines():
            if line and not line.startswith((" ", "#")):
                name, version = line.split(" ")[0].split("==")
                out[name] = (version, set())
            elif name and "--hash=" in line:
                out[name][1].add(line.strip().split("--hash=")[1].rstrip(" \\"))
        return {k: (v, frozenset(h)) for k, (v, h) in out.items()}

    full, core = pins(ROOT / "environment.lock"), pins(ROOT / "environment-core.lock")
    assert core and set(core) < set(full)
    assert {k: v for k, v in core.items() if full[k] != v} == {}
    for extra_only in (
        "vtk",
        "pyvista",
        "trimesh",
        "scikit-image",
        "dask",
        "distributed",
        "pytest",
    ):
        assert extra_only in full and extra_only not in core
    for needed in (
        "jax",
        "jaxlib",
        "numpyro",
        "arviz",
        "xarray",
        "opencv-python-headless",
        "jupyter",
    ):
        assert needed in core


@pytest.mark.slow
def test_wheel_in_a_clean_core_environment(tmp_path):
    report = tmp_path / "install.json"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "benchmarks" / "bench_install.py"),
            "--json",
            str(report),
            "--work",
            str(tmp_path / "work"),
        ],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    record = json.loads(report.read_text()) if report.exists() else {}
    assert proc.returncode == 0, (record.get("failures"), proc.stderr[-3000:])
    assert record["failures"] == [] and record["extras_present"] == []
    assert record["size"]["ratio"] <= 0.60
    assert record["quick_start"]["output"][0].startswith("p(car) =")
    assert not (tmp_path / "work" / "core-env").exists()  # removed: about 1.2 GB
