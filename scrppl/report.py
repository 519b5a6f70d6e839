"""The Markdown report that ``scrppl reproduce`` writes: every figure and the key numbers.

It only reads what the stages wrote under the output folder (JSON, CSV and PNG files), so it can be rebuilt
at any time with ``scrppl reproduce`` (stages that are current are skipped) or :func:`write_report`.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from scrppl._io import atomic_path

__all__ = ["write_report"]

#: Figures in the order the paper numbers them, with captions; any other PNG under figures/ follows.
FIGURE_CAPTIONS = (
    (
        "dataset-sheet",
        "The synthetic multiview dataset: one instance per category from the 8 azimuths.",
    ),
    ("view-sphere", "The 72 views (8 azimuths x 3 elevations x 3 scales) around one object."),
    ("fig1-", "Fig. 1: detector response of one instance over azimuth, with detections drawn."),
    ("responses-", "Mean detector response by azimuth, positives vs negatives."),
    (
        "fig2-",
        "Fig. 2: DPM viewpoint detection functions (posterior predictive; positives left, negatives right).",
    ),
    ("fig3-", "Fig. 3: viewpoint detection functions of SIFT matching and bag-of-features."),
    ("trace-", "MCMC trace of one hierarchical fit."),
    ("forest-", "Posterior intervals of one hierarchical fit."),
    ("fig4-", "Fig. 4: the posterior over presence and pose evolving over 4 views."),
    ("fig5-", "Fig. 5: entropy planning vs a random unseen view over the trials."),
    (
        "calibration",
        "Reliability of p(target present | responses): naive Bayes vs instance-aware filter.",
    ),
)


def _md_table(rows: list[dict[str, Any]], columns: list[str] | None = None) -> str:
    if not rows:
        return "_(empty)_\n"
    columns = columns or list(rows[0].keys())

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _json_block(obj: Any) -> str:
    return "```json\n" + json.dumps(obj, indent=2, sort_keys=True)[:6000] + "\n```\n"


def _section_json(title: str, path: Path) -> str:
    if not path.exists():
        return ""
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        return f"## {title}\n\n`{path.name}` could not be read: {err}\n\n"
    if isinstance(data, list) and data and isinstance(data[0], dict):
        body = _md_table(data)
    else:
        body = _json_block(data)
    return f"## {title}\n\nFrom `{path.name}`:\n\n{body}\n"


def _section_csv(title: str, path: Path) -> str:
    if not path.exists():
        return ""
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return f"## {title}\n\nFrom `{path.name}`:\n\n{_md_table(rows)}\n"


def _section_detectors(path: Path) -> str:
    if not path.exists():
        return ""
    q = json.loads(path.read_text())
    ap = q.get("average_precision", {})
    cats = sorted({c for fam in ap.values() for c in fam})
    rows = [
        {
            "detector": fam,
            **{c: ap[fam].get(c, "") for c in cats},
            "mean": q.get("mean_average_precision", {}).get(fam, ""),
        }
        for fam in ap
    ]
    dep = q.get("azimuth_dependence", {})

    def _num(x: float | None) -> str:  # None: not estimable (e.g. one test instance of a category)
        return "n/a" if x is None else f"{x:.2f}"

    dep_rows = [
        {
            "detector": fam,
            **{c: f"{_num(v['positive'])} / {_num(v['negative'])}" for c, v in per.items()},
        }
        for fam, per in dep.items()
    ]
    text = f"## Detectors\n\nOne-vs-rest average precision on the `{q.get('split', 'test')}` split (from `detectors/quality.json`):\n\n"
    text += _md_table(rows, ["detector", *cats, "mean"])
    if dep_rows:
        text += (
            "\nAzimuth dependence, positives / negatives ("
            + q.get("azimuth_dependence_definition", "")
            + "):\n\n"
        )
        text += _md_table(dep_rows, ["detector", *cats])
    if "seconds" in q:
        text += "\nWall time (s): " + ", ".join(f"{k} {v}" for k, v in q["seconds"].items()) + "\n"
    return text + "\n"


def _section_diagnostics(path: Path) -> str:
    if not path.exists():
        return ""
    diag = json.loads(path.read_text())
    rows = []
    for fit, d in sorted(diag.items()):
        if not isinstance(d, dict) or not isinstance(d.get("rhat_max"), dict):
            continue
        rows.append(
            {
                "fit": fit,
                "ok": "yes" if d.get("ok") else "NO",
                "max R-hat": max(d["rhat_max"].values()),
                "min bulk ESS": min(d["ess_bulk_min"].values()),
                "min tail ESS": min(d["ess_tail_min"].values()),
                "divergences": d.get("divergences", ""),
                "min E-BFMI": min(d.get("ebfmi", [float("nan")])),
                "target accept": " -> ".join(
                    f"{a['target_accept_prob']:g}" for a in d.get("attempts", [])
                ),
                "failures": "; ".join(d.get("failures", [])),
            }
        )
    rows.sort(key=lambda r: (r["ok"] == "yes", r["fit"]))  # failures first
    n_ok = sum(r["ok"] == "yes" for r in rows)
    return (
        f"## MCMC diagnostics of the hierarchical fits\n\n{n_ok} of {len(rows)} fits pass every check "
        "(R-hat <= 1.01, bulk ESS >= 400, no divergences, E-BFMI >= 0.3); a fit that failed at the "
        "first acceptance target was refitted at the second (`target accept`); from "
        "`models/diagnostics.json`:\n\n" + _md_table(rows) + "\n"
    )


def _section_experiment(path: Path) -> str:
    if not path.exists():
        return ""
    summ = json.loads(path.read_text())
    rows = []
    for target, t in summ.get("targets", {}).items():
        for exp in ("paper_experiment", "large_experiment"):
            for method, m in t.get(exp, {}).items():
                if not isinstance(m, dict) or "views_to_confidence" not in m:
                    continue
                v = m["views_to_confidence"]
                d = m.get("views_to_confidence_difference_95ci", {})
                rows.append(
                    {
                        "target": target,
                        "experiment": exp.replace("_experiment", ""),
                        "method": method,
                        "views, entropy": v.get("sampled", ""),
                        "views, random": v.get("random", ""),
                        "difference [95% CI]": f"{d.get('mean', float('nan')):.3f} [{d.get('lo', float('nan')):.3f}, {d.get('hi', float('nan')):.3f}]",
                        "ECE": m.get("ece", ""),
                    }
                )
    settings = summ.get("settings", {})
    text = (
        "## Sequential recognition experiment\n\n"
        f"Detector `{summ.get('detector', '')}`; views until p(true class) > {settings.get('confidence_threshold', 0.95)} "
        "for the entropy planner and a random unseen view (paired trials; negative difference = entropy planning "
        "needs fewer views), and the expected calibration error (ECE) of p(o | F). From `simulate-summary.json` "
        f"(settings: {json.dumps(settings)}):\n\n"
    )
    return text + _md_table(rows) + "\n"


def _figures(out: Path) -> str:
    figdir = out / "figures"
    if not figdir.exists():
        return ""
    pngs = sorted(figdir.glob("*.png"))
    used: set[Path] = set()
    parts = ["## Figures\n"]
    for prefix, caption in FIGURE_CAPTIONS:
        for p in pngs:
            if p.name.startswith(prefix) and p not in used:
                used.add(p)
                parts.append(f"**{p.stem}** — {caption}\n\n![{p.stem}](figures/{p.name})\n")
    for p in pngs:
        if p not in used:
            parts.append(f"**{p.stem}**\n\n![{p.stem}](figures/{p.name})\n")
    return "\n".join(parts) + "\n"


def write_report(
    out: str | Path, *, dataset_root: Path | None = None, profile: str = "full", seed: int = 0
) -> Path:
    """Write ``<out>/report.md`` from the outputs of the stages; return its path."""
    out = Path(out)
    parts = [
        "# scrppl: reproduction report\n",
        "Active, sequential object-category recognition with viewpoint detection models, after Meger, "
        "Gupta & Little (ICRA 2010). Generated by `scrppl reproduce "
        f"--profile {profile} --seed {seed}`; every number below is read from the files beside this report.\n",
    ]
    from scrppl.datasets import dataset_layout, open_dataset

    layout = dataset_layout(dataset_root) if dataset_root is not None else None
    if layout in ("synthetic", "index", "savarese"):
        try:  # names only: the dataset stage has checked every file
            summary = open_dataset(
                dataset_root, split_seed=seed, validate=False, progress=False
            ).summary()
        except (FileNotFoundError, ValueError) as err:
            parts.append(f"## Dataset\n\nThe dataset could not be loaded: {err}\n")
        else:
            keys = [
                "name",
                "n_categories",
                "instances",
                "images",
                "missing_views",
                "azimuths",
                "elevations",
                "scales",
            ]
            parts.append("## Dataset\n\n" + _md_table([{k: summary[k] for k in keys}]))
            parts.append(
                "\nInstances per split: "
                + ", ".join(f"{k} {v}" for k, v in summary["split_counts"].items())
                + "\n"
            )
    parts.append(_section_json("Stage timings (seconds)", out / "timings.json"))
    parts.append(_section_detectors(out / "detectors" / "quality.json"))
    parts.append(_section_diagnostics(out / "models" / "diagnostics.json"))
    parts.append(
        _section_csv("Held-out comparison of viewpoint models", out / "models" / "heldout.csv")
    )
    parts.append(_section_experiment(out / "simulate-summary.json"))
    parts.append(_figures(out))
    path = out / "report.md"
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(p for p in parts if p))
    return path
