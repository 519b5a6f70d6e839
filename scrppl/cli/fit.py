"""``scrppl fit``: the paper's Gaussians and the hierarchical viewpoint models for every detector x target.

Reads ``<out>/responses.nc`` and writes under ``<out>``:

* ``models/gaussian-<detector>-<target>.nc`` and ``models/hierarchical-<detector>-<target>.nc``;
* ``models/diagnostics.json`` (R-hat, bulk/tail ESS, divergences, E-BFMI of every hierarchical fit);
* ``models/heldout.csv`` (held-out log predictive density and calibration, Gaussian vs hierarchical);
* ``figures/fig2-<dpm>-<target>.png`` / ``figures/fig3-<sift|bof>-<target>.png`` (polar viewpoint
  functions) and ``figures/trace-*.png``, ``figures/forest-*.png`` of one fit.

Fits whose files are newer than ``responses.nc`` are loaded instead of refitted unless ``--force``. The
command exits with status 3 when a fit fails its diagnostics, unless ``--accept-diagnostics``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from scrppl.cli._common import add_common

#: Chains for both profiles (on one host device per core, up to one per chain).
N_CHAINS = 4
#: NUTS settings per profile: (warm-up, kept draws per chain).
PROFILE_DRAWS = {"quick": (400, 400), "book": (500, 1000), "full": (500, 1000)}
#: Targets drawn in Figs. 2 and 3 when present (the paper's choice).
PAPER_TARGETS = ("bicycle", "car", "monitor")


def register(subparsers) -> None:
    """Add the ``fit`` subcommand."""
    p = subparsers.add_parser(
        "fit",
        help="fit the paper's Gaussians and hierarchical viewpoint models",
        description="Fit the paper's Gaussian and the hierarchical viewpoint model of every detector x "
        "target in <out>/responses.nc; write models/, diagnostics, held-out scores and figures.",
    )
    add_common(p)
    p.add_argument(
        "--accept-diagnostics",
        action="store_true",
        help="exit 0 even if a fit fails its MCMC diagnostics",
    )
    p.add_argument("--force", action="store_true", help="refit even if the models are current")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument(
        "--detectors", default=None, help="comma-separated detectors to fit (default: all)"
    )
    p.add_argument(
        "--targets", default=None, help="comma-separated target categories (default: all)"
    )
    p.add_argument(
        "--progress", action=argparse.BooleanOptionalAction, default=True, help="show progress bars"
    )
    p.set_defaults(func=handler)


def _configure_host_devices(n: int) -> None:
    """Ask XLA for ``n`` CPU devices (only effective before JAX initialises its backend)."""
    import numpyro

    numpyro.set_host_device_count(n)


def _select(requested: str | None, available, axis):
    if requested in (None, "", "all"):
        return list(available)
    requested = [x.strip() for x in requested.split(",") if x.strip()]
    missing = [x for x in requested if x not in available]
    if missing:
        raise ValueError(f"{axis}s {missing} are not in the response table ({list(available)})")
    return list(requested)


def _figure_targets(targets: list[str]) -> list[str]:
    chosen = [t for t in PAPER_TARGETS if t in targets]
    return chosen or targets[:3]


def handler(args: argparse.Namespace) -> int:
    """Run ``scrppl fit``; returns the exit status."""
    # one host device per core, up to one per chain (chains beyond that share a device by vmap;
    # more devices than cores only adds contention -- measured in benchmarks/bench_fit.py)
    _configure_host_devices(max(1, min(N_CHAINS, os.cpu_count() or 1)))
    import jax
    import pandas as pd
    from tqdm.auto import tqdm

    from scrppl._io import atomic_path
    from scrppl.models import transforms
    from scrppl.models.data import extract_view_data
    from scrppl.models.evaluate import evaluate_models
    from scrppl.models.fit import MODEL_VERSION, fit_hierarchical
    from scrppl.models.gaussian import fit_gaussian
    from scrppl.models.io import (
        load_posterior,
        load_response_model,
        model_path,
        save_gaussian,
        save_posterior,
    )
    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.predictive import to_response_model
    from scrppl.responses import load_response_table

    out = Path(args.out)
    responses = out / "responses.nc"
    table = load_response_table(responses)
    models_dir, fig_dir = out / "models", out / "figures"
    detectors = _select(args.detectors, [str(d) for d in table["detector"].values], "detector")
    targets = _select(args.targets, [str(t) for t in table["target"].values], "target")
    warmup, draws = PROFILE_DRAWS[args.profile]
    config = SamplerConfig(num_warmup=warmup, num_samples=draws, num_chains=N_CHAINS, chunk=warmup)
    key = jax.random.key(args.seed)
    stamp = responses.stat().st_mtime
    has_test = (table["split"].values.astype(str) == "test").any()

    def current(path: Path) -> bool:
        return not args.force and path.exists() and path.stat().st_mtime >= stamp

    diag_path = models_dir / "diagnostics.json"
    diagnostics = json.loads(diag_path.read_text()) if diag_path.exists() else {}
    diagnostics = {k: v for k, v in diagnostics.items() if k != "thresholds"}
    heldout, fitted = [], {}
    jobs = [(d, t) for d in detectors for t in targets]
    for job, (det, tgt) in enumerate(tqdm(jobs, desc="scrppl fit", disable=not args.progress)):
        data, meta = extract_view_data(table, det, tgt, split="fit")
        gpath = model_path(models_dir, "gaussian", det, tgt)
        hpath = model_path(models_dir, "hierarchical", det, tgt)
        if not current(gpath):
            g, n_obs = fit_gaussian(data)
            save_gaussian(gpath, g, n_obs, meta)
        tree = load_posterior(hpath) if current(hpath) else None
        if (
            tree is not None
            and json.loads(tree.attrs["meta"]).get("model_version") != MODEL_VERSION
        ):
            tree = None  # fitted by another version of the model
        if tree is None:
            tree = fit_hierarchical(
                jax.random.fold_in(key, job), data, meta, config, progress=args.progress, warn=False
            )  # reported below
            save_posterior(hpath, tree)
        report = json.loads(tree.attrs["diagnostics"])
        fit_meta = json.loads(tree.attrs["meta"])
        report["noncentered"] = fit_meta.get("noncentered")
        report["attempts"] = fit_meta.get("attempts", [])
        diagnostics[f"{det}/{tgt}"] = report
        gauss, _ = load_response_model(models_dir, "gaussian", det, tgt)
        hier = to_response_model(tree)
        fitted[(det, tgt)] = (gauss, hier, tree, meta["transform"])
        if has_test:
            test, _ = extract_view_data(table, det, tgt, split="test")
            heldout.append(
                evaluate_models(
                    {"gaussian": gauss, "hierarchical": hier},
                    test,
                    {"detector": det, "target": tgt},
                )
            )
    from scrppl.models.diagnostics import THRESHOLDS

    with atomic_path(diag_path) as tmp:
        tmp.write_text(json.dumps({"thresholds": THRESHOLDS, **diagnostics}, indent=1))
    if heldout:
        frame = pd.concat(heldout, ignore_index=True)
        with atomic_path(models_dir / "heldout.csv") as tmp:
            frame.to_csv(tmp, index=False)
        cols = [
            "detector",
            "target",
            "kind",
            "lpd_single",
            "lpd_single_se",
            "lpd_joint",
            "lpd_joint_se",
            "cover50",
            "cover90",
        ]
        print(
            "Held-out log predictive density per response (single / joint over the views of an "
            "instance) and interval coverage, all test instances:"
        )
        print(frame[frame["class"] == "all"][cols].to_string(index=False, float_format="%.3f"))
    else:
        print("no 'test' instances in the response table: held-out evaluation skipped")

    if not args.no_figures:
        _figures(fitted, targets, fig_dir, transforms)

    failed = {
        k: v["failures"]
        for k, v in diagnostics.items()
        if k.split("/")[0] in detectors and k.split("/")[1] in targets and not v["ok"]
    }
    if failed:
        for name, failures in failed.items():
            print(f"diagnostics failed for {name}: {'; '.join(failures)}", file=sys.stderr)
        if not args.accept_diagnostics:
            print(
                f"{len(failed)} fit(s) failed their MCMC diagnostics (see {diag_path}); "
                "rerun with --accept-diagnostics to accept them",
                file=sys.stderr,
            )
            return 3
    return 0


def _figures(fitted: dict, targets: list[str], fig_dir: Path, transforms) -> None:
    from scrppl.plotting.models import (
        plot_fit_forest,
        plot_fit_trace,
        plot_viewpoint_functions,
        save_figure,
    )

    for (det, tgt), (gauss, hier, _, transform) in fitted.items():
        if tgt not in _figure_targets(targets):
            continue
        number = "fig3" if transforms.default_transform(det) == "anscombe" else "fig2"
        scale = "" if transform == "identity" else f" ({transform} scale)"
        fig = plot_viewpoint_functions(
            [(f"{det} / {tgt}", hier, gauss)], radial_label=f"response{scale}"
        )
        save_figure(fig, fig_dir / f"{number}-{det}-{tgt}.png")
    if fitted:
        (det, tgt), (_, _, tree, _) = next(iter(fitted.items()))
        names = [
            n
            for n in ("alpha", "eta", "sigma_class", "instance_sd", "category_sd")
            if n in tree["posterior"].data_vars
        ]
        save_figure(plot_fit_trace(tree, names), fig_dir / f"trace-{det}-{tgt}.png")
        save_figure(plot_fit_forest(tree, names), fig_dir / f"forest-{det}-{tgt}.png")
