"""Imaging domains of the synthetic generator: every nuisance parameter does what it says.

Each test renders one small view with one parameter of `Nuisance` set and compares it with the same view
without it (the clean image): closed forms where there is one (added white noise raises the Laplacian
energy by ``20 sigma^2``), exact pixel shares for occlusion and truncation, and orderings otherwise.
"""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic, render_view
from scrppl.datasets.synthetic.domain import (
    PAPER_LEVEL,
    PRESET_NAMES,
    PRESETS,
    Domain,
    Nuisance,
    domain_at_level,
)
from scrppl.views import ViewGrid

SEED = 3
W, H = 160, 120
# two scales: 1 (near; the far-resolution effect is off) and 2 (twice the base distance)
GRID = ViewGrid(8, (25.0,), (1.0, 2.0))
CATEGORY, INSTANCE, SPLIT = "toaster", 1, "test"


def config(domain: Domain | str = "clean", **kw) -> SyntheticConfig:
    return SyntheticConfig(
        categories=("toaster", "mouse"),
        n_instances=3,
        grid=GRID,
        width=W,
        height=H,
        domain=domain,
        **kw,
    )


def robot(**params) -> SyntheticConfig:
    """Every split rendered with only ``params`` of the robot's nuisances."""
    return config(Domain("test", catalogue=False, robot=Nuisance(**params)))


@pytest.fixture(scope="module")
def loaded():
    """The instance's scene (the process's renderer is shared, so :func:`render` sets it up again)."""
    from scrppl.datasets.synthetic.generate import _Instance

    return _Instance(config(), SEED, CATEGORY, INSTANCE, SPLIT)


def render(cfg: SyntheticConfig, loaded, view=(1, 0, 0), split=SPLIT):
    from scrppl.datasets.synthetic.floors import make_floor
    from scrppl.datasets.synthetic.shapes import build_instance

    # another test may have loaded another object into the shared renderer
    loaded.renderer.set_instance(build_instance(CATEGORY, loaded.style.shape_seed))
    loaded.renderer.set_floor(make_floor(loaded.style.floor_seed))
    return render_view(cfg, SEED, CATEGORY, INSTANCE, view, split, _loaded=loaded)


@pytest.fixture(scope="module")
def clean(loaded):
    return render(config(), loaded)


def laplacian_energy(img: np.ndarray) -> float:
    """Mean squared 4-neighbour Laplacian over the interior, all channels."""
    x = img.astype(np.float64)
    lap = x[1:-1, :-2] + x[1:-1, 2:] + x[:-2, 1:-1] + x[2:, 1:-1] - 4 * x[1:-1, 1:-1]
    return float(np.mean(lap**2))


# -- the clean preset is the original generator ------------------------------------------------------
def _original_render_view(cfg, seed, category, instance, view, split, loaded):
    """The generator's ``render_view`` as it was before imaging domains existed (the reference)."""
    from scrppl.datasets.synthetic.backgrounds import render_background
    from scrppl.datasets.synthetic.compose import composite, develop
    from scrppl.datasets.synthetic.render import Lighting, kelvin_to_rgb, view_camera
    from scrppl.datasets.synthetic.styles import view_style

    st = loaded.style
    vs = view_style(seed, category, instance, view, split, cfg)
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
        cfg.grid, *view, distance=loaded.distance, height=r.object_height, radius=r.radius,
        jitter=vs.camera_jitter,
    )  # fmt: skip
    frame = r.render(camera)
    background = render_background(vs.background, cfg.width, cfg.height)
    widen = float(np.sqrt(cfg.grid.scales[view[2]] / min(cfg.grid.scales)))
    image = composite(frame, background, (st.fade[0] * widen, st.fade[1] * widen))
    image = develop(np.random.default_rng(vs.noise_seed), image, vs.development)
    return image, frame.object_mask, vs.development.jpeg_quality


@pytest.mark.parametrize("split", ["train", "test"])
def test_clean_preset_renders_the_original_images(loaded, split):
    cfg = SyntheticConfig.for_profile("tiny", "clean")
    assert cfg == SyntheticConfig.for_profile("tiny") and cfg.domain.is_clean
    cfg = config("clean")
    for view in [(0, 0, 0), (3, 0, 1)]:
        img, mask, q = render(cfg, loaded, view, split)
        ref_img, ref_mask, ref_q = _original_render_view(
            cfg, SEED, CATEGORY, INSTANCE, view, split, loaded
        )
        assert img.tobytes() == ref_img.tobytes()
        assert np.array_equal(mask, ref_mask) and q == ref_q


def test_same_seed_same_bytes_and_another_seed_differs(loaded):
    cfg = config("hard")
    a = render(cfg, loaded)
    b = render(cfg, loaded)
    assert a[0].tobytes() == b[0].tobytes() and np.array_equal(a[1], b[1]) and a[2] == b[2]
    c = render_view(cfg, SEED + 1, CATEGORY, INSTANCE, (1, 0, 0), SPLIT)
    assert c[0].tobytes() != a[0].tobytes()


# -- one parameter at a time -------------------------------------------------------------------------
def test_sensor_noise_adds_twenty_sigma_squared_of_laplacian_energy(loaded, clean):
    sigma = 6.0
    img, mask, _ = render(robot(noise=(sigma, sigma)), loaded)
    assert np.array_equal(mask, clean[1])
    diff = img.astype(float) - clean[0].astype(float)
    # clipping at 0/255 is rare in these images; rounding adds 1/12 grey level^2
    assert np.std(diff) == pytest.approx(np.sqrt(sigma**2 + 1 / 12), rel=0.06)
    gain = laplacian_energy(img) - laplacian_energy(clean[0])
    assert gain == pytest.approx(20 * sigma**2, rel=0.12)
    more = render(robot(noise=(2 * sigma, 2 * sigma)), loaded)[0]
    assert laplacian_energy(more) - laplacian_energy(clean[0]) == pytest.approx(4 * gain, rel=0.15)


@pytest.mark.parametrize(
    "param, values",
    [("defocus", (0.8, 1.6, 3.0)), ("motion_blur", (2.0, 5.0, 10.0))],
)
def test_blur_lowers_high_frequency_energy_monotonically(loaded, clean, param, values):
    energies = [laplacian_energy(clean[0])]
    for v in values:
        img, mask, _ = render(robot(**{param: (v, v)}), loaded)
        assert np.array_equal(mask, clean[1])
        energies.append(laplacian_energy(img))
    assert all(b < a for a, b in zip(energies, energies[1:], strict=False)), energies


def test_jpeg_quality_is_drawn_from_the_range_and_lowers_psnr(loaded, clean):
    from scrppl.datasets.synthetic.compose import encode_jpeg

    assert clean[2] >= 85  # the camera's own quality
    psnrs, blobs = [], set()
    for q in (90, 60, 30, 10):
        img, _, quality = render(robot(jpeg_quality=(q, q)), loaded)
        assert quality == q and img.tobytes() == clean[0].tobytes()  # only the encoding changes
        blob = encode_jpeg(img, quality)
        blobs.add(blob)
        dec = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
        mse = np.mean((dec.astype(float) - img.astype(float)) ** 2)
        psnrs.append(10 * np.log10(255.0**2 / mse))
    assert len(blobs) == 4
    assert all(b < a for a, b in zip(psnrs, psnrs[1:], strict=False)), psnrs
    qs = {render(robot(jpeg_quality=(20, 40)), loaded, (a, 0, 0))[2] for a in range(8)}
    assert qs <= set(range(20, 41)) and len(qs) > 1


@pytest.mark.parametrize("fraction", [0.15, 0.4])
def test_occluder_hides_the_stated_share_of_the_object(loaded, clean, fraction):
    img, mask, _ = render(robot(occlusion=1.0, occlusion_fraction=(fraction, fraction)), loaded)
    full = clean[1]
    assert not np.any(mask & ~full)  # the occluder only removes object pixels
    hidden = 1.0 - mask.sum() / full.sum()
    assert hidden == pytest.approx(fraction, abs=0.02)
    changed = np.any(img != clean[0], axis=-1)
    assert changed[full & ~mask].mean() > 0.95  # the hidden pixels show the occluder
    assert changed[mask].mean() < 0.05  # the visible ones are untouched


@pytest.mark.parametrize("fraction", [0.2, 0.45])
def test_truncation_cuts_the_object_at_the_border(loaded, clean, fraction):
    img, mask, _ = render(robot(truncation=1.0, truncation_fraction=(fraction, fraction)), loaded)
    kept = mask.sum() / clean[1].sum()
    # whole columns leave: the share is exact up to one column of the object
    one_column = clean[1].sum(axis=0).max() / clean[1].sum()
    assert kept == pytest.approx(1.0 - fraction, abs=one_column + 1e-9)
    assert mask[:, 0].any() or mask[:, -1].any()
    assert not clean[1][:, 0].any() and not clean[1][:, -1].any()


def _object_means(img, mask):
    return img[mask].astype(float).mean(axis=0)


def test_light_colour_shifts_the_channel_means(loaded):
    warm, mask, _ = render(robot(light_kelvin=(2500.0, 2500.0)), loaded)
    cold, mask2, _ = render(robot(light_kelvin=(10000.0, 10000.0)), loaded)
    assert np.array_equal(mask, mask2)
    w, c = _object_means(warm, mask), _object_means(cold, mask)
    assert w[0] / w[2] > 1.15 * c[0] / c[2]  # red over blue: warm light is redder
    # a white-balance cast moves the channels of the whole image apart
    base = render(robot(), loaded)[0].reshape(-1, 3).astype(float).mean(0)
    cast = render(robot(color_cast=0.3), loaded)[0].reshape(-1, 3).astype(float).mean(0)
    ratio = cast / base
    assert ratio.max() / ratio.min() > 1.05


def test_light_intensity_and_direction_change_shading_not_the_mask(loaded, clean):
    bright, m1, _ = render(robot(light_intensity=(1.8, 1.8)), loaded)
    dim, m2, _ = render(robot(light_intensity=(0.5, 0.5)), loaded)
    assert np.array_equal(m1, clean[1]) and np.array_equal(m2, clean[1])
    assert _object_means(bright, m1).mean() > _object_means(clean[0], m1).mean()
    assert _object_means(dim, m1).mean() < _object_means(clean[0], m1).mean()
    turned, m3, _ = render(robot(light_direction=1.0), loaded)
    assert np.array_equal(m3, clean[1])
    diff = np.abs(turned.astype(float) - clean[0].astype(float)).mean(axis=-1)
    assert diff[m3].mean() > 3.0


def test_far_views_lose_resolution_near_views_do_not(loaded):
    near_clean = render(config(), loaded, (1, 0, 0))[0]
    far_clean = render(config(), loaded, (1, 0, 1))[0]
    cfg = robot(far_resolution=0.4)
    near = render(cfg, loaded, (1, 0, 0))[0]
    far = render(cfg, loaded, (1, 0, 1))[0]
    assert near.tobytes() == near_clean.tobytes()  # scale 1: log2(1) = 0, full resolution
    assert laplacian_energy(far) < 0.6 * laplacian_energy(far_clean)
    # effective resolution: what is left is (nearly) what survives a 0.4x down- and up-sampling
    small = cv2.resize(far, (round(W * 0.4), round(H * 0.4)), interpolation=cv2.INTER_AREA)
    again = cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR)
    assert (
        np.abs(again.astype(float) - far.astype(float)).mean()
        < 0.5 * np.abs(again.astype(float) - far_clean.astype(float)).mean()
    )


def test_distractors_stand_behind_or_in_front(loaded, clean):
    img, mask, _ = render(robot(distractors=(3, 3), distractor_front=0.0), loaded)
    assert np.array_equal(mask, clean[1])  # behind: the object is whole
    changed = np.any(img != clean[0], axis=-1)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0  # beyond the lens blur
    assert not changed[inner].any() and changed[~mask].mean() > 0.02
    front, fmask, _ = render(robot(distractors=(3, 3), distractor_front=1.0), loaded)
    assert not np.any(fmask & ~clean[1])
    assert 0.3 <= fmask.sum() / clean[1].sum() < 1.0  # partly hidden, never mostly


def test_catalogue_images_are_studio_shots_of_the_exact_view(loaded):
    cfg = config("robot")
    from scrppl.datasets.synthetic.generate import _Instance

    cat = _Instance(cfg, SEED, CATEGORY, INSTANCE, "train")
    assert cat.catalogue
    img, mask, q = render_view(cfg, SEED, CATEGORY, INSTANCE, (2, 0, 0), "train", _loaded=cat)
    assert q == 95
    # the backdrop at the top of the image is plain: tiny variation along each row
    assert img[:8].astype(float).std(axis=1).max() < 2.5
    again = render_view(cfg, SEED, CATEGORY, INSTANCE, (2, 0, 0), "train", _loaded=cat)[0]
    assert again.tobytes() == img.tobytes()
    # the exact grid view: the object's pixels are those of the clean dataset rendered without jitter
    exact = render_view(config(jitter=0.0), SEED, CATEGORY, INSTANCE, (2, 0, 0), "train")[1]
    assert np.array_equal(mask, exact)
    robot_img = render_view(cfg, SEED, CATEGORY, INSTANCE, (2, 0, 0), "test")[0]
    assert robot_img.tobytes() != img.tobytes()


# -- parameters, presets and the dataset's record ------------------------------------------------------
@pytest.mark.parametrize(
    "param, value",
    [
        ("distractors", (3, 1)),
        ("distractors", (0, 2.5)),
        ("distractor_size", (0.0, 0.5)),
        ("distractor_front", 1.5),
        ("occlusion", -0.1),
        ("occlusion_fraction", (0.2, 0.9)),
        ("truncation", 2),
        ("truncation_fraction", (0.5, 0.7)),
        ("light_direction", "strong"),
        ("light_intensity", (0.0, 1.0)),
        ("light_kelvin", (500.0, 6000.0)),
        ("color_cast", 0.9),
        ("defocus", (-1.0, 1.0)),
        ("motion_blur", (0.0, 100.0)),
        ("noise", (5.0,)),
        ("far_resolution", 0.0),
        ("jpeg_quality", (0, 50)),
    ],
)
def test_invalid_parameter_names_itself(param, value):
    with pytest.raises(ValueError, match=param):
        Nuisance(**{param: value})


def test_presets_and_round_trip():
    assert PRESET_NAMES == ("clean", "robot", "paper", "hard")
    assert PRESETS["clean"].is_clean
    for name in PRESET_NAMES:
        cfg = SyntheticConfig.for_profile("quick", name)
        assert cfg.domain.name == name
        back = SyntheticConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
        assert back == cfg
        assert dataclasses.replace(cfg, domain=name) == cfg
    # harder presets are harder in every parameter that has an order
    r, h = PRESETS["robot"].robot, PRESETS["hard"].robot
    assert h.noise[1] > r.noise[1] and h.jpeg_quality[1] < r.jpeg_quality[1]
    assert h.far_resolution < r.far_resolution and h.occlusion > r.occlusion
    # the paper's regime is level PAPER_LEVEL of the knob, between robot and hard
    p = PRESETS["paper"]
    assert p.catalogue and p.robot == domain_at_level(PAPER_LEVEL).robot and 1 < PAPER_LEVEL < 2
    assert (
        r.noise[1] < p.robot.noise[1] < h.noise[1] and r.occlusion < p.robot.occlusion < h.occlusion
    )
    with pytest.raises(ValueError, match="preset"):
        SyntheticConfig.for_profile("quick", "foggy")
    with pytest.raises(ValueError, match="unknown nuisance parameters"):
        Nuisance.from_dict({"fog": 1})
    # a description written before domains existed reads as the clean domain
    old = SyntheticConfig.for_profile("tiny").to_dict()
    del old["domain"]
    assert SyntheticConfig.from_dict(old) == SyntheticConfig.for_profile("tiny")


def test_cache_folders_of_presets_differ(tmp_path, monkeypatch):
    from scrppl.cli._common import dataset_root

    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path))
    names = {
        p: dataset_root(SimpleNamespace(root=None, profile="quick", seed=1, preset=p)).name
        for p in PRESET_NAMES
    }
    assert names["clean"] == "synthetic-quick-seed1"  # the folder of datasets made before presets
    assert len(set(names.values())) == len(PRESET_NAMES)


def test_dataset_records_its_domain_and_trains_on_catalogue_images_only(tmp_path):
    from scrppl.detectors.base import training_images

    cfg = dataclasses.replace(
        config("robot"), categories=("mouse", "toaster"), grid=ViewGrid(8, (25.0,), (1.4,))
    )
    ds = make_synthetic(tmp_path / "robot", cfg, SEED, workers=1, progress=False)
    assert ds.meta["config"]["domain"] == PRESETS["robot"].to_dict()
    saved = json.loads((tmp_path / "robot" / "dataset.json").read_text())
    assert saved["meta"]["config"]["domain"]["name"] == "robot"
    # another preset never reuses the folder
    with pytest.raises(ValueError, match="another configuration"):
        make_synthetic(tmp_path / "robot", dataclasses.replace(cfg, domain="hard"), SEED, workers=1)
    pos, neg = training_images(ds, "mouse", split="train")
    train = set(ds.select(split="train")[["category", "instance"]].itertuples(index=False))
    assert {(t.category, t.instance) for t in pos + neg} <= train

    def top_variation(img):
        return float(img[:8].astype(float).std(axis=1).max())

    # catalogue images: a plain backdrop at the top of the image, unlike the robot's rooms
    assert max(top_variation(t.image) for t in pos + neg) < 6.0
    held = ds.select(split=["fit", "test"])
    robot_var = [top_variation(ds.load_image(r)) for _, r in held.iterrows()]
    assert np.median(robot_var) > 12.0


def test_pipeline_passes_the_preset_to_every_command(tmp_path):
    from scrppl.cli import main
    from scrppl.pipeline import stages

    robot_stages = stages(
        tmp_path / "data", tmp_path / "out", seed=0, profile="quick", preset="robot"
    )
    for stage in robot_stages:
        for argv in stage.argv:
            if "--profile" in argv:
                assert argv[argv.index("--preset") + 1] == "robot"
    clean_stages = stages(tmp_path / "data", tmp_path / "out", seed=0, profile="quick")
    assert all("--preset" not in argv for st in clean_stages for argv in st.argv)
    with pytest.raises(SystemExit):
        main(["reproduce", "--preset", "foggy"])


# -- the difficulty knob -----------------------------------------------------------------------------
def test_levels_one_and_two_are_the_presets_and_level_zero_has_no_nuisance():
    from scrppl.datasets.synthetic.domain import domain_at_level

    assert domain_at_level(1) == PRESETS["robot"] and Domain.at_level(1.0) == PRESETS["robot"]
    assert domain_at_level(2) == PRESETS["hard"] and Domain.at_level(2.0) == PRESETS["hard"]
    zero = domain_at_level(0)
    assert zero.catalogue and zero.robot == Nuisance() and zero.robot.is_clean
    assert zero.robot.light_kelvin is None and zero.robot.jpeg_quality is None
    assert zero.name == "level-0" and domain_at_level(0.5).name == "level-0p5"
    # every level trains on the catalogue images
    assert all(domain_at_level(x).catalogue for x in np.linspace(0, 2, 9))


def test_level_between_anchors_is_the_endpointwise_linear_mix():
    from scrppl.datasets.synthetic.domain import domain_at_level

    r, h = PRESETS["robot"].robot.to_dict(), PRESETS["hard"].robot.to_dict()
    got = domain_at_level(1.25).robot.to_dict()
    for name, a in r.items():
        b = h[name]
        if isinstance(a, list):
            want = [0.75 * x + 0.25 * y for x, y in zip(a, b, strict=True)]
            if name in ("distractors", "jpeg_quality"):  # integers, rounded half up
                want = [int(np.floor(w + 0.5)) for w in want]
            np.testing.assert_allclose(got[name], want, err_msg=name)
        else:
            np.testing.assert_allclose(got[name], 0.75 * a + 0.25 * b, err_msg=name)
    # below level 1 from the neutral values: no noise, the camera's JPEG 85-95, 5500 K
    half = domain_at_level(0.5).robot
    assert half.noise == (1.0, 3.0) and half.jpeg_quality == (60, 88)
    assert half.light_kelvin == (4150.0, 6750.0) and half.far_resolution == pytest.approx(0.8)
    assert half.occlusion == pytest.approx(0.15) and half.distractors == (1, 2)  # 0.5 rounds up
    # a range gated by a zero probability at level 0 keeps the robot preset's range below level 1
    assert half.occlusion_fraction == PRESETS["robot"].robot.occlusion_fraction


def test_every_nuisance_parameter_is_monotone_in_the_level():
    from scrppl.datasets.synthetic.domain import domain_at_level

    levels = np.linspace(0.0, 2.0, 81)
    rows = [domain_at_level(x).robot.to_dict() for x in levels]
    gated = {"distractor_size", "occlusion_fraction", "truncation_fraction"}
    for name in rows[0]:
        # None (level 0 only) and the gated ranges (inert at level 0) are compared above level 0
        series = rows[1:] if name in gated or rows[0][name] is None else rows
        values = np.array([np.atleast_1d(np.asarray(v[name], float)) for v in series])
        for col in values.T:
            d = np.diff(col)
            assert (d >= -1e-12).all() or (d <= 1e-12).all(), name
    # and harder means more of every effect
    assert rows[-1]["noise"][1] > rows[40]["noise"][1] > rows[20]["noise"][1] > rows[0]["noise"][1]


@pytest.mark.parametrize("level", [-0.1, 2.5, "hard", None])
def test_invalid_level_names_itself(level):
    from scrppl.datasets.synthetic.domain import domain_at_level

    with pytest.raises(ValueError, match="difficulty level"):
        domain_at_level(level)


def test_splits_option_renders_the_same_images_of_those_instances_only(tmp_path):
    cfg = SyntheticConfig(
        categories=("mouse",), n_instances=3, grid=ViewGrid(4, (25.0,), (1.0,)), width=W,
        height=H, domain="robot",
    )  # fmt: skip
    full = make_synthetic(tmp_path / "full", cfg, SEED, workers=1, progress=False)
    part = make_synthetic(
        tmp_path / "part", cfg, SEED, workers=1, progress=False, splits=("test", "fit")
    )
    assert "splits" not in full.meta and part.meta["splits"] == ["fit", "test"]
    held = full.index[full.index["split"] != "train"].reset_index(drop=True)
    assert len(part.index) == len(held) == 8 and set(part.index["split"]) == {"fit", "test"}
    for col in ("category", "instance", "azimuth", "split", "image", "x0", "y0", "x1", "y1"):
        assert part.index[col].tolist() == held[col].tolist(), col
    for rel in held["image"]:
        assert (tmp_path / "part" / rel).read_bytes() == (tmp_path / "full" / rel).read_bytes()
    assert not any(
        (tmp_path / "part" / rel).exists()
        for rel in full.index["image"]
        if rel not in set(held["image"])
    )
    # complete: loaded, not rendered again; the folder never passes for the whole dataset
    again = make_synthetic(tmp_path / "part", cfg, SEED, workers=1, splits=["fit", "test"])
    assert again.index.equals(part.index)
    with pytest.raises(ValueError, match="another configuration"):
        make_synthetic(tmp_path / "part", cfg, SEED, workers=1)
    with pytest.raises(ValueError, match="splits"):
        make_synthetic(tmp_path / "x", cfg, SEED, workers=1, splits=("holdout",))
