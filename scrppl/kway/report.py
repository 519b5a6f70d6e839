"""The K-way section of ``report.md``: :func:`kway_markdown` turns ``kway-summary.json`` into Markdown."""

from __future__ import annotations

__all__ = ["kway_markdown", "TITLE"]

TITLE = "Which object is it? K-way recognition"

_NAMES = {
    "planning": "K-way filter, entropy planning",
    "random": "K-way filter, random views",
    "one_vs_rest": "K one-vs-rest binary filters",
}


def _ci(mean: float, lo: float, hi: float, digits: int = 3) -> str:
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _experiment(e: dict, label: str, how: str = "") -> str:
    steps = e["steps"]
    head = (
        ["method"]
        + [f"{k} view{'s' if k > 1 else ''}" for k in steps]
        + ["views to p(true) > 0.95"]
    )
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, row in e["methods"].items():
        acc = row["accuracy"]
        cells = [_ci(acc["mean"][i], acc["lo"][i], acc["hi"][i]) for i in range(len(steps))]
        v = row["views_to_confidence"]
        lines.append(
            f"| {_NAMES.get(m, m)} | "
            + " | ".join(cells)
            + f" | {_ci(v['mean'], v['lo'], v['hi'], 2)} |"
        )
    d = e["planning_minus_random"]
    vd = d["views_to_confidence"]
    text = (
        f"**{label}** ({e['n_trials']} trials{_draws(e)}): accuracy of the MAP category after each "
        "number of views, "
        "mean [95% bootstrap interval]\n\n" + "\n".join(lines) + "\n\n"
        f"Planning minus random on the same trials: views to confidence {_ci(vd['mean'], vd['lo'], vd['hi'], 2)}"
    )
    acc_d = d["accuracy"]
    n = len(acc_d["mean"])
    idx = [k - 1 for k in steps if k - 1 < n]
    text += "; accuracy " + ", ".join(
        f"after {i + 1}: {_ci(acc_d['mean'][i], acc_d['lo'][i], acc_d['hi'][i])}" for i in idx
    )
    if "random_minus_one_vs_rest" in e:
        r = e["random_minus_one_vs_rest"]["views_to_confidence"]
        text += (
            f". The K-way filter (random views) minus one-vs-rest on the same views: views to confidence "
            f"{_ci(r['mean'], r['lo'], r['hi'], 2)}"
        )
        a = e["random_minus_one_vs_rest"].get("accuracy")
        if a:
            text += "; accuracy " + ", ".join(
                f"after {k}: {_ci(a['mean'][k - 1], a['lo'][k - 1], a['hi'][k - 1])}"
                for k in steps
                if k - 1 < len(a["mean"])
            )
    cal = e.get("calibration")
    if cal:
        text += (
            ". Expected calibration error of the top-label probability after "
            + ", ".join(str(k) for k in cal["steps"])
            + " views: "
            + "; ".join(
                f"{_NAMES.get(m, m)} " + ", ".join(f"{x:.3f}" for x in vals)
                for m, vals in cal["ece_top"].items()
            )
        )
        t = cal.get("temperature", 1.0)
        if t != 1.0 and "ece_top_untempered" in cal:
            raw = cal["ece_top_untempered"]
            text += (
                f" (the K-way probabilities tempered by T = {t:.2f}, fitted on trials of the fit "
                f"instances{how}; untempered: "
                + "; ".join(
                    f"{_NAMES.get(m, m)} " + ", ".join(f"{x:.3f}" for x in raw[m])
                    for m in raw
                    if m != "one_vs_rest"
                )
                + ")"
            )
    return text + ".\n"


def _recall(summary: dict, e: dict) -> str:
    cats = summary["categories"]
    head = ["method", "views"] + cats
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, by_step in e["confusion"].items():
        for step, mat in by_step.items():
            lines.append(
                f"| {_NAMES.get(m, m)} | {step} | "
                + " | ".join(f"{mat[i][i]:.2f}" for i in range(len(cats)))
                + " |"
            )
    return (
        "Per-category recall (the diagonal of the row-normalised confusion matrices; the matrices are in "
        "`kway-summary.json` and `figures/kway-confusion.png`):\n\n" + "\n".join(lines) + "\n"
    )


def _planner_name(planner: str | None) -> str:
    return {
        "collapsed": "collapsed (moment-matched update)",
        "sampled": "sampled (exact mixture update)",
        "equicorrelated": "equicorrelated (collapsed, one correlation shared by every two detectors)",
    }.get(planner or "", planner or "sampled")


def _draws(e: dict) -> str:
    """Which posterior draws an experiment's trials read (older summaries do not say)."""
    n, k = e.get("n_draws", 0), e.get("draws_per_trial", 0)
    if k:
        return f", each reading its own {k} of {n:,} posterior draws per detector"
    return f", {n} posterior draws per detector in every trial" if n else ""


def kway_markdown(summary: dict) -> str:
    """The report section for a ``kway-summary.json`` (:func:`scrppl.kway.study.summary_dict`)."""
    cfg = summary.get("planner_config", {})
    text = (
        f"## {TITLE}\n\n"
        f"Held-out instances of all {len(summary['categories'])} categories ({', '.join(summary['categories'])}), "
        f"hidden pose, random start; at every view the {summary['detector']} detectors of every category "
        f"respond. Filter: {summary.get('filter')}; planner: {_planner_name(cfg.get('planner'))} expected "
        f"{cfg.get('objective', '?')} entropy, M = {cfg.get('n_samples', '?')}.\n\n"
    )
    corr = summary.get("correlations")
    if corr:
        text += (
            "Responses correlated across the detectors (the correlated filter, `scrppl.kway.correlation`): "
            f"the correlation matrices fitted by NUTS in {corr['attempts']} "
            f"attempt{'s' if corr['attempts'] > 1 else ''}, diagnostics "
            f"{'passed' if corr['diagnostics_ok'] else 'FAILED'}; mean correlation between two detectors "
            f"{corr['view_rho_mean']:.2f} for the noise of one view, {corr['instance_rho_mean']:.2f} for "
            "the instance effects.\n\n"
        )
    if summary.get("diagnostics_failed"):
        text += f"_Fits used despite failed MCMC diagnostics: {', '.join(summary['diagnostics_failed'])}._\n\n"
    fitted = summary.get("calibration_fit", {})
    how = ""
    if fitted.get("method") == "leave-one-object-out":
        loo = fitted["loo"]
        how = (
            ", each object left out of the models by Pareto-smoothed importance sampling, with Pareto k "
            f"above {loo['threshold']} for {loo['above']} of {loo['pairs']} object-target pairs"
        )
    text += _experiment(summary["trials"], "Paper-sized experiment", how)
    if "large" in summary:
        text += "\n" + _experiment(summary["large"], "Large experiment", how)
    return text + "\n" + _recall(summary, summary["trials"])
