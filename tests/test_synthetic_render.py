"""The synthetic dataset's renderer, backgrounds and generator, on the tiny configuration.

The tiny dataset (3 categories x 2 instances x 8 azimuths, one height and scale) is rendered once per
module, in this process; one test renders a smaller dataset with two spawned workers to check that the
pixels do not depend on how the work is split.
"""

import json
import os
import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

from scrppl.datasets.core import assign_splits, bbox_from_mask
from scrppl.datasets.synthetic import SyntheticConfig, load_or_make, make_synthetic, render_view
from scrppl.datasets.synthetic.backgrounds import (
    PHOTO_POOLS,
    POOLS,
    draw_background,
    pool_of_split,
    pool_sources,
    render_background,
)
from scrppl.datasets.synthetic.compose import encode_jpeg, encode_png
from scrppl.datasets.synthetic.floors import FLOOR_KINDS, make_floor, periodic_noise
from scrppl.datasets.synthetic.generate import image_stem, view_style
from scrppl.datasets.synthetic.render import (
    base_distance,
    kelvin_to_rgb,
    object_extent,
    view_camera,
)
from scrppl.views import ViewGrid

SEED = 3


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny") / "synthetic"
    config = SyntheticConfig.for_profile("tiny")
    ds = make_synthetic(root, config, SEED, workers=1, progress=False)
    return config, ds


def _mask(ds, row):
    return ds.load_mask(row)


# -- the generated dataset --------------------------------------------------------------------------
def test_tiny_dataset_is_complete_and_laid_out_like_savarese(tiny):
    config, ds = tiny
    summary = ds.summary()
    assert summary["n_categories"] == len(config.categories) == 3
    assert summary["instances"] == 3 * config.n_instances
    assert summary["images"] == config.n_images == 3 * 2 * 8
    assert summary["missing_views"] == 0
    assert ds.meta["seed"] == SEED and ds.meta["config"] == config.to_dict()
    row = ds.row("bicycle", 1, 2, 0, 0)
    assert row["image"] == "bicycle/bicycle_2/bicycle_2_A3_H1_S1.jpg"
    assert row["mask"] == "bicycle/bicycle_2/mask/bicycle_2_A3_H1_S1.png"
    img = ds.load_image(row)
    assert img.shape == (config.height, config.width, 3) and img.dtype == np.uint8
    # the index's splits are assign_splits' (which were fixed before rendering)
    expected = assign_splits(
        SEED, {c: range(2) for c in config.categories}, config.split_proportions
    )
    for (c, i), g in ds.index.groupby(["category", "instance"]):
        assert set(g["split"]) == {expected[(c, i)]}


def test_masks_are_nonempty_inside_the_frame_and_boxes_are_tight(tiny):
    config, ds = tiny
    for _, row in ds.index.iterrows():
        mask = _mask(ds, row)
        assert mask.shape == (config.height, config.width)
        assert 0.01 < mask.mean() < 0.8, row["image"]
        ys, xs = np.nonzero(mask)
        x0, y0, x1, y1 = ds.bbox(row)
        assert (x0, y0, x1, y1) == (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
        # base_distance frames the object: it never touches the image border
        assert x0 > 0 and y0 > 0 and x1 < config.width and y1 < config.height, row["image"]


def test_mask_is_the_object_in_the_image(tiny):
    """The mask covers something that looks different from its surroundings (not, e.g., a shifted
    or empty region): mean colours inside the mask and in a ring around it differ."""
    _, ds = tiny
    row = ds.row("cellphone", 0, 0)
    img = ds.load_image(row).astype(float)
    mask = _mask(ds, row)
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool) & ~mask
    assert ring.sum() > 100
    inside, outside = img[mask].mean(0), img[ring].mean(0)
    assert np.abs(inside - outside).max() > 5


def test_bicycle_is_thin_from_the_front_and_wide_from_the_side(tiny):
    _, ds = tiny
    for inst in range(2):
        front = _mask(ds, ds.row("bicycle", inst, 0))
        side = _mask(ds, ds.row("bicycle", inst, 2))
        back = _mask(ds, ds.row("bicycle", inst, 4))
        width = {
            k: np.ptp(np.nonzero(m)[1])
            for k, m in (("front", front), ("side", side), ("back", back))
        }
        assert width["front"] < 0.5 * width["side"], width
        assert width["back"] < 0.5 * width["side"], width
        iou = (front & side).sum() / (front | side).sum()
        assert iou < 0.5


def test_same_seed_gives_identical_bytes_when_one_view_is_rendered_alone(tiny):
    config, ds = tiny
    row = ds.row("mouse", 1, 5)
    view = (5, 0, 0)
    image, mask, quality = render_view(config, SEED, "mouse", 1, view, row["split"])
    assert encode_jpeg(image, quality) == (ds.root / row["image"]).read_bytes()
    assert encode_png(mask) == (ds.root / row["mask"]).read_bytes()
    # a different seed gives a different image
    other, _, _ = render_view(config, SEED + 1, "mouse", 1, view, row["split"])
    assert np.abs(other.astype(int) - image.astype(int)).mean() > 5


def test_resume_regenerates_only_the_deleted_view_identically(tiny, tmp_path):
    config, ds = tiny
    root = tmp_path / "copy"
    shutil.copytree(ds.root, root)
    target = root / ds.row("cellphone", 0, 3)["image"]
    original = target.read_bytes()
    target.unlink()
    (root / "index.csv").unlink()  # as if the run had been interrupted before writing the index
    others = {p: p.stat().st_mtime_ns for p in root.rglob("*.jpg") if p != target}
    again = make_synthetic(root, config, SEED, workers=1, progress=False)
    assert target.read_bytes() == original
    assert all(p.stat().st_mtime_ns == t for p, t in others.items())
    pd.testing.assert_frame_equal(again.index, ds.index)
    # a complete folder is just loaded: nothing is rewritten
    stamp = target.stat().st_mtime_ns
    loaded = load_or_make(root, config, SEED, workers=1, progress=False)
    assert target.stat().st_mtime_ns == stamp
    pd.testing.assert_frame_equal(loaded.index, ds.index)


@pytest.mark.slow  # spawning two render processes costs ~10 s (more on a busy machine)
def test_worker_processes_give_the_same_pixels(tmp_path):
    """Two spawned workers (one render window each) write the bytes one in-process renderer writes."""
    config = SyntheticConfig(
        categories=("car", "head"), n_instances=1, grid=ViewGrid(4, (10.0,), (1.9,))
    )
    a = make_synthetic(tmp_path / "one", config, SEED, workers=1, progress=False)
    b = make_synthetic(tmp_path / "two", config, SEED, workers=2, progress=False)
    pd.testing.assert_frame_equal(a.index, b.index)
    for rel in a.index["image"].tolist() + a.index["mask"].tolist():
        assert (a.root / rel).read_bytes() == (b.root / rel).read_bytes(), rel


# -- backgrounds ------------------------------------------------------------------------------------
def test_background_pools_are_disjoint_and_follow_the_split(tiny):
    config, ds = tiny
    train, heldout = (set(pool_sources(p, SEED)) for p in POOLS)
    assert train and heldout and not train & heldout
    assert not set(PHOTO_POOLS["train"]) & set(PHOTO_POOLS["heldout"])
    used = {"train": set(), "heldout": set()}
    for _, row in ds.index.iterrows():
        view = (row["azimuth"], row["elevation"], row["scale"])
        vs = view_style(SEED, row["category"], row["instance"], view, row["split"], config)
        pool = pool_of_split(row["split"])
        assert vs.background.source in (train if pool == "train" else heldout)
        used[pool].add(vs.background.source)
    assert used["train"] and used["heldout"]
    assert not used["train"] & used["heldout"]
    with pytest.raises(ValueError, match="split"):
        pool_of_split("validation")


def test_background_photos_are_bundled_and_backgrounds_deterministic():
    for pool in POOLS:
        for name in PHOTO_POOLS[pool]:
            choice = draw_background(np.random.default_rng(0), pool, 0, 64, 48)._replace(
                source=f"photo:{name}"
            )
            img = render_background(choice, 64, 48)
            assert img.shape == (48, 64, 3) and 0 <= img.min() and img.max() <= 1
    c1 = draw_background(np.random.default_rng(7), "heldout", 1, 320, 240)
    c2 = draw_background(np.random.default_rng(7), "heldout", 1, 320, 240)
    assert c1 == c2
    np.testing.assert_array_equal(render_background(c1, 320, 240), render_background(c2, 320, 240))


# -- floors, camera, light --------------------------------------------------------------------------
@pytest.mark.parametrize("kind", FLOOR_KINDS)
def test_floor_textures_tile_seamlessly(kind):
    tex = make_floor(11, kind).texture.astype(float)
    assert tex.shape == (256, 256, 3)
    # the jump across the wrap-around seam is no larger than the jumps between neighbouring
    # columns (rows) inside the texture, plank gaps and grout lines included
    for axis in (0, 1):
        t = np.moveaxis(tex, axis, 0)
        interior = np.abs(np.diff(t, axis=0)).mean(axis=(1, 2))
        seam = np.abs(t[0] - t[-1]).mean()
        assert seam <= 1.5 * interior.max() + 1, (axis, seam, interior.max())
    np.testing.assert_array_equal(make_floor(11, kind).texture, make_floor(11, kind).texture)


def test_a_non_tiling_texture_fails_the_seam_check():
    """The seam statistic above does catch a texture that does not wrap (a gradient)."""
    t = np.linspace(0, 255, 256)[None, :, None] * np.ones((256, 1, 3))
    interior = np.abs(np.diff(t, axis=1)).mean(axis=(0, 2))
    seam = np.abs(t[:, 0] - t[:, -1]).mean()
    assert seam > 10 * interior.max()


def test_periodic_noise_is_standardised_and_wraps(rng):
    x = periodic_noise(rng, (64, 96), 2.0)
    assert abs(x.mean()) < 1e-9 and abs(x.std() - 1) < 1e-9
    # smooth noise: the first and last columns (rows), neighbours across the wrap, are as strongly
    # correlated as neighbouring columns (rows) inside
    for axis in (0, 1):
        t = np.moveaxis(x, axis, 0)
        inside = np.corrcoef(t[:-1].ravel(), t[1:].ravel())[0, 1]
        across = np.corrcoef(t[0], t[-1])[0, 1]
        assert inside > 0.6 and across > 0.5
    # white noise (beta = 0) is uncorrelated
    w = periodic_noise(rng, (64, 96), 0.0)
    assert abs(np.corrcoef(w[:, :-1].ravel(), w[:, 1:].ravel())[0, 1]) < 0.1


def test_camera_follows_the_azimuth_convention():
    grid = ViewGrid()
    for a, direction in ((0, (1, 0)), (2, (0, 1)), (4, (-1, 0)), (6, (0, -1))):
        cam = view_camera(grid, a, 1, 0, distance=2.0, height=0.6)
        xy = cam.position[:2] / np.linalg.norm(cam.position[:2])
        np.testing.assert_allclose(xy, direction, atol=1e-12)
        np.testing.assert_allclose(cam.focal_point, [0, 0, 0.3])
        el = np.degrees(
            np.arcsin((cam.position[2] - 0.3) / np.linalg.norm(cam.position - cam.focal_point))
        )
        assert el == pytest.approx(25.0)
    near = view_camera(grid, 0, 0, 0, distance=2.0, height=0.6)
    far = view_camera(grid, 0, 0, 2, distance=2.0, height=0.6)
    ratio = np.linalg.norm(far.position - far.focal_point) / np.linalg.norm(
        near.position - near.focal_point
    )
    assert ratio == pytest.approx(grid.scales[2] / grid.scales[0])


def test_base_distance_frames_a_box_exactly():
    """For a unit cube seen head-on at elevation ~0, the bound is the pinhole formula."""
    grid = ViewGrid(4, (1e-9,), (1.0,))
    cube = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.0, 1.0)])
    fill, aspect = 0.8, 4 / 3
    d = base_distance(cube, grid, aspect=aspect, fill=fill)
    tan_v = np.tan(np.radians(15.0)) * fill
    # the nearest face is at depth d - 0.5 and spans half-height 0.5 vertically (tightest)
    assert d == pytest.approx(0.5 + 0.5 / tan_v, rel=1e-6)


def test_object_extent_normalises_any_placement():
    import trimesh

    from scrppl.datasets.synthetic.shapes import Part

    box = trimesh.creation.box(extents=(4.0, 2.0, 1.0))
    box.apply_translation((10.0, -3.0, 5.0))
    transform, radius, height = object_extent([Part(box, (0.5, 0.5, 0.5))])
    v = box.vertices @ transform[:3, :3].T + transform[:3, 3]
    np.testing.assert_allclose(v.min(0), [-0.5, -0.25, 0.0], atol=1e-12)
    np.testing.assert_allclose(v.max(0), [0.5, 0.25, 0.25], atol=1e-12)
    assert height == pytest.approx(0.25)
    assert radius == pytest.approx(np.linalg.norm([0.5, 0.25, 0.125]))


def test_colour_temperature():
    warm, daylight, cold = kelvin_to_rgb(2700), kelvin_to_rgb(6600), kelvin_to_rgb(12000)
    assert warm[0] == 1 and warm[2] < 0.6
    assert np.all(daylight > 0.95)
    assert cold[2] == 1 and cold[0] < 0.9


def test_renderer_mask_matches_an_independent_pass():
    from scrppl.datasets.synthetic.generate import _renderer
    from scrppl.datasets.synthetic.render import Lighting
    from scrppl.datasets.synthetic.shapes import build_instance

    r = _renderer(160, 120)
    r.set_instance(build_instance("iron", 4))
    r.set_floor(make_floor(4))
    r.set_lighting(Lighting(direction=np.array([0.4, -0.3, 0.8])))
    grid = ViewGrid()
    d = base_distance(r.vertices, grid, aspect=160 / 120)
    for view in ((0, 0, 0), (3, 2, 1), (6, 1, 2)):
        cam = view_camera(grid, *view, distance=d, height=r.object_height, radius=r.radius)
        frame = r.render(cam)
        alone = r.render_object_mask(cam)
        assert frame.object_mask.sum() > 50
        assert (frame.object_mask != alone).sum() <= 2
        assert not (frame.floor_mask & frame.object_mask).any()
        assert frame.floor_mask.any()
        assert np.all(np.isfinite(frame.floor_radius[frame.floor_mask]))
        assert np.all(np.isinf(frame.floor_radius[~frame.floor_mask]))


# -- errors -----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"categories": ("car", "spaceship")}, "unknown categories"),
        ({"categories": ("car", "car")}, "repeat"),
        ({"categories": ()}, "at least one category"),
        ({"n_instances": 0}, "n_instances"),
        ({"width": 8}, "width"),
        ({"grid": ViewGrid(8, (90.0,), (1.0,))}, "elevations"),
        ({"grid": ViewGrid(8, (20.0,), (0.0,))}, "scales"),
        ({"split_proportions": (0.5, 0.5, 0.5)}, "split_proportions"),
        ({"jitter": -1.0}, "jitter"),
    ],
)
def test_bad_configurations_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SyntheticConfig(**kwargs)


def test_profiles_and_round_trip():
    full = SyntheticConfig.for_profile("full")
    assert full.n_images == 7200 and len(full.categories) == 10 and full.n_instances == 10
    assert full.width >= 320 and full.height >= 240
    quick = SyntheticConfig.for_profile("quick")
    assert quick.n_images < full.n_images
    for cfg in (full, quick, SyntheticConfig.for_profile("tiny")):
        assert SyntheticConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ValueError, match="profile"):
        SyntheticConfig.for_profile("huge")


def test_bad_generator_arguments(tiny, tmp_path):
    config, ds = tiny
    with pytest.raises(ValueError, match="seed"):
        make_synthetic(tmp_path / "a", config, -1, workers=1, progress=False)
    with pytest.raises(ValueError, match="workers"):
        make_synthetic(tmp_path / "a", config, 0, workers=0, progress=False)
    with pytest.raises(ValueError, match="SyntheticConfig"):
        make_synthetic(tmp_path / "a", {"categories": ["car"]}, 0, workers=1, progress=False)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    with pytest.raises(RuntimeError, match="cannot write"):
        make_synthetic(blocker / "sub", config, 0, workers=1, progress=False)
    # a folder holding another configuration's dataset is never mixed with this one
    with pytest.raises(ValueError, match="another configuration"):
        make_synthetic(ds.root, config, SEED + 1, workers=1, progress=False)


def test_image_stem_is_one_based():
    assert image_stem("car", 0, (0, 0, 0)) == "car_1_A1_H1_S1"
    assert image_stem("shoe", 9, (7, 2, 2)) == "shoe_10_A8_H3_S3"


def test_bbox_from_rendered_mask_round_trips(tiny):
    _, ds = tiny
    row = ds.index.iloc[0]
    mask = cv2.imread(os.fspath(ds.root / row["mask"]), cv2.IMREAD_GRAYSCALE)
    assert set(np.unique(mask)) <= {0, 255}
    assert bbox_from_mask(mask > 127) == ds.bbox(row)
