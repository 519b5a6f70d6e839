"""``scrppl detect``: train the detectors, score the dataset, write the response table and figures.

The dataset is the one at ``--root`` (:func:`scrppl.datasets.open_dataset`): the synthetic cache of
``--profile`` and ``--seed`` by default, or any scrppl dataset folder or copy of Savarese et al.'s 3D
Object Category dataset (then ``--seed`` also seeds its instance split).

Writes under ``--out``:

* ``detectors/<family>-<target>.npz`` -- trained detectors (reused when present with the same settings);
* ``responses.nc`` -- the response table (:mod:`scrppl.responses`); an interrupted run resumes from
  ``responses.partial.nc``; a table already written by the same detectors is kept;
* ``detectors/quality.json`` -- average precision per family x category on the test split and the
  azimuth dependence of every detector;
* ``figures/fig1-<target>.png`` -- the paper's Fig. 1 for one test instance of every target;
* ``figures/responses-<family>.png`` -- mean response by azimuth, positives vs negatives, on the
  held-out (fit and test) instances.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from scrppl.cli._common import add_common, open_dataset_of

DEFAULT_FAMILIES = "sift,bof,dpm"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``detect`` subcommand."""
    p = subparsers.add_parser(
        "detect",
        help="train detectors and score every image (the response table)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(p)
    p.add_argument(
        "--families",
        default=DEFAULT_FAMILIES,
        help=f"comma-separated detector families: sift, bof, dpm, hog (default: {DEFAULT_FAMILIES})",
    )
    p.add_argument(
        "--targets", default=None, help="comma-separated target categories (default: all)"
    )
    p.add_argument(
        "--views",
        choices=("all", "canonical"),
        default="all",
        help="training views: all views of the training instances, or the canonical few",
    )
    p.add_argument("--workers", type=int, default=2, help="processes used for scoring (default: 2)")
    p.add_argument(
        "--max-negatives",
        type=int,
        default=None,
        help="negative training images per target (default: the library's default)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=handler)


def _split_list(text: str | None) -> list[str] | None:
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise ValueError(f"empty list: {text!r}")
    return items


def handler(args: argparse.Namespace) -> int:
    """Run the detection stage; returns the exit status."""
    from scrppl.detectors import detector_class
    from scrppl.detectors.evaluation import quality_summary
    from scrppl.detectors.scoring import score_dataset
    from scrppl.detectors.train import DEFAULT_MAX_NEGATIVES, train_detectors

    dataset = open_dataset_of(args, progress=not args.quiet)
    families = _split_list(args.families)
    for fam in families:
        detector_class(fam)  # ValueError naming an unknown family
    targets = _split_list(args.targets) or dataset.categories
    unknown = [t for t in targets if t not in dataset.categories]
    if unknown:
        raise ValueError(f"unknown category {unknown[0]!r}; the dataset has {dataset.categories}")
    out = Path(args.out)
    progress = not args.quiet
    max_neg = DEFAULT_MAX_NEGATIVES if args.max_negatives is None else args.max_negatives

    t0 = time.perf_counter()
    detectors = train_detectors(
        dataset,
        families,
        targets,
        views=args.views,
        seed=args.seed,
        out_dir=out,
        progress=progress,
        max_negatives=max_neg,
    )
    t1 = time.perf_counter()
    table = score_dataset(
        dataset, detectors, path=out / "responses.nc", progress=progress, workers=args.workers
    )
    t2 = time.perf_counter()
    quality = quality_summary(table, "test")
    quality.update(
        dataset=str(dataset.name),
        views=args.views,
        seed=args.seed,
        families=families,
        targets=targets,
        seconds={"training": round(t1 - t0, 1), "scoring": round(t2 - t1, 1)},
    )
    qpath = out / "detectors" / "quality.json"
    from scrppl._io import atomic_path

    with atomic_path(qpath) as tmp:
        tmp.write_text(json.dumps(quality, indent=2, sort_keys=True))
    if not args.no_figures:
        write_figures(dataset, detectors, table, out / "figures")
    print(f"response table: {out / 'responses.nc'}")
    for fam in families:
        print(f"  {fam}: mean AP (test) = {quality['mean_average_precision'][fam]}")
    return 0


def fig1_threshold(table, family: str, target: str) -> float:
    """Fig. 1's detection threshold: the 95th percentile of the detector's negative test responses."""
    import numpy as np

    s = table["score"].sel(detector=family, target=target)
    neg = s.where((table["category"] != target) & (table["split"] == "test")).values
    neg = neg[np.isfinite(neg)]
    return float(np.quantile(neg, 0.95)) if neg.size else float("nan")


def write_figures(dataset, detectors, table, folder: Path) -> list[Path]:
    """Fig. 1 for one test instance per target, and the mean-by-azimuth summary per family."""
    import matplotlib.pyplot as plt
    import numpy as np

    from scrppl._io import atomic_path
    from scrppl.plotting.detectors import plot_mean_response_by_azimuth, plot_response_over_azimuth

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    families = list(detectors)
    fam = "dpm" if "dpm" in families else families[0]
    grid = dataset.grid
    e, s = grid.n_elevation // 2, grid.n_scale // 2
    for target, det in detectors[fam].items():
        rows = dataset.select(category=target, split="test", elevation=e, scale=s)
        if rows.empty:
            continue
        instance = int(rows["instance"].min())
        images, dets, resp, boxes = [], [], [], []
        for a in range(grid.n_azimuth):
            sel = rows[(rows["instance"] == instance) & (rows["azimuth"] == a)]
            if sel.empty:
                images.append(None)
                dets.append([])
                resp.append(np.nan)
                boxes.append(None)
                continue
            row = sel.iloc[0]
            img, box = dataset.load_image(row), dataset.bbox(row)
            images.append(img)
            boxes.append(box)
            dets.append(det.detect(img, box))
            resp.append(
                float(
                    table["score"].sel(
                        detector=fam,
                        target=target,
                        category=target,
                        instance=instance,
                        azimuth=a,
                        elevation=e,
                        scale=s,
                    )
                )
            )
        thr = fig1_threshold(table, fam, target)
        fig = plot_response_over_azimuth(
            images,
            np.asarray(resp),
            dets,
            azimuth_degrees=grid.azimuth_degrees,
            threshold=thr if np.isfinite(thr) else None,
            object_boxes=boxes,
            title=f"{fam} for {target!r}: test instance {instance} (e={e}, s={s})",
            detector_name=fam,
        )
        path = folder / f"fig1-{target}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
        written.append(path)
    for family in families:
        fig = plot_mean_response_by_azimuth(table, family, split=("fit", "test"))
        path = folder / f"responses-{family}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
