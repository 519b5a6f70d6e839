"""The Markdown report that ``scrppl reproduce`` writes: a summary of the key numbers and every figure.

It only reads what the stages wrote under the output folder (JSON, CSV and PNG files), so it can be rebuilt
at any time with ``scrppl reproduce`` (stages that are current are skipped) or :func:`write_report`.

Numbers in ``report.md`` are rounded to what they can carry (see :data:`ROUNDING`); the full-precision
tables behind them are written beside it as ``report-*.csv`` and linked from the report.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

from scrppl._io import CorruptFileError, atomic_path, read_json

__all__ = ["write_report"]

#: Decimals shown in the Markdown tables, by kind of number (the CSV files keep full precision).
ROUNDING = {
    "average precision": 2,
    "azimuth dependence": 2,
    "log predictive density": 3,
    "coverage": 2,
    "R-hat": 3,
    "ESS": 0,
    "E-BFMI": 2,
    "seconds": 1,
    "views": 2,
    "probability / entropy / ECE": 3,
}

#: Figure groups in the paper's order: (file-name prefix, heading, what the figure is).
FIGURE_GROUPS = (
    (
        "fig1-",
        "Fig. 1: detector response over viewpoint",
        "One test instance of each target seen from every azimuth, with the detector's response and "
        "its detections drawn.",
    ),
    (
        "fig2-",
        "Fig. 2: DPM viewpoint detection functions",
        "Posterior predictive of the DPM response over azimuth for the target category (positives "
        "left, negatives right).",
    ),
    (
        "fig3-",
        "Fig. 3: viewpoint detection functions of SIFT matching and bag-of-features",
        "The same functions for the two weaker detectors: flatter over azimuth and less separated.",
    ),
    (
        "fig4-",
        "Fig. 4: the posterior over presence and pose",
        "p(present, pose | F) (solid) and p(absent, pose | F) (dashed) on polar axes after each view "
        "of one trial; the x marks the true pose, the circle the robot's azimuth.",
    ),
    (
        "fig5-",
        "Fig. 5: entropy planning vs a random unseen view",
        "Per target and method: the TP-minus-TN statistic (left) and the class entropy H(o | F) "
        "(right) against the number of views, entropy planner vs random view, with bootstrap 95% "
        "intervals.",
    ),
)

#: Captions of the figures outside the paper's numbering, by file-name prefix.
OTHER_CAPTIONS = (
    (
        "dataset-sheet",
        "The synthetic multiview dataset: one instance per category from each azimuth.",
    ),
    ("view-sphere", "The views (azimuths x elevations x scales) around one object."),
    ("responses-", "Mean detector response by azimuth, positives vs negatives."),
    ("trace-", "MCMC trace of one hierarchical fit."),
    ("forest-", "Posterior intervals of one hierarchical fit."),
    (
        "calibration",
        "Reliability of p(target present | responses): naive Bayes vs instance-aware filter.",
    ),
    ("kway-accuracy", "K-way recognition: accuracy, p(true category) and entropy against views."),
    ("kway-confusion", "K-way recognition: confusion matrices after 1, 2 and 4 views."),
    (
        "difficulty-sweep",
        "When looking pays off: views saved by entropy planning against held-out AP, across imaging "
        "difficulty and detector families.",
    ),
)

#: Which stage writes each input, for the line that says an input is missing.
_STAGE_OF = {
    "timings.json": "reproduce",
    "detectors/quality.json": "detect",
    "models/diagnostics.json": "fit",
    "models/heldout.csv": "fit",
    "simulate-summary.json": "simulate",
    "kway-summary.json": "kway",
    "decomposition.json": "decompose",
}

_KINDS = ("gaussian", "hierarchical")


# --------------------------------------------------------------------------------------- formatting


def _num(x: Any, digits: int) -> str:
    """``x`` rounded to ``digits`` decimals; '' for a missing value and 'n/a' for NaN or None."""
    if x is None:
        return "n/a"
    if isinstance(x, str):
        if not x.strip():
            return ""
        try:
            x = float(x)
        except ValueError:
            return x
    x = float(x)
    if not math.isfinite(x):
        return "n/a"
    text = f"{x:.{digits}f}"
    return text.lstrip("-") if float(text) == 0 else text  # no "-0.000"


def _pm(mean: Any, se: Any, digits: int) -> str:
    """``mean ± se`` (the s.e. dropped when it is not estimable)."""
    m, s = _num(mean, digits), _num(se, digits)
    return m if s in ("", "n/a") else f"{m} ± {s}"


def _md_table(rows: list[dict[str, str]], columns: list[str]) -> str:
    """A Markdown table of already formatted cells."""
    if not rows:
        return "_(empty)_\n"
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> str:
    """Write ``rows`` (full precision) to ``path``; return the Markdown link to it."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return f"[`{path.name}`]({path.name})"


def _missing(title: str, rel: str, why: str = "") -> str:
    stage = _STAGE_OF.get(rel, "")
    reason = why or (
        f"`{rel}` was not written (the `{stage}` stage did not run)"
        if stage
        else f"`{rel}` is missing"
    )
    return f"## {title}\n\n_Not available: {reason}._\n"


def _load_json(out: Path, rel: str, title: str) -> tuple[Any, str]:
    """``(data, "")``, or ``(None, section saying why not)``."""
    path = out / rel
    if not path.exists():
        return None, _missing(title, rel)
    try:
        return read_json(path, rel), ""
    except CorruptFileError as err:
        return None, _missing(title, rel, f"`{rel}` could not be read: {err.reason}")


# ----------------------------------------------------------------------------------------- sections


def _section_timings(out: Path) -> str:
    title = "Stage timings"
    t, msg = _load_json(out, "timings.json", title)
    if msg:
        return msg
    cpu = t.get("cpu_seconds") or {}
    machine = t.get("machine") or {}
    background = set(t.get("background") or ())
    busy = t.get("machine_busy_seconds") or {}
    meta = ("cpu_seconds", "machine", "background", "wall_seconds_total", "machine_busy_seconds")
    stages = {k: v for k, v in t.items() if k not in meta}
    rows = []
    for k, v in stages.items():
        c = cpu.get(k)
        ratio = c / v if isinstance(v, int | float) and v > 0 and c is not None else None
        b = busy.get(k)
        cores = b / v if isinstance(v, int | float) and v > 0 and b is not None else None
        rows.append(
            {
                "stage": f"{k} (background)" if k in background else k,
                "wall s": _num(v, 1),
                "CPU s": _num(c, 1) if c is not None else "",
                "CPU / wall": _num(ratio, 2) if ratio is not None else "",
                "cores busy": _num(cores, 2) if cores is not None else "",
            }
        )
    # a background stage's seconds overlap the others': the run's own wall time when it was recorded
    total = t.get("wall_seconds_total")
    if not isinstance(total, int | float):
        total = sum(
            float(v)
            for k, v in stages.items()
            if isinstance(v, int | float) and k not in background
        )
    total_cpu = sum(float(v) for v in cpu.values())
    b_total = busy.get("total")
    rows.append(
        {
            "stage": "**total**",
            "wall s": _num(total, 1),
            "CPU s": _num(total_cpu, 1) if cpu else "",
            "CPU / wall": _num(total_cpu / total, 2) if cpu and total > 0 else "",
            "cores busy": _num(b_total / total, 2) if b_total is not None and total > 0 else "",
        }
    )
    where = (
        f" on {machine.get('cores')} cores ({machine.get('cpu')})" if machine.get("cores") else ""
    )
    cols = ["stage", "wall s", "CPU s", "CPU / wall"] if cpu else ["stage", "wall s"]
    note = ""
    if busy:
        cols.append("cores busy")
        note += (
            "\n\n*Cores busy* is the whole machine's busy CPU time during the stage over its wall time "
            "(Linux's `/proc/stat`): the stage's own CPU and that of a background stage running beside "
            "it (and of anything else the machine ran)."
        )
    if background:
        names = ", ".join(sorted(background))
        note += (
            f"\n\nThe {names} stage ran in the background, at a lower priority, beside the stages after "
            "it, taking the cycles they left idle: its wall time overlaps theirs, and the total is the "
            "run's own wall time, not the sum of the stages'."
        )
    return (
        f"## {title}\n\nWall time and CPU time (user + system, this process and its worker "
        f"processes) of each stage{where}, from `timings.json`:\n\n" + _md_table(rows, cols) + note
    )


def _section_detectors(out: Path) -> str:
    title = "Detectors"
    q, msg = _load_json(out, "detectors/quality.json", title)
    if msg:
        return msg
    ap = q.get("average_precision", {})
    cats = sorted({c for fam in ap.values() for c in fam})
    mean_ap = q.get("mean_average_precision", {})
    rows = [
        {
            "detector": fam,
            **{c: _num(ap[fam].get(c, ""), 2) for c in cats},
            "mean": _num(mean_ap.get(fam, ""), 2),
        }
        for fam in ap
    ]
    text = (
        f"## {title}\n\nOne-vs-rest average precision on the `{q.get('split', 'test')}` split "
        "(from `detectors/quality.json`):\n\n" + _md_table(rows, ["detector", *cats, "mean"])
    )
    dep = q.get("azimuth_dependence", {})
    dep_rows = [
        {
            "detector": fam,
            **{
                c: f"{_num(v.get('positive'), 2)} / {_num(v.get('negative'), 2)}"
                for c, v in per.items()
            },
        }
        for fam, per in dep.items()
    ]
    if dep_rows:
        definition = q.get("azimuth_dependence_definition", "")
        text += (
            "\nAzimuth dependence of the response, positives / negatives"
            + (f" ({definition})" if definition else "")
            + ":\n\n"
            + _md_table(dep_rows, ["detector", *cats])
        )
    if isinstance(q.get("seconds"), dict):
        text += (
            "\nWall time: "
            + ", ".join(f"{k} {_num(v, 1)} s" for k, v in q["seconds"].items())
            + ".\n"
        )
    return text


def _section_diagnostics(out: Path) -> str:
    title = "MCMC diagnostics of the hierarchical fits"
    diag, msg = _load_json(out, "models/diagnostics.json", title)
    if msg:
        return msg
    rows, full = [], []
    for fit, d in sorted(diag.items()):
        if not isinstance(d, dict) or not isinstance(d.get("rhat_max"), dict):
            continue
        attempts = " -> ".join(f"{a['target_accept_prob']:g}" for a in d.get("attempts", []))
        # the azimuth coefficients sampled non-centred at the first attempt (choose_noncentered)
        first = (d.get("attempts") or [{}])[0].get("noncentered", d.get("noncentered")) or []
        coef = ", ".join(x for x in first if x.startswith("coef")) or "none"
        ebfmi = d.get("ebfmi") or [float("nan")]
        rows.append(
            {
                "fit": fit,
                "ok": "yes" if d.get("ok") else "NO",
                "max R-hat": _num(max(d["rhat_max"].values()), 3),
                "min bulk ESS": _num(min(d.get("ess_bulk_min", {"": None}).values()), 0),
                "min tail ESS": _num(min(d.get("ess_tail_min", {"": None}).values()), 0),
                "divergences": str(d.get("divergences", "")),
                "min E-BFMI": _num(min(ebfmi), 2),
                "target accept": attempts,
                "non-centred coef": coef,
                "failures": "; ".join(d.get("failures", [])),
            }
        )
        for param, rhat in d["rhat_max"].items():
            full.append(
                {
                    "fit": fit,
                    "parameter": param,
                    "rhat_max": rhat,
                    "ess_bulk_min": d.get("ess_bulk_min", {}).get(param, ""),
                    "ess_tail_min": d.get("ess_tail_min", {}).get(param, ""),
                    "fit_ok": bool(d.get("ok")),
                    "divergences": d.get("divergences", ""),
                    "ebfmi_min": min(ebfmi),
                    "target_accept": attempts,
                }
            )
    rows.sort(key=lambda r: (r["ok"] == "yes", r["fit"]))  # failures first
    n_ok = sum(r["ok"] == "yes" for r in rows)
    n_retried = sum(
        len(d.get("attempts", [])) > 1
        for d in diag.values()
        if isinstance(d, dict) and isinstance(d.get("rhat_max"), dict)
    )
    n_effect = sum(
        bool(d.get("azimuth_effect"))
        for d in diag.values()
        if isinstance(d, dict) and isinstance(d.get("rhat_max"), dict)
    )
    effect = (
        f" {n_effect} of {len(rows)} fits have the instance x azimuth effect (`scrppl fit "
        "--azimuth-effect auto` gives it where the grid has more than one ring)."
        if n_effect
        else ""
    )
    link = _write_csv(out / "report-diagnostics.csv", full)
    th = diag.get("thresholds", {})
    return (
        f"## {title}\n\n**{n_ok} of {len(rows)} fits pass every check** (R-hat <= "
        f"{th.get('rhat_max', 1.01)}, bulk ESS >= {_num(th.get('ess_bulk_min', 400), 0)}, no "
        f"divergences, E-BFMI >= {th.get('ebfmi_min', 0.3)}). Each fit's parameterisation was chosen "
        "from its data before sampling (`non-centred coef`: the azimuth coefficients sampled "
        "non-centred, by the count and signal-to-noise rules of `choose_noncentered`); "
        f"**{n_retried} of {len(rows)} needed a second attempt** (the retry ladder: a higher acceptance "
        "target, shown in `target accept`, then every coefficient non-centred, longer chains, pooled "
        f"noise).{effect} Worst parameter of each fit, from "
        f"`models/diagnostics.json`; every parameter in {link}.\n\n"
        + _md_table(rows, list(rows[0]) if rows else [])
    )


def _heldout_wide(rows: list[dict[str, str]]) -> list[dict[str, Any]]:
    """Pivot ``heldout.csv`` to one row per (detector, target, class), the model kinds side by side."""
    value_cols = [
        c
        for c in (rows[0] if rows else {})
        if c not in ("detector", "target", "kind", "class", "n_instances", "n_responses")
    ]
    wide: dict[tuple[str, str, str], dict[str, Any]] = {}
    for r in rows:
        key = (r.get("detector", ""), r.get("target", ""), r.get("class", "all"))
        w = wide.setdefault(
            key,
            {
                "detector": key[0],
                "target": key[1],
                "class": key[2],
                "n_instances": r.get("n_instances", ""),
                "n_responses": r.get("n_responses", ""),
            },
        )
        for c in value_cols:
            w[f"{r.get('kind', '')}_{c}"] = float(r[c]) if r[c] not in ("", None) else float("nan")
    return list(wide.values())


def _mean(values: list[float]) -> float:
    vals = [v for v in values if math.isfinite(v)]
    return sum(vals) / len(vals) if vals else float("nan")


def _section_heldout(out: Path) -> str:
    title = "Held-out comparison of viewpoint models"
    rel = "models/heldout.csv"
    if not (out / rel).exists():
        return _missing(title, rel)
    with (out / rel).open() as fh:
        wide = _heldout_wide(list(csv.DictReader(fh)))
    link = _write_csv(out / "report-heldout.csv", wide)
    allc = [w for w in wide if w["class"] == "all"]
    g, h = _KINDS

    def get(w: dict[str, Any], kind: str, col: str) -> float:
        return w.get(f"{kind}_{col}", float("nan"))

    rows = [
        {
            "detector": w["detector"],
            "target": w["target"],
            "n": str(w["n_instances"]),
            "single, Gaussian": _pm(get(w, g, "lpd_single"), get(w, g, "lpd_single_se"), 3),
            "single, hierarchical": _pm(get(w, h, "lpd_single"), get(w, h, "lpd_single_se"), 3),
            "joint, Gaussian": _pm(get(w, g, "lpd_joint"), get(w, g, "lpd_joint_se"), 3),
            "joint, hierarchical": _pm(get(w, h, "lpd_joint"), get(w, h, "lpd_joint_se"), 3),
            "joint gain": _num(get(w, h, "lpd_joint") - get(w, g, "lpd_joint"), 3),
            "90% cover, G / H": f"{_num(get(w, g, 'cover90'), 2)} / {_num(get(w, h, 'cover90'), 2)}",
        }
        for w in sorted(allc, key=lambda w: (w["detector"], w["target"]))
    ]
    detectors = sorted({w["detector"] for w in allc})
    means = []
    for det in detectors:
        ws = [w for w in allc if w["detector"] == det]
        row = {"detector": det, "targets": str(len(ws))}
        for label, col, digits in (
            ("single", "lpd_single", 3),
            ("joint", "lpd_joint", 3),
            ("50% cover", "cover50", 2),
            ("90% cover", "cover90", 2),
        ):
            for kind, short in ((g, "Gaussian"), (h, "hierarchical")):
                row[f"{label}, {short}"] = _num(_mean([get(w, kind, col) for w in ws]), digits)
        means.append(row)
    return (
        f"## {title}\n\nLog predictive density of the held-out instances' responses, per response "
        "(nats; higher is better), ± its standard error over instances: `single` scores each response "
        "alone, `joint` scores an instance's responses together (where the hierarchical model's "
        "instance effect should pay off; for the Gaussian model, which has none, the two agree); `joint gain` = hierarchical − Gaussian. `90% cover` is the "
        "share of responses inside the 90% predictive interval (0.90 when calibrated). Both classes "
        f"together, from `{rel}`; the absent / present split and every column in {link}.\n\n"
        "Mean over targets, per detector:\n\n"
        + _md_table(means, list(means[0]) if means else [])
        + "\nPer detector and target:\n\n"
        + _md_table(rows, list(rows[0]) if rows else [])
    )


def _section_experiment(out: Path) -> str:
    title = "Sequential recognition experiment"
    summ, msg = _load_json(out, "simulate-summary.json", title)
    if msg:
        return msg
    rows, steps_rows, full = [], [], []
    for target, t in summ.get("targets", {}).items():
        for exp in ("paper_experiment", "large_experiment"):
            for method, m in t.get(exp, {}).items():
                if not isinstance(m, dict) or "views_to_confidence" not in m:
                    continue
                v = m["views_to_confidence"]
                d = m.get("views_to_confidence_difference_95ci", {})
                name = exp.replace("_experiment", "")
                rows.append(
                    {
                        "target": target,
                        "experiment": name,
                        "method": method,
                        "views, entropy": _num(v.get("sampled"), 2),
                        "views, random": _num(v.get("random"), 2),
                        "difference [95% CI]": f"{_num(d.get('mean'), 3)} "
                        f"[{_num(d.get('lo'), 3)}, {_num(d.get('hi'), 3)}]",
                        "ECE": _num(m.get("ece"), 3),
                    }
                )
                flat: dict[str, Any] = {"target": target, "experiment": name, "method": method}
                for key, val in m.items():
                    if isinstance(val, dict):
                        for k2, v2 in val.items():
                            if isinstance(v2, dict):
                                flat.update({f"{key}.{k2}.{k3}": v3 for k3, v3 in v2.items()})
                            else:
                                flat[f"{key}.{k2}"] = v2
                    else:
                        flat[key] = val
                full.append(flat)
                if name == "paper":
                    pc = m.get("p_correct_by_step", {})
                    steps = sorted(pc.get("sampled", {}), key=int)
                    if steps:
                        steps_rows.append(
                            {
                                "target": target,
                                "method": method,
                                **{
                                    f"{s} view{'s' * (s != '1')}": f"{_num(pc['sampled'].get(s), 3)}"
                                    f" / {_num(pc.get('random', {}).get(s), 3)}"
                                    for s in steps
                                },
                            }
                        )
    settings = summ.get("settings", {})
    link = _write_csv(out / "report-experiment.csv", full) if full else "(no rows)"
    text = (
        f"## {title}\n\nDetector `{summ.get('detector', '')}`. Views until p(true class) > "
        f"{settings.get('confidence_threshold', 0.95)} for the entropy planner and a random unseen view "
        "(paired trials; a negative difference means entropy planning needs fewer views), and the "
        "expected calibration error (ECE) of p(o | F), in the paper-sized experiment"
        + (f" ({settings['trials']} trials)" if "trials" in settings else "")
        + " and the large one"
        + (f" ({settings['large_trials']} trials)" if "large_trials" in settings else "")
        + f". From `simulate-summary.json`; every number by step in {link}.\n\n"
        + _md_table(rows, list(rows[0]) if rows else [])
    )
    if steps_rows:
        text += (
            "\np(correct class) after n views, entropy planner / random view (paper experiment):\n\n"
            + _md_table(steps_rows, list(steps_rows[0]))
        )
    if settings:
        text += "\nSettings:\n\n" + _md_table(
            [
                {"setting": k, "value": ", ".join(map(str, v)) if isinstance(v, list) else str(v)}
                for k, v in settings.items()
            ],
            ["setting", "value"],
        )
        if "large_max_draws" in settings:
            text += (
                "\n`max_draws` posterior draws of each fit, evenly spaced, serve every trial of the paper "
                "experiment; each trial of the large one reads its own `large_max_draws`, drawn from all "
                "of a fit's draws by the trial's key, so its intervals cover which draws were read.\n"
            )
    extra = []
    if "calibration_ece_pooled_over_targets" in summ:
        pooled = summ["calibration_ece_pooled_over_targets"]
        if isinstance(pooled, dict):
            extra.append(
                "ECE pooled over targets: "
                + ", ".join(f"{k} {_num(v, 3)}" for k, v in pooled.items())
            )
        else:
            extra.append(f"ECE pooled over targets: {_num(pooled, 3)}")
    if "seconds_total" in summ:
        extra.append(f"wall time {_num(summ['seconds_total'], 1)} s")
    if extra:
        text += "\n" + "; ".join(extra) + ".\n"
    return text


def _section_kway(out: Path) -> str:
    """K-way recognition (``scrppl kway``): :func:`scrppl.kway.report.kway_markdown`."""
    from scrppl.kway.report import TITLE, kway_markdown

    summ, msg = _load_json(out, "kway-summary.json", TITLE)
    return msg or kway_markdown(summ)


def _section_sweep(out: Path, profile: str) -> str:
    """The difficulty sweep (``scrppl sweep``): one row per (level, family, target)."""
    title = "When does looking pay off? The difficulty sweep"
    from scrppl.pipeline import NO_SWEEP_PROFILES

    if profile in NO_SWEEP_PROFILES and not (out / "sweep-summary.json").exists():
        return (
            f"## {title}\n\n_Not run in the {profile} profile (it would add about two thirds to the "
            f"run's time): `scrppl sweep --profile {profile} --out {out.name}` writes it._\n"
        )
    summ, msg = _load_json(out, "sweep-summary.json", title)
    if msg:
        return msg
    st = summ.get("settings", {})
    rows = []
    for level, points in summ.get("points", {}).items():
        for name, p in points.items():
            v = p.get("views_to_confidence", {})
            r = p.get("reached_confidence", {})
            rows.append(
                {
                    "level": level.removeprefix("level-").replace("p", "."),
                    "detector/target": name,
                    "AP": _num(p.get("ap"), 2),
                    "views, random": _num(v.get("random"), 2),
                    "views, entropy": _num(v.get("sampled"), 2),
                    "saved [95% CI]": f"{_num(p.get('views_saved'), 3)} "
                    f"[{_num(p.get('views_saved_lo'), 3)}, {_num(p.get('views_saved_hi'), 3)}]",
                    "confident, random": _num(r.get("random"), 3),
                    "trials": p.get("n_trials", "?"),
                    "fit ok": "yes" if p.get("fit_ok") else "NO",
                }
            )
    from scrppl.models.fit import RETRY_ACCEPT

    text = (
        f"## {title}\n\n"
        "The paired experiment repeated with the run's detectors on new renderings of its held-out "
        "instances at imaging difficulty levels (0: no nuisance, 1: the `robot` preset, 2: `hard`; "
        "`scrppl.datasets.synthetic.domain.domain_at_level`), one ring of views: "
        + (
            f"paired trials in blocks of {st.get('block_trials')} until the interval of the views saved "
            f"is at most +-{st['half_width']} views, at most {st.get('n_trials', '?')} (rounded up to "
            "whole blocks; the *trials* column says how many ran)"
            if st.get("half_width", 0) > 0
            else f"{st.get('n_trials', '?')} paired trials per row"
        )
        + ", the hierarchical model with the "
        "instance-aware filter, entropy planning against a random unseen view. Views are the mean "
        "number to p(true) > 0.95 (a trial that never gets there counts as one more than it had); "
        "*saved* is random minus planning with its paired bootstrap interval. Each fit runs "
        f"{st.get('num_chains', '?')} chains x {st.get('num_samples', '?')} draws with every azimuth "
        "coefficient non-centred"
        + (
            ", and a fit that misses a diagnostic gate is refitted at the acceptance target "
            f"{RETRY_ACCEPT}, then with {st['retry_longer']} times the warm-up and draws"
            if st.get("retry_longer", 1) > 1
            else ", in one attempt"
        )
        + "; the diagnostics are in `sweep-summary.json`.\n\n"
    )
    if not rows:
        return text + "_(no points)_\n"
    n_ok = sum(r["fit ok"] == "yes" for r in rows)
    text += _md_table(rows, list(rows[0]))
    text += f"\n{n_ok} of {len(rows)} fits pass every diagnostic gate.\n"
    return text


def _section_decomposition(out: Path, profile: str) -> str:
    """Where planning gains or loses views (``scrppl decompose``): one row per target and method."""
    title = "Where planning gains or loses views"
    if profile != "full" and not (out / "decomposition.json").exists():
        return (
            f"## {title}\n\n_Not run in the {profile} profile: `scrppl decompose --out {out.name}` "
            "writes it._\n"
        )
    summ, msg = _load_json(out, "decomposition.json", title)
    if msg:
        return msg
    st = summ.get("settings", {})
    names = {"greedy_joint": "eq. 5", "confident": "confident", "clairvoyant": "clairvoyant"}
    rows, csv_rows = [], []
    for target, entry in summ.get("targets", {}).items():
        for method, m in entry.get("methods", {}).items():
            r = m.get("rows", {})
            if "random" not in r:
                continue
            row = {
                "target": target,
                "method": method,
                "random": _num(r["random"].get("views_to_confidence"), 2),
            }
            for key, name in names.items():
                if key not in r:
                    continue
                d = r[key].get("difference_vs_random", {})
                row[name] = (
                    f"{_num(r[key].get('views_to_confidence'), 2)} "
                    f"({_num(d.get('mean'), 2)} [{_num(d.get('lo'), 2)}, {_num(d.get('hi'), 2)}])"
                )
            if "confident" in r and m.get("room"):
                s = r["confident"].get("share_of_room", {})
                row["confident share of room"] = (
                    f"{_num(s.get('mean'), 2)} [{_num(s.get('lo'), 2)}, {_num(s.get('hi'), 2)}]"
                )
            rows.append(row)
            csv_rows.append(
                {"target": target, "method": method}
                | {f"{k}_views": v.get("views_to_confidence") for k, v in r.items()}
                | {
                    f"{k}_minus_random": v.get("difference_vs_random", {}).get("mean")
                    for k, v in r.items()
                }
            )
    text = (
        f"## {title}\n\n"
        f"Mean views to p(true) > 0.95 on {st.get('trials', '?')} paired trials per target, for a "
        "random unseen view, the paper's planner (eq. 5), the planner for views to "
        "confidence (`scrppl.confident`) and the clairvoyant bound (the fewest views had every response "
        "been known); in brackets each row minus random with its paired 95% bootstrap interval. The "
        "*room* is random minus clairvoyant; the confident planner's *share* is the part of it it takes. "
        "Every table and the per-view information are in `decomposition.md`.\n\n"
    )
    if not rows:
        return text + "_(no targets)_\n"
    columns = list(dict.fromkeys(k for row in rows for k in row))
    text += _md_table([{c: row.get(c, "") for c in columns} for row in rows], columns)
    link = _write_csv(out / "report-decomposition.csv", csv_rows)
    return (
        text + f"\nEvery row's mean views and difference from random in full precision: {link}.\n"
    )


def _caption(name: str) -> str:
    return next((cap for prefix, cap in OTHER_CAPTIONS if name.startswith(prefix)), "")


def _section_figures(out: Path) -> str:
    figdir = out / "figures"
    pngs = sorted(figdir.glob("*.png")) if figdir.exists() else []
    if not pngs:
        return (
            "## Figures\n\n_Not available: no figures under `figures/` (the stages did not run)._\n"
        )
    parts = ["## Figures\n"]
    used: set[Path] = set()
    for prefix, heading, sentence in FIGURE_GROUPS:
        group = [p for p in pngs if p.name.startswith(prefix)]
        used.update(group)
        parts.append(f"### {heading}\n\n{sentence}\n")
        if not group:
            parts.append(f"_No `{prefix}*.png` under `figures/`._\n")
        parts += [f"**{p.stem}**\n\n![{p.stem}](figures/{p.name})\n" for p in group]
    rest = [p for p in pngs if p not in used]
    rest.sort(
        key=lambda p: (
            next(
                (i for i, (pre, _) in enumerate(OTHER_CAPTIONS) if p.name.startswith(pre)),
                len(OTHER_CAPTIONS),
            ),
            p.name,
        )
    )
    if rest:
        parts.append(
            "### Other figures\n\nThe dataset, the raw responses, the fits and calibration.\n"
        )
        for p in rest:
            cap = _caption(p.name)
            parts.append(
                f"**{p.stem}**"
                + (f" — {cap}" if cap else "")
                + f"\n\n![{p.stem}](figures/{p.name})\n"
            )
    return "\n".join(parts)


def _section_problems(out: Path) -> str:
    """The dataset's files that ``scrppl detect`` skipped (``dataset-problems.csv``), if any."""
    from scrppl.datasets.problems import PROBLEMS_FILE, read_problems

    path = out / PROBLEMS_FILE
    if not path.exists():
        return ""
    try:
        problems = read_problems(path)
    except (OSError, ValueError, KeyError, UnicodeDecodeError) as err:
        return f"\n_`{PROBLEMS_FILE}` could not be read: {err}._\n"
    if not problems:
        return ""
    rows = [{"file": str(p.path), "artefact": p.artefact, "problem": p.message} for p in problems]
    shown = 50
    text = (
        f"\n**{len(problems)} file(s) of the dataset could not be used** and were skipped (every valid "
        f"image was used); the list is in `{PROBLEMS_FILE}`:\n\n"
        + _md_table(rows[:shown], ["file", "artefact", "problem"])
    )
    if len(rows) > shown:
        text += f"\n... and {len(rows) - shown} more.\n"
    return text


def _section_dataset(dataset_root: Path | None, seed: int, out: Path | None = None) -> str:
    if dataset_root is None:
        return ""
    from scrppl.datasets import dataset_layout, open_dataset

    layout = dataset_layout(dataset_root)
    if layout not in ("synthetic", "index", "savarese"):
        return f"## Dataset\n\n_Not available: no dataset found at `{dataset_root}`._\n"
    try:  # names only: the dataset stage has checked every file
        summary = open_dataset(
            dataset_root, split_seed=seed, validate=False, progress=False, errors="report"
        ).summary()
    except (FileNotFoundError, ValueError) as err:
        return f"## Dataset\n\n_Not available: the dataset could not be loaded: {err}._\n"
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
    text = "## Dataset\n\n" + _md_table([{k: str(summary.get(k, "")) for k in keys}], keys)
    if summary.get("split_counts"):
        text += (
            "\nInstances per split: "
            + ", ".join(f"{k} {v}" for k, v in summary["split_counts"].items())
            + ".\n"
        )
    if out is not None:
        text += _section_problems(out)
    return text


#: The default regime's criteria, stated before any experiment is run (issue: the paper's regime):
#: held-out DPM mean average precision in this range ...
REGIME_AP_RANGE = (0.55, 0.75)
#: ... and single views ambiguous enough that the random-view baseline of the default method needs at
#: least this many views on average to reach p(true) > 0.95.
REGIME_MIN_RANDOM_VIEWS = 3.0
#: The method whose views to confidence the criteria use (the library's default model and filter).
REGIME_METHOD = "hierarchical+instance"


def imaging_preset(dataset_root: Path | None) -> str | None:
    """The imaging preset recorded in a synthetic dataset's ``synthetic.json``; ``None`` otherwise."""
    if dataset_root is None:
        return None
    path = Path(dataset_root) / "synthetic.json"
    if not path.exists():
        return None
    try:
        meta = read_json(path, "synthetic dataset provenance")
    except CorruptFileError:
        return None
    domain = meta.get("config", {}).get("domain", {}) if isinstance(meta, dict) else {}
    return str(domain.get("name", "clean")) if isinstance(domain, dict) else None


def regime_numbers(out: str | Path) -> dict[str, Any]:
    """The regime of a run as its criteria measure it.

    From ``detectors/quality.json`` and ``simulate-summary.json``: the held-out DPM mean AP, and for
    :data:`REGIME_METHOD` in the large experiment the mean over targets of the views to
    ``p(true) > 0.95`` for the random baseline and the entropy planner, with the per-target paired
    difference. Missing inputs leave their entries ``None``.
    """
    out = Path(out)
    res: dict[str, Any] = {"dpm_mean_ap": None, "random_views": None, "planning_views": None}
    q = out / "detectors" / "quality.json"
    if q.exists():
        try:
            res["dpm_mean_ap"] = (
                read_json(q, "detector quality").get("mean_average_precision", {}).get("dpm")
            )
        except (CorruptFileError, AttributeError):
            pass
    sp = out / "simulate-summary.json"
    if sp.exists():
        try:
            summ = read_json(sp, "simulation summary")
        except CorruptFileError:
            summ = {}
        per_target = {}
        for target, t in summ.get("targets", {}).items():
            m = t.get("large_experiment", {}).get(REGIME_METHOD)
            if isinstance(m, dict) and "views_to_confidence" in m:
                per_target[target] = {
                    "random": m["views_to_confidence"].get("random"),
                    "planning": m["views_to_confidence"].get("sampled"),
                    "difference_95ci": m.get("views_to_confidence_difference_95ci", {}),
                }
        if per_target:
            res["targets"] = per_target
            res["detector"] = summ.get("detector")
            res["random_views"] = math.fsum(v["random"] for v in per_target.values()) / len(
                per_target
            )
            res["planning_views"] = math.fsum(v["planning"] for v in per_target.values()) / len(
                per_target
            )
    ap, views = res["dpm_mean_ap"], res["random_views"]
    res["ap_criterion_met"] = (
        None if ap is None else bool(REGIME_AP_RANGE[0] <= ap <= REGIME_AP_RANGE[1])
    )
    res["ambiguity_criterion_met"] = (
        None if views is None else bool(views >= REGIME_MIN_RANDOM_VIEWS)
    )
    return res


def _section_regime(out: Path, preset: str | None) -> str:
    r = regime_numbers(out)
    if r["dpm_mean_ap"] is None and r["random_views"] is None:
        return ""
    yes = {True: "met", False: "not met", None: "not measured"}
    text = "## Regime\n\n"
    if preset:
        text += f"Imaging preset `{preset}` (`scrppl.datasets.synthetic.domain`)" + (
            ": detectors trained on catalogue images, scored on robot images with the preset's nuisances. "
            if preset != "clean"
            else ": detectors trained and scored in one clean rendering domain. "
        )
    lo, hi = REGIME_AP_RANGE
    text += (
        f"Held-out DPM mean average precision {_num(r['dpm_mean_ap'], 2)} (criterion {lo}-{hi}: "
        f"{yes[r['ap_criterion_met']]}). "
    )
    if r["random_views"] is not None:
        text += (
            f"Views to p(true) > 0.95 with `{REGIME_METHOD}` in the large experiment, mean over "
            f"{len(r['targets'])} targets of the `{r.get('detector')}` detector: random unseen view "
            f"{_num(r['random_views'], 2)} (criterion at least {REGIME_MIN_RANDOM_VIEWS:g}: "
            f"{yes[r['ambiguity_criterion_met']]}), entropy planning {_num(r['planning_views'], 2)}.\n"
        )
        rows = [
            {
                "target": t,
                "views, random": _num(v["random"], 2),
                "views, entropy": _num(v["planning"], 2),
                "entropy - random [95% CI]": f"{_num(v['difference_95ci'].get('mean'), 3)} "
                f"[{_num(v['difference_95ci'].get('lo'), 3)}, {_num(v['difference_95ci'].get('hi'), 3)}]",
            }
            for t, v in r["targets"].items()
        ]
        text += "\n" + _md_table(rows, list(rows[0]))
    else:
        text += "\n"
    return text


def write_report(
    out: str | Path,
    *,
    dataset_root: Path | None = None,
    profile: str = "full",
    seed: int = 0,
    preset: str | None = None,
) -> Path:
    """Write ``<out>/report.md`` and its ``report-*.csv`` tables from the stages' outputs.

    Parameters
    ----------
    out
        The output folder of ``scrppl reproduce``.
    dataset_root
        The dataset the run used (its summary heads the report); ``None`` leaves that section out.
    profile, seed, preset
        As given to ``scrppl reproduce``; named in the report's first lines (``preset``: the synthetic
        dataset's imaging preset, ``None`` for a dataset the run did not generate).

    Returns
    -------
    The path of ``report.md``. A stage that did not run leaves its section saying so.
    """
    out = Path(out)
    for stale in out.glob("report-*.csv"):  # a table whose input is gone must not linger
        stale.unlink()
    if preset is None:
        preset = imaging_preset(dataset_root)
    sections = [
        _section_regime(out, preset),
        _section_dataset(dataset_root, seed, out),
        _section_timings(out),
        _section_detectors(out),
        _section_diagnostics(out),
        _section_heldout(out),
        _section_experiment(out),
        _section_kway(out),
        _section_sweep(out, profile),
        _section_decomposition(out, profile),
        _section_figures(out),
    ]
    csvs = sorted(out.glob("report-*.csv"))
    head = (
        "# scrppl: reproduction report\n\n"
        "Active, sequential object-category recognition with viewpoint detection models, after Meger, "
        f"Gupta & Little (ICRA 2010). Generated by `scrppl reproduce --profile {profile}"
        + (f" --preset {preset}" if preset else "")
        + f" --seed {seed}`; "
        "every number below is read from the files beside this report and rounded to what it can carry "
        "(decimals: " + ", ".join(f"{k} {v}" for k, v in ROUNDING.items()) + ")."
    )
    if csvs:
        head += (
            " Full-precision tables: " + ", ".join(f"[`{p.name}`]({p.name})" for p in csvs) + "."
        )
    path = out / "report.md"
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join([head + "\n", *(s for s in sections if s)]))
    return path
