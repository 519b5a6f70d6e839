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

Domains. ``config.domain`` (`scrppl.datasets.synthetic.domain`) says how each split is photographed. In
the ``robot`` and ``hard`` presets the ``train`` split -- the only images the detectors are trained on --
is rendered as catalogue images (exact grid views on a studio backdrop under studio light, neutral camera),
while the ``fit`` and ``test`` splits, which the viewpoint models are fitted on and the simulator observes,
gain the nuisances of a real room (`scrppl.datasets.synthetic.nuisances`), as in Meger et al. (2010),
whose detector was trained on PASCAL VOC and run on another dataset. The dataset's metadata records the
domain with every parameter (``meta["config"]["domain"]``). The ``clean`` preset renders every split as
before, byte for byte.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from scrppl._io import atomic_path
from scrppl.datasets.core import (
    INDEX_FILE,
    META_FILE,
    SYNTHETIC_GENERATOR,
    SYNTHETIC_PROVENANCE_FILE,
    MultiviewDataset,
    assign_splits,
    bbox_from_mask,
)
from scrppl.datasets.synthetic.config import PROFILES, SyntheticConfig
from scrppl.datasets.synthetic.styles import (
    InstanceStyle,
    ViewStyle,
    instance_style,
    view_style,
)

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
#: Provenance file written at the start of a generation.
PROVENANCE_FILE = SYNTHETIC_PROVENANCE_FILE


# -- per-instance and per-view randomness ----------------------------------------------------------
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

    def __init__(
        self, config: SyntheticConfig, seed: int, category: str, instance: int, split: str = "test"
    ):
        from scrppl.datasets.synthetic.floors import make_floor
        from scrppl.datasets.synthetic.nuisances import plain_floor
        from scrppl.datasets.synthetic.render import base_distance
        from scrppl.datasets.synthetic.shapes import build_instance

        self.style = instance_style(seed, category, instance, config.jitter)
        self.catalogue = config.domain.catalogue and split == "train"
        self.tone = _studio_tone(seed, category, instance) if self.catalogue else None
        self.renderer = _renderer(config.width, config.height)
        self.renderer.set_instance(build_instance(category, self.style.shape_seed))
        self.renderer.set_floor(
            plain_floor(self.tone) if self.catalogue else make_floor(self.style.floor_seed)
        )
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

    nuisance = config.domain.robot
    robot = not (config.domain.catalogue and split == "train") and not nuisance.is_clean
    sprites = []
    if robot and nuisance.distractors[1] > 0:  # distractors of the other categories
        sprites = [sp for sp in _sprite_pool(seed) if sp.category != category]
    loaded = _loaded or _Instance(config, seed, category, instance, split)
    if loaded.catalogue:
        return _render_catalogue(config, seed, category, instance, view, loaded)
    st = loaded.style
    vs = view_style(seed, category, instance, view, split, config)
    r = loaded.renderer
    direction, intensity, kelvin = (
        st.light_direction,
        st.light_intensity * vs.light_gain,
        st.light_kelvin,
    )
    if robot:
        from scrppl.datasets.synthetic import nuisances as nz

        a, e, s = (int(v) for v in view)
        nrng = np.random.default_rng(
            [int(seed), _category_key(category), int(instance), a, e, s, 4]
        )
        nd = nz.draw_nuisance(nrng, nuisance, config.grid.scales[s], len(sprites))
        direction = nz.relight_direction(direction, nd, nuisance.light_direction)
        intensity *= nd.light_gain
        kelvin = kelvin if nd.light_kelvin is None else nd.light_kelvin
    r.set_lighting(
        Lighting(
            direction=direction,
            intensity=intensity,
            color=kelvin_to_rgb(kelvin),
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
    if robot and nd.truncation is not None:
        frame = nz.truncate_frame(frame, *nd.truncation)
    background = render_background(vs.background, config.width, config.height)
    # the farther the camera, the more floor it sees: widen the floor's fade with the distance
    widen = float(np.sqrt(config.grid.scales[view[2]] / min(config.grid.scales)))
    image = composite(frame, background, (st.fade[0] * widen, st.fade[1] * widen))
    if not robot:
        image = develop(np.random.default_rng(vs.noise_seed), image, vs.development)
        return image, frame.object_mask, vs.development.jpeg_quality
    mask = frame.object_mask
    image, mask = nz.paste_sprites(image, mask, sprites, nd.distractors)
    if nd.occluder is not None and mask.any():
        image, mask, _ = nz.occlude(image, mask, *nd.occluder, _occluder_texture(seed, nd, config))
    image = image * np.asarray(nd.color_gain, np.float32)
    image = nz.optics(image, nd.defocus, nd.motion, nd.resolution)
    image = develop(np.random.default_rng(vs.noise_seed), image, vs.development)
    image = nz.add_noise(nd.noise_seed, image, nd.noise)
    quality = vs.development.jpeg_quality if nd.jpeg_quality is None else nd.jpeg_quality
    return image, mask, quality


def _category_key(category: str) -> int:
    import zlib

    return zlib.crc32(category.encode())


def _studio_tone(seed: int, category: str, instance: int) -> np.ndarray:
    """The backdrop and floor colour of an instance's catalogue photographs: a light, nearly neutral tone."""
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), 3])
    return np.clip(rng.uniform(0.68, 0.95) * (1.0 + rng.uniform(-0.04, 0.04, 3)), 0.0, 1.0)


def _render_catalogue(
    config: SyntheticConfig,
    seed: int,
    category: str,
    instance: int,
    view: tuple[int, int, int],
    loaded: _Instance,
) -> tuple[np.ndarray, np.ndarray, int]:
    """A catalogue photograph: the exact grid view on a studio backdrop, studio light, neutral camera."""
    from scrppl.datasets.synthetic.compose import composite, develop, draw_development
    from scrppl.datasets.synthetic.nuisances import studio_backdrop
    from scrppl.datasets.synthetic.render import Lighting, kelvin_to_rgb, view_camera

    a, e, s = (int(v) for v in view)
    rng = np.random.default_rng([int(seed), _category_key(category), int(instance), a, e, s, 3])
    r = loaded.renderer
    phi = np.deg2rad(a * config.grid.step_degrees + 35.0)  # key light beside the camera
    el = np.deg2rad(50.0)
    r.set_lighting(
        Lighting(
            direction=np.array([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)]),
            intensity=1.1,
            color=kelvin_to_rgb(5600.0),
            ambient=0.42,
        )
    )
    camera = view_camera(
        config.grid, a, e, s, distance=loaded.distance, height=r.object_height, radius=r.radius
    )
    frame = r.render(camera)
    # a seamless sweep: the backdrop takes the colour of the lit floor, into which the floor fades
    floor = frame.rgb[frame.floor_mask]
    tone = np.median(floor, axis=0) / 255.0 if len(floor) else loaded.tone
    background = studio_backdrop(rng, tone, config.width, config.height)
    widen = float(np.sqrt(config.grid.scales[s] / min(config.grid.scales)))
    fade = loaded.style.fade
    image = composite(frame, background, (fade[0] * widen, fade[1] * widen))
    dev = draw_development(rng, 0.0)  # neutral: no colour jitter, no noise, JPEG 95
    image = develop(np.random.default_rng(0), image, dev)
    return image, frame.object_mask, dev.jpeg_quality


def _occluder_texture(seed: int, nd, config: SyntheticConfig) -> np.ndarray:
    """The surface of an occluder: a darkened crop of a held-out background source."""
    from scrppl.datasets.synthetic.backgrounds import draw_background, render_background

    k, cx, cy, gain = nd.occluder_texture
    rng = np.random.default_rng([int(seed), k, 5])
    choice = draw_background(rng, "heldout", int(seed), config.width, config.height)
    choice = choice._replace(
        crop=(0.3, choice.crop[1], cx, cy), gain=tuple(gain * g for g in choice.gain), defocus=0.5
    )
    return render_background(choice, config.width, config.height)


#: Distractor sprites: instances of every category seen from random views, rendered once per process.
N_SPRITES = 30
_SPRITE_SIZE = 160
_SPRITES: dict[int, list] = {}


def _sprite_pool(seed: int) -> list:
    """The distractor sprites of a dataset seed (:class:`~scrppl.datasets.synthetic.nuisances.Sprite`).

    Sprite ``k`` is an instance of category ``CATEGORIES[k % 10]`` with a shape seed, azimuth and
    elevation drawn from ``default_rng([seed, 0xD157, k])`` (never an instance of the dataset), rendered
    by a renderer of its own under a neutral light and cut out by its mask.
    """
    if seed in _SPRITES:
        return _SPRITES[seed]
    from scrppl.datasets.synthetic.floors import make_floor
    from scrppl.datasets.synthetic.nuisances import Sprite
    from scrppl.datasets.synthetic.render import Lighting, SceneRenderer, base_distance, view_camera
    from scrppl.datasets.synthetic.shapes import CATEGORIES, build_instance
    from scrppl.views import ViewGrid

    r = SceneRenderer(
        _SPRITE_SIZE, _SPRITE_SIZE
    )  # its own window: the dataset's renderer keeps its instance
    r.set_floor(make_floor(0))
    grid = ViewGrid(8, (20.0,), (1.0,))
    pool = []
    for k in range(N_SPRITES):
        rng = np.random.default_rng([int(seed), 0xD157, k])
        category_k = CATEGORIES[k % len(CATEGORIES)]
        r.set_instance(build_instance(category_k, int(rng.integers(2**31))))
        az = float(rng.uniform(0, 2 * np.pi))
        r.set_lighting(
            Lighting(direction=np.array([np.cos(az), np.sin(az), 1.2]), intensity=1.1, ambient=0.35)
        )
        d = base_distance(r.vertices, grid, aspect=1.0, fill=0.9)
        cam = view_camera(
            grid, int(rng.integers(8)), 0, 0, distance=d, height=r.object_height, radius=r.radius
        )
        frame = r.render(cam)
        ys, xs = np.nonzero(frame.object_mask)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        rgb = frame.rgb[y0:y1, x0:x1].astype(np.float32) / 255.0
        pool.append(Sprite(rgb, frame.object_mask[y0:y1, x0:x1].copy(), category_k))
    r.close()
    _SPRITES[seed] = pool
    return pool


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
    nuisance = config.domain.robot
    if not nuisance.is_clean and nuisance.distractors[1] > 0:
        _sprite_pool(task.seed)
    loaded = _Instance(config, task.seed, task.category, task.instance, task.split)
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
    """Set up a spawned rendering process."""
    import signal

    # llvmpipe starts one rasteriser thread per core; with one worker process per core, one each is
    # faster (and the pixels do not depend on the thread count)
    os.environ.setdefault("LP_NUM_THREADS", "1")
    # Ctrl-C is the parent's business: it stops handing out work and lets running instances finish
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # and if the parent is killed outright, do not linger (Linux; elsewhere the next read fails)
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


# -- the generator ---------------------------------------------------------------------------------
def _provenance(config: SyntheticConfig, seed: int) -> dict[str, Any]:
    return {
        "generator": SYNTHETIC_GENERATOR,
        "render_version": RENDER_VERSION,
        "seed": int(seed),
        "config": config.to_dict(),
    }


def _normalised(meta: dict[str, Any]) -> dict[str, Any]:
    """``meta`` with its configuration in today's form (a folder made before domains existed is clean)."""
    try:
        return {**meta, "config": SyntheticConfig.from_dict(meta["config"]).to_dict()}
    except (ValueError, KeyError, TypeError):
        return meta


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
    splits: tuple[str, ...] | list[str] | None = None,
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
    splits
        Render only the instances of these splits (of ``"train"``, ``"fit"``, ``"test"``); the instances
        and their splits are those of the whole dataset, so a held-out instance is the same one. The
        folder then holds (and its index lists) only those instances, and its metadata records
        ``splits``. ``None`` (default): every instance, and metadata as before.

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
    if splits is not None:
        wanted = sorted({str(x) for x in splits})
        bad = [x for x in wanted if x not in ("train", "fit", "test")]
        if not wanted or bad:
            raise ValueError(
                f"splits must name some of 'train', 'fit', 'test', got {list(splits)!r}"
            )
        meta["splits"] = wanted

    existing = _existing(root, meta)
    if existing is not None:
        return existing
    _check_writable(root)
    prov = root / PROVENANCE_FILE
    if prov.exists():
        try:
            old = _normalised(json.loads(prov.read_text()))
        except (json.JSONDecodeError, ValueError, KeyError, TypeError):
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
    keep = {ci for ci, sp in splits.items() if "splits" not in meta or sp in meta["splits"]}
    for c in config.categories:
        for i in range(config.n_instances):
            if (c, i) not in keep:
                continue
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
            if (c, i) not in keep:
                continue
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
    mine = _normalised({k: saved.get(k) for k in meta})
    if mine != meta or saved.get("splits") != meta.get("splits"):
        raise ValueError(
            f"{root} holds a dataset made with another configuration, seed or renderer version "
            f"(its {META_FILE} says {json.dumps(mine, sort_keys=True)}); delete that folder or "
            "choose another root"
        )
    dataset = MultiviewDataset.load(root)
    cfg = SyntheticConfig.from_dict(meta["config"])
    n_images = cfg.n_images
    if "splits" in meta:
        parts = assign_splits(
            meta["seed"],
            {c: range(cfg.n_instances) for c in cfg.categories},
            cfg.split_proportions,
        )
        n_kept = sum(sp in meta["splits"] for sp in parts.values())
        n_images = n_kept * cfg.grid.n_views
    if len(dataset) != n_images:
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
