"""Generate the synthetic multiview dataset: every instance of every category from every view.

:func:`make_synthetic` renders ``categories x n_instances x A x E x S`` images into a folder laid out
like Savarese et al.'s 3D Object Category dataset::

    <root>/<category>/<category>_<n>/<category>_<n>_A<a+1>_H<e+1>_S<s+1>.jpg    (image)
    <root>/<category>/<category>_<n>/mask/<same stem>.png                     (mask, 0/255)

with ``n = instance + 1`` (1-based, as in the Savarese folders), and writes the index (``index.csv``,
``dataset.json``) of a `scrppl.datasets.core.MultiviewDataset` with the bounding boxes.

Determinism. Every random choice is drawn from a generator seeded by the image's identity --
``numpy.random.default_rng([seed, crc32(category), instance, ...])`` for the instance (its shape seed,
floor, light, floor fade) and ``[..., a, e, s, ...]`` for the view (camera jitter, background, camera
development, noise) -- never from a shared stream. So the same seed gives identical pixels whether the
dataset is rendered in one go, by any number of worker processes, or one deleted image at a time.

Resumption. Each image and mask is written atomically (`scrppl._io.atomic_path`); a view whose two
files exist is skipped, and its bounding box is recomputed from the mask, so an interrupted run picks up
where it stopped. The index is written last. ``synthetic.json`` records the configuration and seed at
the start, so a folder is never completed with a different configuration.

Splits. Instances are assigned to ``train``/``fit``/``test`` by `scrppl.datasets.core.assign_splits`
*before* rendering, because the background pool of an image depends on its instance's split
(`scrppl.datasets.synthetic.backgrounds`): training images and held-out images never share a
background.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scrppl._io import atomic_path
from scrppl.datasets.core import (
    DEFAULT_SPLIT_PROPORTIONS,
    INDEX_FILE,
    META_FILE,
    MultiviewDataset,
    assign_splits,
    bbox_from_mask,
)
from scrppl.views import ViewGrid

__all__ = [
    "SyntheticConfig",
    "make_synthetic",
    "load_or_make",
    "render_view",
    "instance_style",
    "view_style",
    "image_stem",
    "InstanceStyle",
    "ViewStyle",
    "RENDER_VERSION",
    "PROFILES",
]

#: Bumped whenever the renderer's output changes, so stale folders are recognised.
RENDER_VERSION = 1
#: Profiles of :meth:`SyntheticConfig.for_profile`.
PROFILES = ("full", "quick", "tiny")
#: Provenance file written at the start of a generation.
PROVENANCE_FILE = "synthetic.json"


def _all_categories() -> tuple[str, ...]:
    from scrppl.datasets.synthetic.shapes import CATEGORIES

    return tuple(CATEGORIES)


@dataclass(frozen=True)
class SyntheticConfig:
    """What to render.

    Parameters
    ----------
    categories
        Category names (a subset of `scrppl.datasets.synthetic.shapes.CATEGORIES`), no repeats.
    n_instances
        Instances per category.
    grid
        The view grid (azimuths, elevations in degrees, scales as distance multipliers).
    width, height
        Image size in pixels.
    split_proportions
        Shares of ``(train, fit, test)`` instances per category (`scrppl.datasets.core.assign_splits`).
    jitter
        Strength of the nuisance variation: camera pose within its view bin, lighting, floor, camera
        development and noise (1: the default dataset; 0: exact grid views, a neutral camera).
    fill
        Share of the half-frame the object spans in its tightest view at scale 1.
    """

    categories: tuple[str, ...] = field(default_factory=_all_categories)
    n_instances: int = 10
    grid: ViewGrid = field(default_factory=ViewGrid)
    width: int = 320
    height: int = 240
    split_proportions: tuple[float, float, float] = DEFAULT_SPLIT_PROPORTIONS
    jitter: float = 1.0
    fill: float = 0.9

    def __post_init__(self) -> None:
        cats = self.categories
        if isinstance(cats, str) or not isinstance(cats, Sequence):
            raise ValueError(f"categories must be a sequence of names, got {cats!r}")
        object.__setattr__(self, "categories", tuple(str(c) for c in cats))
        known = _all_categories()
        if not self.categories:
            raise ValueError("a synthetic dataset needs at least one category")
        unknown = [c for c in self.categories if c not in known]
        if unknown:
            raise ValueError(
                f"unknown categories {unknown}; expected names from {', '.join(known)}"
            )
        if len(set(self.categories)) != len(self.categories):
            raise ValueError(f"categories repeat: {list(self.categories)}")
        if int(self.n_instances) != self.n_instances or self.n_instances < 1:
            raise ValueError(f"n_instances must be a positive integer, got {self.n_instances!r}")
        object.__setattr__(self, "n_instances", int(self.n_instances))
        if not isinstance(self.grid, ViewGrid):
            raise ValueError(
                f"grid must be a scrppl.views.ViewGrid, got {type(self.grid).__name__}"
            )
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or not 32 <= v <= 4096:
                raise ValueError(
                    f"{name} must be an integer number of pixels in 32..4096, got {v!r}"
                )
            object.__setattr__(self, name, int(v))
        if not all(0.0 < el < 90.0 for el in self.grid.elevations):
            raise ValueError(
                f"elevations must lie strictly between 0 and 90 degrees, got {self.grid.elevations}"
            )
        if not all(s > 0 for s in self.grid.scales):
            raise ValueError(
                f"scales must be positive distance multipliers, got {self.grid.scales}"
            )
        p = tuple(float(x) for x in self.split_proportions)
        if len(p) != 3 or min(p) < 0 or not np.isclose(sum(p), 1.0):
            raise ValueError(
                f"split_proportions must be three non-negative shares summing to 1, got {self.split_proportions}"
            )
        object.__setattr__(self, "split_proportions", p)
        if not 0.0 <= float(self.jitter) <= 2.0:
            raise ValueError(f"jitter must lie in [0, 2], got {self.jitter!r}")
        if not 0.1 <= float(self.fill) <= 1.0:
            raise ValueError(f"fill must lie in [0.1, 1], got {self.fill!r}")
        object.__setattr__(self, "jitter", float(self.jitter))
        object.__setattr__(self, "fill", float(self.fill))

    @property
    def n_images(self) -> int:
        """Number of images: categories x instances x views."""
        return len(self.categories) * self.n_instances * self.grid.n_views

    @classmethod
    def for_profile(cls, name: str) -> SyntheticConfig:
        """A named configuration.

        * ``"full"``: all ten categories x 10 instances x the Savarese grid (8 x 3 x 3) = 7,200 images.
        * ``"quick"``: four categories x 6 instances x 8 azimuths at one height and scale (192 images,
          well under a minute) -- a pipeline that runs end to end in a few minutes.
        * ``"tiny"``: three categories x 2 instances x 8 azimuths at one height and scale (48 images,
          seconds) -- for tests.
        """
        if name == "full":
            return cls()
        if name == "quick":
            return cls(
                categories=("bicycle", "car", "monitor", "shoe"),
                n_instances=6,
                grid=ViewGrid(8, (25.0,), (1.4,)),
            )
        if name == "tiny":
            return cls(
                categories=("bicycle", "cellphone", "mouse"),
                n_instances=2,
                grid=ViewGrid(8, (25.0,), (1.0,)),
            )
        raise ValueError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable description (inverse: :meth:`from_dict`)."""
        return {
            "categories": list(self.categories),
            "n_instances": self.n_instances,
            "grid": self.grid.to_dict(),
            "width": self.width,
            "height": self.height,
            "split_proportions": list(self.split_proportions),
            "jitter": self.jitter,
            "fill": self.fill,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SyntheticConfig:
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        d["grid"] = ViewGrid.from_dict(d["grid"])
        d["categories"] = tuple(d["categories"])
        d["split_proportions"] = tuple(d["split_proportions"])
        return cls(**d)


# -- per-instance and per-view randomness ----------------------------------------------------------
def _category_key(category: str) -> int:
    return zlib.crc32(category.encode())


class InstanceStyle(NamedTuple):
    """Everything random about one instance's photo session (drawn by :func:`instance_style`)."""

    shape_seed: int
    floor_seed: int
    light_direction: np.ndarray
    light_intensity: float
    light_kelvin: float
    ambient: float
    fade: tuple[float, float]


class ViewStyle(NamedTuple):
    """Everything random about one image (drawn by :func:`view_style`)."""

    camera_jitter: tuple[float, float, float, float, float, float]
    light_gain: float
    background: Any  # backgrounds.BackgroundChoice
    development: Any  # compose.Development
    noise_seed: int


def instance_style(seed: int, category: str, instance: int, jitter: float = 1.0) -> InstanceStyle:
    """The random choices of one instance, from ``default_rng([seed, crc32(category), instance, 1])``."""
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), 1])
    shape_seed = int(rng.integers(2**31))
    floor_seed = int(rng.integers(2**31))
    k = float(jitter)
    az = rng.uniform(0.0, 2.0 * np.pi)
    el = np.deg2rad(55.0 + k * rng.uniform(-15.0, 15.0))
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    intensity = float(1.15 * np.exp(k * rng.uniform(-0.12, 0.12)))
    kelvin = float(5500.0 + k * rng.uniform(-2000.0, 2000.0))
    ambient = float(0.32 + k * rng.uniform(-0.06, 0.06))
    r_in = float(1.9 + k * rng.uniform(-0.3, 0.4))
    fade = (r_in, r_in + float(1.6 + k * rng.uniform(-0.4, 0.6)))
    return InstanceStyle(shape_seed, floor_seed, direction, intensity, kelvin, ambient, fade)


def view_style(
    seed: int,
    category: str,
    instance: int,
    view: tuple[int, int, int],
    split: str,
    config: SyntheticConfig,
) -> ViewStyle:
    """The random choices of one image, from ``default_rng([seed, crc32(category), instance, a, e, s, 2])``."""
    from scrppl.datasets.synthetic.backgrounds import draw_background, pool_of_split
    from scrppl.datasets.synthetic.compose import draw_development

    a, e, s = (int(v) for v in view)
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), a, e, s, 2])
    k = config.jitter
    cam = (
        k * rng.uniform(-4.0, 4.0),  # azimuth, degrees (bins are 45 degrees wide)
        k * rng.uniform(-2.5, 2.5),  # elevation, degrees
        k * rng.uniform(-0.04, 0.04),  # log distance
        k * rng.uniform(-0.04, 0.04),  # look-at shift, in object radii
        k * rng.uniform(-0.04, 0.04),
        k * rng.uniform(-2.0, 2.0),  # roll, degrees
    )
    light_gain = float(np.exp(k * rng.uniform(-0.08, 0.08)))
    background = draw_background(rng, pool_of_split(split), int(seed), config.width, config.height)
    development = draw_development(rng, k)
    noise_seed = int(rng.integers(2**31))
    return ViewStyle(tuple(float(c) for c in cam), light_gain, background, development, noise_seed)


def image_stem(category: str, instance: int, view: tuple[int, int, int]) -> str:
    """Savarese-style file stem ``<category>_<instance+1>_A<a+1>_H<e+1>_S<s+1>``."""
    a, e, s = view
    return f"{category}_{instance + 1}_A{a + 1}_H{e + 1}_S{s + 1}"


def _relpaths(category: str, instance: int, view: tuple[int, int, int]) -> tuple[str, str]:
    folder = f"{category}/{category}_{instance + 1}"
    stem = image_stem(category, instance, view)
    return f"{folder}/{stem}.jpg", f"{folder}/mask/{stem}.png"


# -- rendering one instance (in a worker process or in-process) ------------------------------------
_RENDERER: dict[tuple[int, int], Any] = {}


def _renderer(width: int, height: int):
    """The process's reusable :class:`~scrppl.datasets.synthetic.render.SceneRenderer` of this size."""
    from scrppl.datasets.synthetic.render import SceneRenderer

    key = (width, height)
    if key not in _RENDERER:
        _RENDERER[key] = SceneRenderer(width, height)
    return _RENDERER[key]


class _Instance:
    """A loaded instance: the renderer set up with its shape, floor and light."""

    def __init__(self, config: SyntheticConfig, seed: int, category: str, instance: int):
        from scrppl.datasets.synthetic.floors import make_floor
        from scrppl.datasets.synthetic.render import base_distance
        from scrppl.datasets.synthetic.shapes import build_instance

        self.style = instance_style(seed, category, instance, config.jitter)
        self.renderer = _renderer(config.width, config.height)
        self.renderer.set_instance(build_instance(category, self.style.shape_seed))
        self.renderer.set_floor(make_floor(self.style.floor_seed))
        self.distance = base_distance(
            self.renderer.vertices,
            config.grid,
            aspect=config.width / config.height,
            fill=config.fill,
        )


def render_view(
    config: SyntheticConfig,
    seed: int,
    category: str,
    instance: int,
    view: tuple[int, int, int],
    split: str,
    *,
    _loaded: _Instance | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Render one image of the dataset, exactly as :func:`make_synthetic` writes it (before JPEG).

    Parameters
    ----------
    config, seed
        The dataset's configuration and seed.
    category, instance
        Which object.
    view
        ``(a, e, s)`` view indices.
    split
        The instance's split (it picks the background pool).

    Returns
    -------
    image : (H, W, 3) uint8 RGB array
    mask : (H, W) bool array
        The object's pixels.
    jpeg_quality : int
        The JPEG quality the image is stored with.
    """
    from scrppl.datasets.synthetic.backgrounds import render_background
    from scrppl.datasets.synthetic.compose import composite, develop
    from scrppl.datasets.synthetic.render import Lighting, kelvin_to_rgb, view_camera

    loaded = _loaded or _Instance(config, seed, category, instance)
    st = loaded.style
    vs = view_style(seed, category, instance, view, split, config)
    r = loaded.renderer
    r.set_lighting(
        Lighting(
            direction=st.light_direction,
            intensity=st.light_intensity * vs.light_gain,
            color=kelvin_to_rgb(st.light_kelvin),
            ambient=st.ambient,
        )
    )
    camera = view_camera(
        config.grid,
        *view,
        distance=loaded.distance,
        height=r.object_height,
        radius=r.radius,
        jitter=vs.camera_jitter,
    )
    frame = r.render(camera)
    background = render_background(vs.background, config.width, config.height)
    # the farther the camera, the more floor it sees: widen the floor's fade with the distance
    widen = float(np.sqrt(config.grid.scales[view[2]] / min(config.grid.scales)))
    image = composite(frame, background, (st.fade[0] * widen, st.fade[1] * widen))
    image = develop(np.random.default_rng(vs.noise_seed), image, vs.development)
    return image, frame.object_mask, vs.development.jpeg_quality


class _Task(NamedTuple):
    config: dict
    seed: int
    root: str
    category: str
    instance: int
    split: str
    views: list[tuple[int, int, int]]


def _render_task(task: _Task) -> list[tuple[tuple[int, int, int], tuple[int, int, int, int]]]:
    """Render and write the missing views of one instance; returns their bounding boxes."""
    from scrppl.datasets.synthetic.compose import encode_jpeg, encode_png

    config = SyntheticConfig.from_dict(task.config)
    root = Path(task.root)
    loaded = _Instance(config, task.seed, task.category, task.instance)
    out = []
    for view in task.views:
        view = tuple(int(v) for v in view)
        image, mask, quality = render_view(
            config, task.seed, task.category, task.instance, view, task.split, _loaded=loaded
        )
        img_rel, mask_rel = _relpaths(task.category, task.instance, view)
        if not mask.any():
            raise RuntimeError(f"the object is not visible in {img_rel} (empty mask)")
        with atomic_path(root / img_rel) as tmp:
            tmp.write_bytes(encode_jpeg(image, quality))
        with atomic_path(root / mask_rel) as tmp:
            tmp.write_bytes(encode_png(mask))
        out.append((view, bbox_from_mask(mask)))
    return out


def _worker_init() -> None:
    # llvmpipe starts one rasteriser thread per core; with one worker process per core, one each is
    # faster (and the pixels do not depend on the thread count)
    os.environ.setdefault("LP_NUM_THREADS", "1")


# -- the generator ---------------------------------------------------------------------------------
def _provenance(config: SyntheticConfig, seed: int) -> dict[str, Any]:
    return {
        "generator": "scrppl.datasets.synthetic",
        "render_version": RENDER_VERSION,
        "seed": int(seed),
        "config": config.to_dict(),
    }


def _check_writable(root: Path) -> None:
    try:
        root.mkdir(parents=True, exist_ok=True)
        with atomic_path(root / ".write-test") as tmp:
            tmp.write_text("ok")
        (root / ".write-test").unlink()
    except OSError as err:
        raise RuntimeError(f"cannot write the synthetic dataset to {root}: {err}") from err


def _mask_box(path: Path) -> tuple[int, int, int, int]:
    import cv2

    m = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if m is None:
        raise ValueError(f"unreadable mask image: {path}")
    return bbox_from_mask(m > 127)


def make_synthetic(
    root: str | os.PathLike,
    config: SyntheticConfig,
    seed: int = 0,
    *,
    workers: int | None = None,
    progress: bool = True,
) -> MultiviewDataset:
    """Render the synthetic dataset into ``root`` (resuming), write its index and return it.

    If ``root`` already holds the complete dataset of this configuration and seed, it is just loaded.

    Parameters
    ----------
    root
        Output folder (created if needed).
    config
        What to render.
    seed
        Non-negative integer; the same seed gives identical images.
    workers
        Rendering processes (default: one per CPU core; 1 renders in this process). Each process keeps
        one off-screen render window for all its images.
    progress
        Show a progress bar over the images.

    Returns
    -------
    MultiviewDataset
        Named ``"synthetic"``; its ``meta`` records the configuration, seed and renderer version.

    Raises
    ------
    ValueError
        Bad seed or workers, or ``root`` holds a dataset of another configuration or seed.
    RuntimeError
        ``root`` cannot be written.
    """
    if not isinstance(config, SyntheticConfig):
        raise ValueError(f"config must be a SyntheticConfig, got {type(config).__name__}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    root = Path(root)
    meta = _provenance(config, seed)

    existing = _existing(root, meta)
    if existing is not None:
        return existing
    _check_writable(root)
    prov = root / PROVENANCE_FILE
    if prov.exists():
        try:
            old = json.loads(prov.read_text())
        except json.JSONDecodeError:
            old = None
        if old != meta:
            raise ValueError(
                f"{root} holds a partial synthetic dataset of another configuration, seed or renderer "
                f"version ({prov}); delete that folder or choose another root"
            )
    else:
        with atomic_path(prov) as tmp:
            tmp.write_text(json.dumps(meta, indent=2, sort_keys=True))

    splits = assign_splits(
        seed, {c: range(config.n_instances) for c in config.categories}, config.split_proportions
    )
    views = [tuple(int(x) for x in v) for v in config.grid.all_views()]
    boxes: dict[tuple[str, int, tuple[int, int, int]], tuple[int, int, int, int]] = {}
    tasks: list[_Task] = []
    for c in config.categories:
        for i in range(config.n_instances):
            todo = []
            for v in views:
                img_rel, mask_rel = _relpaths(c, i, v)
                if (root / img_rel).exists() and (root / mask_rel).exists():
                    boxes[(c, i, v)] = _mask_box(root / mask_rel)
                else:
                    todo.append(v)
            if todo:
                tasks.append(_Task(config.to_dict(), seed, str(root), c, i, splits[(c, i)], todo))

    n_todo = sum(len(t.views) for t in tasks)
    if n_todo:
        from tqdm.auto import tqdm

        n_workers = (os.cpu_count() or 1) if workers is None else int(workers)
        n_workers = max(1, min(n_workers, len(tasks)))
        with tqdm(
            total=n_todo, desc="rendering synthetic dataset", unit="img", disable=not progress
        ) as bar:
            for task, result in _run_tasks(tasks, n_workers):
                for view, box in result:
                    boxes[(task.category, task.instance, view)] = box
                bar.update(len(result))

    rows = []
    for c in config.categories:
        for i in range(config.n_instances):
            for v in views:
                img_rel, mask_rel = _relpaths(c, i, v)
                x0, y0, x1, y1 = boxes[(c, i, v)]
                rows.append(
                    {
                        "category": c,
                        "instance": i,
                        "azimuth": v[0],
                        "elevation": v[1],
                        "scale": v[2],
                        "split": splits[(c, i)],
                        "image": img_rel,
                        "mask": mask_rel,
                        "x0": x0,
                        "y0": y0,
                        "x1": x1,
                        "y1": y1,
                    }
                )
    import pandas as pd

    meta = {**meta, "split_seed": seed, "split_proportions": list(config.split_proportions)}
    dataset = MultiviewDataset(root, pd.DataFrame(rows), config.grid, "synthetic", meta)
    dataset.save()
    return dataset


def _run_tasks(tasks: list[_Task], n_workers: int):
    """Yield ``(task, result)`` as tasks finish, in this process or in a pool of spawned workers."""
    if n_workers == 1:
        for task in tasks:
            yield task, _render_task(task)
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    # spawn, not fork: the parent may hold threads (JAX, BLAS) and a forked VTK context is unsafe
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(n_workers, mp_context=ctx, initializer=_worker_init) as pool:
        futures = {pool.submit(_render_task, t): t for t in tasks}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        except BrokenProcessPool as err:
            raise RuntimeError(
                "a rendering worker process died. Workers are spawned, so a script that calls "
                "make_synthetic must do so under `if __name__ == '__main__':`; or pass workers=1 to "
                "render in this process"
            ) from err
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _existing(root: Path, meta: dict[str, Any]) -> MultiviewDataset | None:
    """The dataset at ``root`` if it is complete and was made with ``meta``; raise if it differs."""
    if not (root / META_FILE).exists() or not (root / INDEX_FILE).exists():
        return None
    try:
        saved = json.loads((root / META_FILE).read_text()).get("meta", {})
    except json.JSONDecodeError:
        return None
    mine = {k: saved.get(k) for k in meta}
    if mine != meta:
        raise ValueError(
            f"{root} holds a dataset made with another configuration, seed or renderer version "
            f"(its {META_FILE} says {json.dumps(mine, sort_keys=True)}); delete that folder or "
            "choose another root"
        )
    dataset = MultiviewDataset.load(root)
    cfg = SyntheticConfig.from_dict(meta["config"])
    if len(dataset) != cfg.n_images:
        return None
    for img, mask in zip(dataset.index["image"], dataset.index["mask"], strict=True):
        if not (root / img).exists() or not (root / mask).exists():
            return None
    return dataset


def load_or_make(
    root: str | os.PathLike, config: SyntheticConfig, seed: int = 0, **kw: Any
) -> MultiviewDataset:
    """Load the dataset at ``root`` if it is complete, else render what is missing (:func:`make_synthetic`)."""
    return make_synthetic(root, config, seed, **kw)
