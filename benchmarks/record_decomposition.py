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

The model-optimal bracket (about a second a trial and method, so a few hundred trials, one folder per
target to use both cores) in the world each filter assumes, kept as ``filter_world``::

    scrppl decompose --profile full --out RESULTS_T --trials 250 --targets T \
        --rows random,greedy_joint,confident,clairvoyant --model-world --world filter --model-optimal
    python benchmarks/record_decomposition.py --filter-world-from RESULTS_bicycle RESULTS_car ...

The same bracket for the model with the instance x azimuth effect (the pipeline's model since
``scrppl fit --azimuth-effect auto`` became the default; the record's other parts are of the one-effect
model), from folders of a ``make reproduce`` made with it, kept as ``filter_world_azimuth_effect``::

    python benchmarks/record_decomposition.py --filter-world-from RESULTS_bicycle ... \
        --filter-world-key filter_world_azimuth_effect --model "..."

The rollout planner (``PlannerConfig("rollout")``, sampled futures; about 65 ms a decision with the
instance-aware filter, so a few hundred trials) on the real responses and in the filter world, kept as
``rollout`` and ``rollout_filter_world``::

    scrppl decompose --profile full --out RESULTS_T --trials 600 --targets T \
        --rows random,greedy_joint,rollout,clairvoyant
    scrppl decompose --profile full --out WORLD_T --trials 250 --targets T \
        --rows random,greedy_joint,rollout,clairvoyant --model-world --world filter
    python benchmarks/record_decomposition.py --rollout-from RESULTS_bicycle ... \
        --rollout-filter-world-from WORLD_bicycle ...

Eq. 5 drawing its responses from oracle models (fitted on the held-out instances themselves) while the
method's filter and metric stay (the ``oracle_greedy`` row), beside eq. 5 on the same real trials, from a
fresh ``make reproduce`` (the pipeline's model), kept as ``oracle_greedy``::

    scrppl decompose --profile full --out RESULTS --trials 5000 \\
        --rows random,greedy_joint,oracle_greedy,clairvoyant --oracle
    python benchmarks/record_decomposition.py --oracle-greedy-from RESULTS --model "..."

The same for the confident planner (``oracle_confident``; about 0.2 s a decision, so 2,000 trials, one
folder per target holding the same run's fits and the oracle fits above), kept as ``oracle_confident``::

    scrppl decompose --profile full --out RESULTS_T --targets T --trials 2000 \\
        --rows random,confident,oracle_confident,clairvoyant --oracle
    python benchmarks/record_decomposition.py --oracle-confident-from RESULTS_bicycle ... --model "..."

Eq. 5 and the confident planner *told the true class and pose* (rows ``state_greedy`` and
``state_confident``: their predictive from the method's own model at the trial's state), and eq. 5 told
the pose only (``pose_greedy``; ``pose_confident`` the same way as ``state_confident``), kept under those
names::

    scrppl decompose --profile full --out RESULTS --trials 10000 \\
        --rows random,greedy_joint,state_greedy,clairvoyant
    scrppl decompose --profile full --out POSE --trials 10000 \\
        --rows random,greedy_joint,pose_greedy,clairvoyant
    scrppl decompose --profile full --out RESULTS_T --targets T --trials 2000 \\
        --rows random,confident,state_confident,clairvoyant
    python benchmarks/record_decomposition.py --state-greedy-from RESULTS --pose-greedy-from POSE \\
        --state-confident-from RESULTS_bicycle ... --model "..."

Run: ``python benchmarks/record_decomposition.py [RESULTS] [--world-from DIR] [--oracle-from DIR]
[--filter-world-from DIR ...] [--rollout-from DIR ...] [--rollout-filter-world-from DIR ...]`` (``--world-from``: the folder of ``decomposition-model-world.json`` when
it is not ``RESULTS``; ``--oracle-from``: a folder whose ``decomposition.json`` has the oracle rows, kept
as ``oracle``; ``--filter-world-from``: folders of ``decomposition-filter-world.json``, their targets
merged). Without ``RESULTS`` the record's other parts are kept as they are.
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


def merge_targets(paths: list[Path]) -> dict:
    """One decomposition from several runs of the same settings, each on some of the targets."""
    runs = [_read(p) for p in paths]
    merged = dict(runs[0], targets={}, seconds_total=0.0)
    for path, run in zip(paths, runs, strict=True):
        if (run["seed"], run["settings"]) != (runs[0]["seed"], runs[0]["settings"]):
            raise SystemExit(f"{path}: seed or settings differ from {paths[0]}'s")
        for target, entry in run["targets"].items():
            if target in merged["targets"]:
                raise SystemExit(f"{path}: target {target!r} is already in another folder's run")
            merged["targets"][target] = entry
        merged["seconds_total"] += float(run.get("seconds_total", 0.0))
    return merged


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "results", type=Path, nargs="?", default=None,
        help="a results folder holding decomposition.json (default: keep the record's)",
    )  # fmt: skip
    for flag, what in (
        (
            "--filter-world-from",
            "decomposition-filter-world.json (--world filter --model-optimal runs)",
        ),
        ("--rollout-from", "decomposition.json with the rollout row (real responses)"),
        ("--rollout-filter-world-from", "decomposition-filter-world.json with the rollout row"),
        ("--oracle-greedy-from", "decomposition.json with the oracle_greedy row"),
        ("--oracle-confident-from", "decomposition.json with the oracle_confident row"),
        ("--pose-greedy-from", "decomposition.json with the pose_greedy row"),
        ("--pose-confident-from", "decomposition.json with the pose_confident row"),
        ("--state-greedy-from", "decomposition.json with the state_greedy row"),
        ("--state-confident-from", "decomposition.json with the state_confident row"),
    ):
        ap.add_argument(flag, type=Path, nargs="+", default=None, help=f"folders of {what}")
    ap.add_argument("--world-from", type=Path, default=None,
                    help="folder of decomposition-model-world.json (default: RESULTS)")  # fmt: skip
    ap.add_argument(
        "--oracle-from", type=Path, default=None,
        help="folder of a decomposition.json run with --oracle (default: none)",
    )  # fmt: skip
    ap.add_argument(
        "--filter-world-key", default="filter_world",
        choices=("filter_world", "filter_world_azimuth_effect"),
        help="the record's key for --filter-world-from (default: filter_world)",
    )  # fmt: skip
    ap.add_argument(
        "--model",
        default=None,
        help="the model of the --filter-world-from, --oracle-*-from or --state-*-from runs, in words",
    )
    ap.add_argument("--out", type=Path, default=RECORD)
    args = ap.parse_args(argv)
    old = {}
    if args.results is None:
        if args.out.exists():
            old = json.loads(args.out.read_text())
        parts = (
            args.filter_world_from,
            args.rollout_from,
            args.rollout_filter_world_from,
            args.oracle_greedy_from,
            args.oracle_confident_from,
            args.pose_greedy_from,
            args.pose_confident_from,
            args.state_greedy_from,
            args.state_confident_from,
        )
        if all(p is None for p in parts) or "real" not in old:
            raise SystemExit(
                "give a results folder, or --filter-world-from, --rollout-from, "
                "--rollout-filter-world-from, --oracle-greedy-from, --oracle-confident-from, "
                "--pose-greedy-from, --pose-confident-from, --state-greedy-from or "
                "--state-confident-from with an existing "
                "record to add to"
            )
        real, world, oracle = old["real"], old.get("model_world"), old.get("oracle")
    else:
        real = _read(args.results / "decomposition.json")
        world_path = (args.world_from or args.results) / "decomposition-model-world.json"
        world = _read(world_path) if world_path.exists() else None
        oracle = _read(args.oracle_from / "decomposition.json") if args.oracle_from else None
    if world is not None and world["seed"] != real["seed"]:
        raise SystemExit(
            f"model world: seed {world['seed']} differs from the real run's {real['seed']}"
        )
    if oracle is not None and "oracle" not in oracle["settings"].get("rows", []):
        raise SystemExit(
            f"{args.oracle_from / 'decomposition.json'}: has no oracle rows (run with --oracle)"
        )
    worlds = {k: old.get(k) for k in ("filter_world", "filter_world_azimuth_effect")}
    if args.filter_world_from is not None:
        filter_world = merge_targets(
            [d / "decomposition-filter-world.json" for d in args.filter_world_from]
        )
        if filter_world["settings"].get("world") != "filter":
            raise SystemExit(f"{args.filter_world_from[0]}: not a --world filter run")
        filter_world["machine"] = machine_description()
        if args.model is not None:
            filter_world["model"] = args.model
        worlds[args.filter_world_key] = filter_world
    rollout = {
        "rollout": old.get("rollout"),
        "rollout_filter_world": old.get("rollout_filter_world"),
    }
    for part, dirs, name in (
        ("rollout", args.rollout_from, "decomposition.json"),
        ("rollout_filter_world", args.rollout_filter_world_from, "decomposition-filter-world.json"),
    ):
        if dirs is None:
            continue
        run = merge_targets([d / name for d in dirs])
        if "rollout" not in run["settings"].get("rows", []):
            raise SystemExit(f"{dirs[0] / name}: has no rollout row")
        if (part == "rollout_filter_world") != (run["settings"].get("world") == "filter"):
            raise SystemExit(f"{dirs[0] / name}: not the world {part} expects")
        run["machine"] = machine_description()
        rollout[part] = run
    given = {
        "oracle_greedy": args.oracle_greedy_from,
        "oracle_confident": args.oracle_confident_from,
        "pose_greedy": args.pose_greedy_from,
        "pose_confident": args.pose_confident_from,
        "state_greedy": args.state_greedy_from,
        "state_confident": args.state_confident_from,
    }
    oracle_rows = {k: old.get(k) for k in given}
    for row, dirs in given.items():
        if dirs is None:
            continue
        run = merge_targets([d / "decomposition.json" for d in dirs])
        if row not in run["settings"].get("rows", []):
            raise SystemExit(f"{dirs[0]}: has no {row} row")
        run["machine"] = machine_description()
        if args.model is not None:
            run["model"] = args.model
        oracle_rows[row] = run
    record = {
        "what": (
            "views to confidence from a random view to the clairvoyant bound in the paper regime "
            "(full profile, paper images, DPM), on the real held-out responses, in the model's own "
            "world and in the world each filter assumes, with the model-optimal bracket (scrppl "
            "decompose; read by ch. 9)"
        ),
        "command": (
            "scrppl decompose --profile full --trials T --rows random,greedy_joint,confident,"
            "clairvoyant [--model-world [--world filter --model-optimal]]"
        ),
        "machine": old.get("machine") or machine_description(),  # of the real run
        **({"model": old["model"]} if "model" in old else {}),
        "real": real,
        "model_world": world,
        "oracle": oracle,
        "filter_world": worlds["filter_world"],
        **rollout,
        **(
            {"filter_world_azimuth_effect": worlds["filter_world_azimuth_effect"]}
            if worlds["filter_world_azimuth_effect"] is not None
            else {}
        ),
        **{k: v for k, v in oracle_rows.items() if v is not None},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
