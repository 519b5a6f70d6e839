"""Figures of a multiview dataset: contact sheets, the view sphere, single images with mask and box.

These show what the viewpoint problem of Meger et al. (2010, Sec. III) looks like: the same object
changes appearance with azimuth, elevation and distance, and a detector's response follows.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

__all__ = [
    "contact_sheet",
    "view_sphere",
    "show_image",
    "show_images",
    "sheet_instances",
    "camera_positions",
]


def sheet_instances(
    dataset: Any, instance: int | Mapping[str, int] | None = None
) -> dict[str, int]:
    """The instance shown for each category of a contact sheet.

    Parameters
    ----------
    dataset
        A :class:`~scrppl.datasets.core.MultiviewDataset`.
    instance
        ``None``: the first (lowest-numbered) ``test`` instance of each category, or its first instance
        if it has no test instance; an ``int``: that instance in every category; a mapping: one
        instance per category (categories not in the mapping are left out).

    Returns
    -------
    ``{category: instance}`` in category order.
    """
    inst = dataset.instances
    if isinstance(instance, Mapping):
        chosen = {str(c): int(i) for c, i in instance.items()}
    elif instance is not None:
        chosen = {c: int(instance) for c in dataset.categories}
    else:
        chosen = {}
        for c, g in inst.groupby("category", sort=True):
            test = g.loc[g["split"] == "test", "instance"]
            chosen[str(c)] = int(test.min() if len(test) else g["instance"].min())
    for c, i in chosen.items():
        if not ((inst["category"] == c) & (inst["instance"] == i)).any():
            raise KeyError(f"the dataset has no instance {i} of category {c!r}")
    return chosen


def show_image(
    dataset: Any,
    row: pd.Series,
    ax: Axes | None = None,
    box: bool = True,
    mask: bool = True,
    *,
    title: bool = True,
    window: float | None = None,
) -> Axes:
    """Draw one image of the dataset, optionally with its object mask, bounding box and window.

    Parameters
    ----------
    dataset
        A :class:`~scrppl.datasets.core.MultiviewDataset`.
    row
        One row of ``dataset.index``.
    ax
        Axes to draw into (default: a new figure).
    box
        Draw the object's bounding box (``dataset.bbox(row)``).
    mask
        Tint the object mask.
    title
        Put ``category #instance`` and the view ``(A, H, S)`` (1-based, as in file names) on top.
    window
        If given, also draw (dashed, cyan) the proto-object window that the detectors score: the box
        enlarged by this margin, as cut by :func:`scrppl.detectors.proto_object_window`.

    Returns
    -------
    The axes.
    """
    if ax is None:
        _, ax = plt.subplots(figsize=(4, 3))
    image = dataset.load_image(row)
    if mask and row["mask"]:
        m = dataset.load_mask(row)
        tint = image.astype(float)
        tint[m] = 0.6 * tint[m] + 0.4 * np.array([255.0, 64.0, 64.0])
        image = tint.astype(np.uint8)
    ax.imshow(image)
    if box:
        x0, y0, x1, y1 = dataset.bbox(row)
        ax.add_patch(
            Rectangle(
                (x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor="yellow", lw=1.5
            )
        )
    if window is not None:
        from scrppl.detectors.base import proto_object_window

        crop, (wx0, wy0) = proto_object_window(image, dataset.bbox(row), margin=window)
        ax.add_patch(
            Rectangle(
                (wx0 - 0.5, wy0 - 0.5),
                crop.shape[1],
                crop.shape[0],
                fill=False,
                edgecolor="cyan",
                lw=1.5,
                ls="--",
            )
        )
    if title:
        ax.set_title(
            f"{row['category']} #{int(row['instance'])}  A{int(row['azimuth']) + 1} "
            f"H{int(row['elevation']) + 1} S{int(row['scale']) + 1}",
            fontsize=9,
        )
    ax.set_xticks([])
    ax.set_yticks([])
    return ax


def show_images(
    dataset: Any,
    rows: pd.DataFrame,
    *,
    ncols: int | None = None,
    width: float = 2.4,
    fig: Figure | None = None,
    **options: Any,
) -> Figure:
    """Several images of the dataset side by side, each drawn by :func:`show_image`.

    Parameters
    ----------
    dataset
        A :class:`~scrppl.datasets.core.MultiviewDataset`.
    rows
        Rows of ``dataset.index`` (e.g. from ``dataset.select(...)``), shown in order.
    ncols
        Images per row of the figure (default: all in one row).
    width
        Width of one panel in inches.
    fig
        Figure to draw into (default: a new one).
    **options
        Passed to :func:`show_image` (``box``, ``mask``, ``title``, ``window``).

    Returns
    -------
    The figure, with one axes per row of ``rows`` (unused cells of the last figure row are hidden).
    """
    if rows.empty:
        raise ValueError("no images to show: the selection of rows is empty")
    n = len(rows)
    ncols = n if ncols is None else max(1, min(int(ncols), n))
    nrows = -(-n // ncols)
    aspect = _aspect(dataset, [rows])
    if fig is None:
        fig = plt.figure(
            figsize=(width * ncols, (width * aspect + 0.35) * nrows), layout="constrained"
        )
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax, (_, row) in zip(axes, rows.iterrows(), strict=False):
        show_image(dataset, row, ax=ax, **options)
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig


def _thumbnail(ax: Axes, dataset: Any, rows: pd.DataFrame) -> None:
    """Show the image of the single row in ``rows`` (or a 'missing' placeholder) without ticks."""
    ax.set_xticks([])
    ax.set_yticks([])
    if rows.empty:
        ax.set_facecolor("0.92")
        ax.text(
            0.5,
            0.5,
            "missing",
            ha="center",
            va="center",
            fontsize=7,
            color="0.4",
            transform=ax.transAxes,
        )
        return
    ax.imshow(dataset.load_image(rows.iloc[0]))


def contact_sheet(
    dataset: Any,
    *,
    instance: int | Mapping[str, int] | None = None,
    elevation: int = 0,
    scale: int = 0,
    categories: list[str] | None = None,
    thumb_width: float = 1.3,
    fig: Figure | None = None,
) -> Figure:
    """A grid of images: one instance per category (rows) seen from every azimuth (columns).

    Column ``a`` shows relative azimuth ``a`` (bin 0 = the object's front, counter-clockwise in
    ``360 / A`` degree steps), so reading a row left to right walks once around the object.

    Parameters
    ----------
    dataset
        A :class:`~scrppl.datasets.core.MultiviewDataset`.
    instance
        Which instance per category, see :func:`sheet_instances` (default: its first test instance).
    elevation, scale
        The view height and distance indices shared by every image.
    categories
        Categories to show, in order (default: all those chosen by ``instance``).
    thumb_width
        Width of one thumbnail in inches.
    fig
        Figure to draw into (default: a new one).

    Returns
    -------
    The figure, with ``C x A`` image axes (``C`` categories, ``A`` azimuths); missing views are grey.
    """
    dataset.grid.check(0, elevation, scale)
    chosen = sheet_instances(dataset, instance)
    if categories is not None:
        missing = [c for c in categories if c not in chosen]
        if missing:
            raise KeyError(f"categories {missing} not in the dataset (or not chosen by instance)")
        chosen = {c: chosen[c] for c in categories}
    n_az = dataset.grid.n_azimuth
    rows = [
        dataset.select(category=c, instance=i, elevation=elevation, scale=scale)
        for c, i in chosen.items()
    ]
    aspect = _aspect(dataset, rows)
    if fig is None:
        fig = plt.figure(
            figsize=(thumb_width * n_az + 1.2, thumb_width * aspect * len(chosen) + 0.6),
            layout="constrained",
        )
    axes = fig.subplots(len(chosen), n_az, squeeze=False)
    degrees = dataset.grid.azimuth_degrees
    for r, ((category, inst), cat_rows) in enumerate(zip(chosen.items(), rows, strict=True)):
        for a in range(n_az):
            ax = axes[r, a]
            _thumbnail(ax, dataset, cat_rows[cat_rows["azimuth"] == a])
            if r == 0:
                ax.set_title(f"A{a + 1}  {degrees[a]:.0f}°", fontsize=9)
            if a == 0:
                ax.set_ylabel(f"{category}\n#{inst}", fontsize=9)
    el, sc = dataset.grid.elevations[elevation], dataset.grid.scales[scale]
    fig.suptitle(
        f"{dataset.name}: one instance per category from {n_az} azimuths "
        f"(H{elevation + 1} = {el:g}°, S{scale + 1} = {sc:g})",
        fontsize=11,
    )
    return fig


def _aspect(dataset: Any, rows: list[pd.DataFrame]) -> float:
    """Height / width of the first image found (3/4 if none)."""
    for r in rows:
        if not r.empty:
            img = dataset.load_image(r.iloc[0])
            return img.shape[0] / img.shape[1]
    return 0.75


def camera_positions(grid: Any, base_distance: float = 1.0) -> np.ndarray:
    """Camera centres of every view of ``grid`` on the view sphere, shape ``(A, E, S, 3)``.

    The convention of the synthetic dataset: view ``(a, e, s)`` has the camera at
    ``d_s (cos(el_e) cos(phi_a), cos(el_e) sin(phi_a), sin(el_e))`` with ``phi_a = a * 360 / A``
    degrees counter-clockwise from the object's front (+x) and ``d_s = base_distance * scales[s]``.
    """
    phi = np.deg2rad(grid.azimuth_degrees)[:, None, None]
    el = np.deg2rad(np.asarray(grid.elevations))[None, :, None]
    d = base_distance * np.asarray(grid.scales)[None, None, :]
    xyz = np.stack(
        np.broadcast_arrays(
            d * np.cos(el) * np.cos(phi), d * np.cos(el) * np.sin(phi), d * np.sin(el)
        ),
        axis=-1,
    )
    return xyz


def _first_gap(have: np.ndarray) -> tuple[int, int]:
    """The first ``(e, s)`` pair with a missing azimuth (for a single 'missing view' legend entry)."""
    e, s = np.argwhere(~have.all(axis=0))[0]
    return int(e), int(s)


def view_sphere(
    dataset: Any,
    category: str,
    instance: int,
    *,
    thumb_width: float = 0.95,
    fig: Figure | None = None,
) -> Figure:
    """The view sphere around one object: every camera position in 3-D beside all its images.

    Left: the ``A x E x S`` camera centres (:func:`camera_positions`) around the object at the origin,
    coloured by height and sized by distance, with the azimuth labels ``A1..A8`` (``A1`` = the object's
    front, +x; counter-clockwise seen from above). Right: every image of the instance, one column per
    azimuth and one row per (height, scale) pair, so that a column is one direction seen from all
    heights and distances and a row walks around the object.

    Parameters
    ----------
    dataset
        A :class:`~scrppl.datasets.core.MultiviewDataset`.
    category, instance
        The object to show.
    thumb_width
        Width of one thumbnail in inches.
    fig
        Figure to draw into (default: a new one).

    Returns
    -------
    The figure: one 3-D axes and ``(E * S) x A`` image axes; views the instance lacks are grey.
    """
    grid = dataset.grid
    rows = dataset.select(category=category, instance=instance)
    if rows.empty:
        raise KeyError(f"the dataset has no instance {instance} of category {category!r}")
    n_az, n_el, n_sc = grid.shape
    aspect = _aspect(dataset, [rows])
    n_rows = n_el * n_sc
    if fig is None:
        fig = plt.figure(
            figsize=(4.8 + thumb_width * n_az, max(4.2, thumb_width * aspect * n_rows + 0.8)),
            layout="constrained",
        )
    left, right = fig.subfigures(1, 2, width_ratios=[4.8, thumb_width * n_az])

    ax3 = left.add_subplot(projection="3d")
    xyz = camera_positions(grid)
    colors = plt.get_cmap("viridis")(np.linspace(0.1, 0.85, n_el))
    have = np.zeros(grid.shape, dtype=bool)
    have[rows["azimuth"].to_numpy(), rows["elevation"].to_numpy(), rows["scale"].to_numpy()] = True
    for e in range(n_el):
        for s in range(n_sc):
            p = xyz[:, e, s]
            ok = have[:, e, s]
            label = f"H{e + 1} {grid.elevations[e]:g}°" if s == 0 else None
            ax3.scatter(
                p[ok, 0],
                p[ok, 1],
                p[ok, 2],
                color=colors[e],
                s=12 + 10 * s,
                label=label,
                depthshade=False,
            )
            if (~ok).any():
                ax3.scatter(
                    p[~ok, 0],
                    p[~ok, 1],
                    p[~ok, 2],
                    color="0.6",
                    marker="x",
                    s=12 + 10 * s,
                    label="missing view" if not have.all() and (e, s) == _first_gap(have) else None,
                    depthshade=False,
                )
            ring = np.concatenate([p, p[:1]])
            ax3.plot(ring[:, 0], ring[:, 1], ring[:, 2], color=colors[e], lw=0.5, alpha=0.5)
    r_max = float(np.abs(xyz).max())
    for a in range(n_az):
        p = xyz[a, -1, -1] * 1.12  # beside the highest, farthest camera: clear of the axis labels
        ax3.text(p[0], p[1], p[2], f"A{a + 1}", fontsize=8, ha="center", va="bottom")
    ax3.quiver(0, 0, 0, 0.6 * r_max, 0, 0, color="crimson", lw=1.5)
    ax3.text(0.7 * r_max, 0, 0.05 * r_max, "front", color="crimson", fontsize=8)
    ax3.scatter([0], [0], [0], color="k", marker="s", s=30)
    ax3.set_xlim(-r_max, r_max)
    ax3.set_ylim(-r_max, r_max)
    ax3.set_zlim(0, r_max)
    ax3.set_box_aspect((2, 2, 1))
    for axis, label in ((ax3.xaxis, "x (front)"), (ax3.yaxis, "y (left)"), (ax3.zaxis, "z (up)")):
        axis.set_ticklabels([])  # distances are in object-size units: the geometry is what matters
        axis.set_label_text(label, fontsize=8)
        axis.labelpad = -10
    ax3.view_init(elev=28, azim=-60)
    ax3.legend(loc="upper left", fontsize=7, frameon=False)
    left.suptitle(f"{grid.n_views} camera positions", fontsize=10)

    axes = right.subplots(n_rows, n_az, squeeze=False)
    degrees = grid.azimuth_degrees
    for e in range(n_el):
        for s in range(n_sc):
            r = e * n_sc + s
            for a in range(n_az):
                ax = axes[r, a]
                sel = rows[(rows["azimuth"] == a) & (rows["elevation"] == e) & (rows["scale"] == s)]
                _thumbnail(ax, dataset, sel)
                if r == 0:
                    ax.set_title(f"A{a + 1} {degrees[a]:.0f}°", fontsize=8)
                if a == 0:
                    ax.set_ylabel(f"H{e + 1} S{s + 1}", fontsize=8)
    right.suptitle(
        f"{category} #{instance}: every view (columns: azimuth; rows: height, scale)", fontsize=10
    )
    return fig
