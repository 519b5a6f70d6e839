"""Compare two runs of ``scrppl reproduce`` stage by stage: where do their numbers first differ?

Two runs of the same profile and seed should give the same bytes. When they do not (two machines, or
one machine with its CPU features narrowed), this finds the first stage that differs and how much:

1. dataset    -- the image and mask files of the two dataset folders (byte for byte);
2. detect     -- the response table (``responses.nc``): cells that differ, largest difference;
3. fit        -- the posterior draws of every hierarchical fit (``models/hierarchical-*.nc``), and the
                 number of attempts each fit needed (``models/diagnostics.json``);
4. simulate   -- the trials (``trials.nc``, ``trials-large.nc``): records that differ;
5. kway, sweep -- their trial files, where both runs have them.

Usage::

    .venv/bin/python scripts/compare_runs.py RUN_A RUN_B [--out record.json]

``RUN_A``/``RUN_B`` are output folders of ``scrppl reproduce`` (their ``run.json`` names the dataset folder).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import xarray as xr


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def compare_files(a: Path, b: Path, patterns=("*.jpg", "*.png", "*.bmp")) -> dict:
    """Byte-for-byte comparison of the image files of two dataset folders."""
    fa = {p.relative_to(a): p for pat in patterns for p in a.rglob(pat)}
    fb = {p.relative_to(b): p for pat in patterns for p in b.rglob(pat)}
    common = sorted(set(fa) & set(fb))
    differ = [str(k) for k in common if _digest(fa[k]) != _digest(fb[k])]
    return {
        "files": len(common),
        "only_in_one": len(set(fa) ^ set(fb)),
        "differ": len(differ),
        "examples": differ[:5],
    }


def _array_diff(x: np.ndarray, y: np.ndarray) -> dict:
    if x.shape != y.shape:
        return {"shape_a": list(x.shape), "shape_b": list(y.shape), "identical": False}
    if x.dtype.kind in "fc":
        same = np.array_equal(x, y, equal_nan=True)
        both = np.isfinite(x) & np.isfinite(y)
        diff = np.abs(x - y)[both]
        return {
            "identical": bool(same),
            "cells": int(x.size),
            "cells_differ": int((~((x == y) | (np.isnan(x) & np.isnan(y)))).sum()),
            "max_abs_diff": float(diff.max()) if diff.size else 0.0,
        }
    same = np.array_equal(x, y)
    return {"identical": bool(same), "cells": int(x.size), "cells_differ": int((x != y).sum())}


def compare_dataset(a: Path, b: Path, variables=None) -> dict:
    """Every data variable of two netCDF datasets."""
    da, db = xr.open_dataset(a), xr.open_dataset(b)
    names = variables or [v for v in da.data_vars if v in db.data_vars]
    out = {v: _array_diff(da[v].values, db[v].values) for v in names}
    return {"identical": all(r["identical"] for r in out.values()), "variables": out}


def compare_posteriors(a: Path, b: Path) -> dict:
    """The posterior draws of each hierarchical fit, and the attempts each fit needed."""
    fits = {}
    for fa in sorted(a.glob("hierarchical-*.nc")):
        fb = b / fa.name
        if not fb.exists():
            continue
        ta, tb = xr.open_datatree(fa), xr.open_datatree(fb)
        post_a, post_b = ta["posterior"].ds, tb["posterior"].ds
        diffs = {v: _array_diff(post_a[v].values, post_b[v].values) for v in post_a.data_vars}
        fits[fa.stem.removeprefix("hierarchical-")] = {
            "identical": all(d["identical"] for d in diffs.values()),
            "max_abs_diff": max((d.get("max_abs_diff", 0.0) for d in diffs.values()), default=0.0),
        }
    attempts = {}
    for run, folder in (("a", a), ("b", b)):
        path = folder / "diagnostics.json"
        if path.exists():
            diag = json.loads(path.read_text())
            fits_diag = diag.get("fits", diag)
            attempts[run] = {
                k: len(v.get("attempts", [])) or 1
                for k, v in fits_diag.items()
                if isinstance(v, dict)
            }
    return {
        "fits": len(fits),
        "identical": sum(f["identical"] for f in fits.values()),
        "differ": sorted(k for k, f in fits.items() if not f["identical"]),
        "largest_difference": max((f["max_abs_diff"] for f in fits.values()), default=0.0),
        "attempts_differ": sorted(
            k
            for k in attempts.get("a", {})
            if attempts.get("b", {}).get(k) != attempts["a"][k]
        )
        if attempts
        else [],
    }


def compare_runs(a: Path, b: Path) -> dict:
    """Stage by stage; ``first_difference`` names the first stage whose outputs differ."""
    info_a = json.loads((a / "run.json").read_text())
    info_b = json.loads((b / "run.json").read_text())
    stages: dict[str, dict] = {}
    ra, rb = Path(info_a["dataset_root"]), Path(info_b["dataset_root"])
    if ra.exists() and rb.exists():
        d = compare_files(ra, rb)
        stages["dataset"] = d | {"identical": d["differ"] == 0 and d["only_in_one"] == 0}
    if (a / "responses.nc").exists() and (b / "responses.nc").exists():
        stages["detect"] = compare_dataset(a / "responses.nc", b / "responses.nc", ["score"])
    if (a / "models").exists() and (b / "models").exists():
        p = compare_posteriors(a / "models", b / "models")
        stages["fit"] = p | {"identical": p["identical"] == p["fits"] and not p["attempts_differ"]}
    for name, files in (
        ("simulate", ("trials.nc", "trials-large.nc")),
        ("kway", ("kway-trials.nc",)),
        ("sweep", ("sweep.nc",)),
    ):
        got = {
            f: compare_dataset(a / f, b / f)
            for f in files
            if (a / f).exists() and (b / f).exists()
        }
        if got:
            stages[name] = {"identical": all(g["identical"] for g in got.values()), "files": got}
    first = next((k for k, v in stages.items() if not v["identical"]), None)
    return {
        "a": {"folder": str(a), **{k: info_a.get(k) for k in ("profile", "seed", "preset", "cpu")}},
        "b": {"folder": str(b), **{k: info_b.get(k) for k in ("profile", "seed", "preset", "cpu")}},
        "first_difference": first,
        "stages": stages,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_a", type=Path)
    p.add_argument("run_b", type=Path)
    p.add_argument("--out", type=Path, help="write the comparison as JSON")
    args = p.parse_args(argv)
    result = compare_runs(args.run_a, args.run_b)
    for stage, r in result["stages"].items():
        print(f"{stage:9s} {'identical' if r['identical'] else 'DIFFERS'}")
    print(f"first stage that differs: {result['first_difference']}")
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
