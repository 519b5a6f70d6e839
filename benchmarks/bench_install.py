"""The wheel alone: build it, install it with only the core dependencies, run the README's quick start.

1. ``scripts/build-dist.sh`` builds the sdist and the wheel (the wheel from the sdist), offline.
2. A fresh virtual environment (the Python ``scripts/find-python.sh`` finds, as ``make`` uses) gets
   ``environment-core.lock`` (the core dependencies at the versions of ``environment.lock``, hash-checked,
   from the index the lock was made with) and the wheel without dependencies; ``pip check`` then
   confirms the wheel's requirements are all met, and the extras' packages must be absent.
3. In that environment, from an empty folder: the README's quick start, run twice (target: under 30 s;
   checked on processor time, wall time recorded beside the load average); the
   example models load; rendering and ``--scheduler`` fail with an error naming their extra.
4. ``du`` of the core environment and of the full ``.venv`` (target: core at most 60 % of full).

Writes ``benchmarks/results/install.json`` (or ``--json PATH``); exit status 1 if a check fails.
``tests/test_dist.py`` (slow) runs it into a temporary folder. The environment is removed at the end
unless ``--keep``. Run: ``.venv/bin/python benchmarks/bench_install.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Top-level modules of the render and dask extras (scrppl._extras.EXTRAS).
EXTRA_MODULES = ("pyvista", "vtk", "vtkmodules", "trimesh", "skimage", "dask", "distributed")
QUICK_START_LIMIT_S = 30.0
SIZE_LIMIT = 0.60


def du_bytes(path: Path) -> int:
    """Disk usage of ``path`` in bytes, as ``du -sh`` counts it (``du -sk``, times 1024)."""
    out = subprocess.run(["du", "-sk", str(path)], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[0]) * 1024


def quick_start_code() -> str:
    """The README's quick start (the first Python block of its "Quick start" section)."""
    text = (ROOT / "README.md").read_text()
    return re.search(r"## Quick start: [^\n]*\n.*?```python\n(.*?)```", text, re.S).group(1)


def run(cmd, **kwargs) -> subprocess.CompletedProcess:
    kwargs.setdefault("capture_output", True)
    kwargs.setdefault("text", True)
    proc = subprocess.run(cmd, **kwargs)
    if proc.returncode != 0:
        raise SystemExit(
            f"bench_install: {' '.join(map(str, cmd))} failed ({proc.returncode}):\n"
            f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
        )
    return proc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--json", type=Path, default=ROOT / "benchmarks" / "results" / "install.json"
    )
    parser.add_argument("--work", type=Path, default=None, help="folder for dist/ and the env")
    parser.add_argument("--keep", action="store_true", help="keep the core environment")
    args = parser.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="scrppl-install-"))
    work.mkdir(parents=True, exist_ok=True)
    record: dict = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "load_average_start": list(os.getloadavg()),
    }
    failures: list[str] = []

    t0 = time.perf_counter()
    dist = work / "dist"
    out = run(["bash", str(ROOT / "scripts" / "build-dist.sh"), str(dist)]).stdout.split()
    wheel = next(Path(p) for p in out if p.endswith(".whl"))
    record["wheel"] = {"name": wheel.name, "bytes": wheel.stat().st_size}
    record["build_s"] = round(time.perf_counter() - t0, 1)

    python = run(["bash", str(ROOT / "scripts" / "find-python.sh")]).stdout.strip()
    env_dir = work / "core-env"
    shutil.rmtree(env_dir, ignore_errors=True)
    t0 = time.perf_counter()
    run([python, "-m", "venv", str(env_dir)])
    py = env_dir / "bin" / "python"
    pip = [str(py), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    run([*pip, "--require-hashes", "-r", str(ROOT / "environment-core.lock")])
    run([*pip, "--no-deps", str(wheel)])
    record["install_s"] = round(time.perf_counter() - t0, 1)
    check = subprocess.run([str(py), "-m", "pip", "check"], capture_output=True, text=True)
    record["pip_check"] = check.stdout.strip()
    if check.returncode:
        failures.append(f"pip check: {check.stdout.strip()}")

    # from an empty folder, so that nothing of the checkout can be imported
    scratch = work / "scratch"
    scratch.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "XLA_", "SCRPPL_"))}
    env.update(MPLBACKEND="Agg", JAX_PLATFORMS="cpu")
    probe = run(
        [
            str(py),
            "-c",
            "import importlib.util, json, scrppl; print(json.dumps({'file': scrppl.__file__, "
            f"'present': [m for m in {list(EXTRA_MODULES)!r} if importlib.util.find_spec(m)]}}))",
        ],
        cwd=scratch,
        env=env,
    )
    found = json.loads(probe.stdout.strip().splitlines()[-1])
    record["extras_present"] = found["present"]
    if found["present"] or not found["file"].startswith(str(env_dir)):
        failures.append(f"not a core-only install of the wheel: {found}")

    # twice: the first run in a fresh environment also fills caches (bytecode of the first imports,
    # the page cache); the limit is on the processor time, which other processes on the machine do
    # not inflate as they do the wall time (both are recorded, with the load average)
    (scratch / "quick_start.py").write_text(quick_start_code())
    runs = []
    for _ in range(2):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        qs = subprocess.run(
            [str(py), "quick_start.py"], cwd=scratch, env=env, capture_output=True, text=True
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        runs.append({"wall_s": round(wall, 1), "cpu_s": round(cpu, 1)})
        if qs.returncode:
            failures.append(f"the quick start failed:\n{qs.stderr[-3000:]}")
            break
    record["quick_start"] = {
        "runs": runs,
        "load_average": list(os.getloadavg()),
        "limit_s": QUICK_START_LIMIT_S,
        "output": qs.stdout.strip().splitlines(),
    }
    record["quick_start_s"] = runs[0]["wall_s"]
    if not qs.returncode and max(r["cpu_s"] for r in runs) > QUICK_START_LIMIT_S:
        failures.append(
            f"the quick start took more than {QUICK_START_LIMIT_S} s of processor time: {runs}"
        )

    # a feature of a missing extra: the error names it
    for extra, argv_ in {
        "render": ["dataset", "make", "--profile", "tiny", "--root", "data", "--workers", "1"],
        "dask": ["fit", "--out", "results", "--scheduler", "tcp://127.0.0.1:1"],
    }.items():
        proc = subprocess.run(
            [str(env_dir / "bin" / "scrppl"), *argv_],
            cwd=scratch,
            env=env,
            capture_output=True,
            text=True,
        )
        ok = proc.returncode == 1 and f'pip install "scrppl[{extra}]"' in proc.stderr
        record[f"missing_{extra}_error"] = (
            proc.stderr.strip().splitlines()[-1:] if proc.stderr else []
        )
        if not ok:
            failures.append(f"scrppl {' '.join(argv_)} without [{extra}]: {proc.stderr[-1500:]}")

    core, full = du_bytes(env_dir), du_bytes(ROOT / ".venv")
    record["size"] = {
        "core_env_bytes": core,
        "full_venv_bytes": full,
        "core_env": f"{core / 2**30:.2f} GiB",
        "full_venv": f"{full / 2**30:.2f} GiB",
        "ratio": round(core / full, 3),
        "limit": SIZE_LIMIT,
    }
    if core > SIZE_LIMIT * full:
        failures.append(
            f"core environment is {core / full:.0%} of the full one (> {SIZE_LIMIT:.0%})"
        )
    record["failures"] = failures
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2) + "\n")
    if not args.keep:
        shutil.rmtree(env_dir, ignore_errors=True)
    print(json.dumps({k: record[k] for k in ("size", "quick_start", "install_s")}, indent=2))
    for f in failures:
        print(f"bench_install: FAIL {f}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
