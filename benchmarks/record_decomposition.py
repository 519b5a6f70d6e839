"""Record a full run's decomposition (``scrppl decompose``) for the book and the README.

The decomposition at the size that decides issue 21 (10,000 paired trials per target in the paper regime)
takes about three quarters of an hour on two cores, far too long to run with the book. This script keeps
what it wrote, with the machine it ran on, in ``benchmarks/results/decomposition-full.json``; ch. 9 reads
that record (a recorded file: its claims hold on every machine). Made with::

    scrppl simulate --profile full --out RESULTS --detector dpm
    scrppl decompose --profile full --out RESULTS --trials 10000 \\
        --rows random,greedy_joint,confident,clairvoyant
    scrppl decompose --profile full --out RESULTS --trials 2000 \\
        --rows random,greedy_joint,confident,clairvoyant --model-world
    scrppl decompose --profile full --out ORACLE --trials 2000 \\
        --rows random,greedy_joint,confident,oracle_random,oracle,clairvoyant --oracle
    python benchmarks/record_decomposition.py RESULTS --oracle-from ORACLE

Run: ``python benchmarks/record_decomposition.py RESULTS [--world-from DIR] [--oracle-from DIR]``
(``--world-from``: the folder of ``decomposition-model-world.json`` when it is not ``RESULTS``;
``--oracle-from``: a folder whose ``decomposition.json`` has the oracle rows, kept as ``oracle``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from scrppl._io import atomic_path
from scrppl.pipeline import machine_description

RECORD = Path(__file__).parent / "results" / "decomposition-full.json"


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise SystemExit(f"{path}: not found (run scrppl decompose first)") from None
    except json.JSONDecodeError as err:
        raise SystemExit(f"{path}: not a JSON file ({err})") from None
    if "targets" not in data or "settings" not in data:
        raise SystemExit(f"{path}: not a decomposition (no 'targets' or 'settings' entry)")
    return data


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path, help="a results folder holding decomposition.json")
    ap.add_argument("--world-from", type=Path, default=None,
                    help="folder of decomposition-model-world.json (default: RESULTS)")  # fmt: skip
    ap.add_argument(
        "--oracle-from", type=Path, default=None,
        help="folder of a decomposition.json run with --oracle (default: none)",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, default=RECORD)
    args = ap.parse_args(argv)
    real = _read(args.results / "decomposition.json")
    world_path = (args.world_from or args.results) / "decomposition-model-world.json"
    world = _read(world_path) if world_path.exists() else None
    if world is not None and world["seed"] != real["seed"]:
        raise SystemExit(
            f"{world_path}: seed {world['seed']} differs from the real run's {real['seed']}"
        )
    oracle = _read(args.oracle_from / "decomposition.json") if args.oracle_from else None
    if oracle is not None and "oracle" not in oracle["settings"].get("rows", []):
        raise SystemExit(
            f"{args.oracle_from / 'decomposition.json'}: has no oracle rows (run with --oracle)"
        )
    record = {
        "what": (
            "views to confidence from a random view to the clairvoyant bound in the paper regime "
            "(full profile, paper images, DPM), on the real held-out responses and in the model's own "
            "world (scrppl decompose; read by ch. 9)"
        ),
        "command": (
            "scrppl decompose --profile full --trials T --rows random,greedy_joint,confident,"
            "clairvoyant [--model-world]"
        ),
        "machine": machine_description(),
        "real": real,
        "model_world": world,
        "oracle": oracle,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
