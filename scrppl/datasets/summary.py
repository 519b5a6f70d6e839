"""Summaries of a multiview dataset: what ``scrppl dataset info`` and ``make`` print.

* :func:`describe` -- :meth:`MultiviewDataset.summary` with per-category counts;
* :func:`format_summary` -- the same as readable text;
* :func:`check_generation_root` -- refuse to generate the synthetic dataset over another dataset.
"""

from __future__ import annotations

from pathlib import Path

from scrppl.datasets.core import MultiviewDataset
from scrppl.datasets.folders import dataset_layout

__all__ = ["describe", "format_summary", "check_generation_root"]


def describe(dataset: MultiviewDataset) -> dict:
    """:meth:`MultiviewDataset.summary` plus ``per_category``: instances, images and missing views of each.

    The per-category counts show at a glance which categories lack views (e.g. a Savarese category
    photographed from two heights only).
    """
    summary = dataset.summary()
    per_category = {}
    for c, g in dataset.index.groupby("category", sort=True):
        n_inst = int(g["instance"].nunique())
        per_category[str(c)] = {
            "instances": n_inst,
            "images": int(len(g)),
            "missing_views": int(n_inst * dataset.grid.n_views - len(g)),
        }
    summary["per_category"] = per_category
    return summary


def format_summary(summary: dict) -> str:
    """Readable text for :func:`describe` (or :meth:`MultiviewDataset.summary`) output."""
    grid = summary["grid"]
    els = ", ".join(f"{e:g}" for e in grid["elevations"])
    scs = ", ".join(f"{s:g}" for s in grid["scales"])
    counts = summary["split_counts"]
    per_category = summary.get("per_category", {})
    lines = [
        f"{summary['name']} dataset at {summary['root']}",
        f"  {summary['n_categories']} categories, {summary['instances']} instances, "
        f"{summary['images']} images ({summary['missing_views']} missing views)",
        f"  grid: {summary['azimuths']} azimuths x {summary['elevations']} elevations ({els} deg) "
        f"x {summary['scales']} scales ({scs})",
        "  instances per split: " + ", ".join(f"{s} {n}" for s, n in counts.items()),
        "",
        f"  {'category':<12} {'images':>7} {'missing':>8}   instance ids: "
        + " ".join(f"{s:<10}" for s in counts),
    ]
    for c in summary["categories"]:
        n = per_category.get(c, {})
        ids = [",".join(str(i) for i in summary["splits"][s].get(c, [])) or "-" for s in counts]
        lines.append(
            f"  {c:<12} {n.get('images', '?'):>7} {n.get('missing_views', '?'):>8}   "
            + " " * len("instance ids: ")
            + " ".join(f"{x:<10}" for x in ids)
        )
    return "\n".join(line.rstrip() for line in lines)


def check_generation_root(root: str | Path) -> None:
    """Refuse a ``root`` that holds another dataset than the synthetic one (before generating into it).

    Raises
    ------
    ValueError
        If ``root`` holds a copy of the Savarese dataset or a saved index of another source
        (:func:`~scrppl.datasets.dataset_layout`), saying how to use that dataset instead.
    """
    layout = dataset_layout(root)
    if layout in ("savarese", "index"):
        what = "a copy of the Savarese dataset" if layout == "savarese" else "a saved dataset index"
        raise ValueError(
            f"{root} holds {what}, not a synthetic dataset: `scrppl dataset make` only generates the "
            f"synthetic dataset. Use that dataset as it is (`scrppl dataset info --root {root}`, "
            f"`scrppl reproduce --root {root}`), or choose another --root to generate into"
        )
