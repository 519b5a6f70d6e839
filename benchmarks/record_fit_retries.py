"""Record: how often the fit stage's retry ladder fires, and what the fit stage costs, on one response table.

Runs ``scrppl fit --profile full`` on a copy of a response table (the paper preset's full table of
``make reproduce``: ``results/responses.nc``) in a fresh folder, with the code of this checkout, and
records the wall and CPU seconds (the process and its children, user + system), the attempts of every fit,
whether each passed its diagnostics, and its held-out joint LPD. ``--label`` names the entry (``before``,
``after``); entries of other labels already in the record are kept, so a before/after pair is made by
running this script in two checkouts one after the other, in one sitting, on one machine.

Run: ``python benchmarks/record_fit_retries.py --responses results/responses.nc --label after``
(about 4-6 minutes on 2 cores). Writes ``benchmarks/results/fit-retries.json``.
"""

import argparse
import csv
import hashlib
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RECORD = HERE / "results" / "fit-retries.json"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--responses", required=True, help="response table (responses.nc) to fit")
    parser.add_argument("--label", required=True, help="name of the entry (e.g. before, after)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    src = Path(args.responses)
    if not src.exists():
        parser.error(f"{src}: no such response table (run make reproduce first)")
    root = Path(__file__).resolve().parents[1]
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
    ).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        shutil.copy(src, out / "responses.nc")
        if (src.parent / "run.json").exists():
            shutil.copy(src.parent / "run.json", out / "run.json")
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "scrppl", "fit", "--profile", "full", "--seed", str(args.seed)]
        proc = subprocess.run(
            [*cmd, "--out", str(out)], cwd=root, env=dict(os.environ, JAX_PLATFORMS="cpu")
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if not (out / "models" / "diagnostics.json").exists():
            sys.exit(f"scrppl fit exited with status {proc.returncode} and wrote no diagnostics")
        diag = json.loads((out / "models" / "diagnostics.json").read_text())
        diag.pop("thresholds", None)
        heldout = {
            f"{r['detector']}/{r['target']}/{r['class']}": round(float(r["lpd_joint"]), 4)
            for r in csv.DictReader(open(out / "models" / "heldout.csv"))
            if r["kind"] == "hierarchical"
        }
    fits = {
        k: {
            "ok": v["ok"],
            "attempts": [
                {a: x[a] for a in ("target_accept_prob", "noncentered", "ok", "divergences")}
                for x in v["attempts"]
            ],
        }
        for k, v in sorted(diag.items())
    }
    entry = {
        "commit": commit,
        "command": " ".join(cmd[2:]),
        "exit_status": proc.returncode,
        "wall_seconds": round(wall, 1),
        "cpu_seconds": {
            "user": round(after.ru_utime - before.ru_utime, 1),
            "system": round(after.ru_stime - before.ru_stime, 1),
        },
        "n_fits": len(fits),
        "n_ok": sum(f["ok"] for f in fits.values()),
        "retried": {k: len(f["attempts"]) for k, f in fits.items() if len(f["attempts"]) > 1},
        "fits": fits,
        "heldout_lpd_joint": heldout,
    }
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    # the table by its content, not by where it lies on this machine
    digest = hashlib.sha256(src.read_bytes()).hexdigest()[:16]
    known = record.get("table") if isinstance(record.get("table"), dict) else {}
    if known.get("sha256_16") != digest:
        known = {}  # another table: its description no longer applies
    record["table"] = {**known, "file": src.name, "sha256_16": digest}
    record["machine"] = {
        "cores": os.cpu_count(),
        "cpu": platform.processor() or platform.machine(),
        "platform": platform.platform(),
    }
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                record["machine"]["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    record[args.label] = entry
    RECORD.parent.mkdir(parents=True, exist_ok=True)
    RECORD.write_text(json.dumps(record, indent=2) + "\n")
    print(
        f"{args.label}: {entry['wall_seconds']} s wall, {entry['cpu_seconds']} CPU-s, "
        f"{entry['n_ok']}/{entry['n_fits']} ok, retried {entry['retried']}"
    )
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
