"""`scrppl dataset make | info | sheet` and the dataset figures, on numpy-drawn fixture datasets."""

import json
import sys
import types
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from scrppl.cli import main
from scrppl.cli._common import DEFAULT_PRESETS
from scrppl.datasets.core import MultiviewDataset, assign_splits, write_ascii_mask
from scrppl.views import ViewGrid

GRID = ViewGrid(8, (10.0,), (1.0,))
CATEGORIES = ("car", "mouse", "shoe")
N_INSTANCES = 3
H, W = 30, 40


def draw(category_k: int, instance: int, a: int) -> tuple[np.ndarray, np.ndarray]:
    """An RGB image whose object (a rectangle) moves with the azimuth, and its mask."""
    img = np.full((H, W, 3), (40 + 60 * category_k, 90, 30 * instance), np.uint8)
    mask = np.zeros((H, W), bool)
    x0, y0 = 2 + 3 * a, 5 + category_k
    mask[y0 : y0 + 12, x0 : x0 + 10 + instance] = True
    img[mask] = (250, 250 - 25 * a, 20)
    return img, mask


def make_fixture_dataset(root: Path, split_seed: int = 0) -> MultiviewDataset:
    """A saved scrppl dataset (index.csv + dataset.json) with PNG images and masks."""
    rows = []
    for k, c in enumerate(CATEGORIES):
        for i in range(N_INSTANCES):
            folder = root / c / f"{c}_{i + 1}"
            (folder / "mask").mkdir(parents=True, exist_ok=True)
            for a in range(GRID.n_azimuth):
                stem = f"{c}_{i + 1}_A{a + 1}_H1_S1"
                img, mask = draw(k, i, a)
                cv2.imwrite(str(folder / f"{stem}.png"), img[:, :, ::-1])
                cv2.imwrite(str(folder / "mask" / f"{stem}.png"), mask.astype(np.uint8) * 255)
                ys, xs = np.nonzero(mask)
                rows.append(
                    dict(
                        category=c,
                        instance=i,
                        azimuth=a,
                        elevation=0,
                        scale=0,
                        split="train",
                        image=f"{c}/{c}_{i + 1}/{stem}.png",
                        mask=f"{c}/{c}_{i + 1}/mask/{stem}.png",
                        x0=xs.min(),
                        y0=ys.min(),
                        x1=xs.max() + 1,
                        y1=ys.max() + 1,
                    )
                )
    ds = MultiviewDataset(root, pd.DataFrame(rows), GRID, "fixture").with_splits(split_seed)
    ds.save()
    return ds


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("fixture-dataset")
    make_fixture_dataset(root, split_seed=7)
    return root


def write_savarese_instance(root: Path, category: str, n: int, heights=(1,)) -> None:
    """One Savarese-layout instance folder (capitalised prefix, .bmp, ASCII masks), all azimuths."""
    folder = root / category / f"{category}_{n}"
    (folder / "mask").mkdir(parents=True, exist_ok=True)
    for a in range(1, 9):
        for h in heights:
            stem = f"{category.capitalize()}_{n}_A{a}_H{h}_S1"
            img, mask = draw(0, n, a - 1)
            cv2.imwrite(str(folder / f"{stem}.bmp"), img[:, :, ::-1])
            write_ascii_mask(folder / "mask" / f"{stem}.mask", mask)


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


# -- info -----------------------------------------------------------------------------------------
def test_info_json(dataset_root, capsys):
    code, out, _ = run(["dataset", "info", "--root", str(dataset_root), "--json"], capsys)
    assert code == 0
    info = json.loads(out)
    assert info["categories"] == list(CATEGORIES)
    assert info["n_categories"] == 3
    assert info["instances"] == len(CATEGORIES) * N_INSTANCES
    assert info["images"] == len(CATEGORIES) * N_INSTANCES * 8
    assert (info["azimuths"], info["elevations"], info["scales"]) == (8, 1, 1)
    assert info["missing_views"] == 0
    assert info["per_category"] == {
        c: {"instances": N_INSTANCES, "images": N_INSTANCES * 8, "missing_views": 0}
        for c in CATEGORIES
    }
    labels = assign_splits(7, {c: range(N_INSTANCES) for c in CATEGORIES})
    for split in ("train", "fit", "test"):
        for c in CATEGORIES:
            expected = [i for i in range(N_INSTANCES) if labels[(c, i)] == split]
            assert info["splits"][split][c] == expected


def test_info_text(dataset_root, capsys):
    code, out, _ = run(["dataset", "info", "--root", str(dataset_root)], capsys)
    assert code == 0
    assert "3 categories, 9 instances, 72 images (0 missing views)" in out
    assert "8 azimuths x 1 elevations" in out
    for c in CATEGORIES:
        assert any(line.split()[:3] == [c, "24", "0"] for line in out.splitlines())


def test_info_on_a_savarese_folder(tmp_path, capsys):
    """Without index.csv the folder is read as the Savarese layout; --seed is its split seed.

    The validation progress bar goes to stderr, so stdout stays valid JSON.
    """
    for n in (1, 2, 3):
        write_savarese_instance(tmp_path, "stapler", n, heights=(1, 2))
    code, out, err = run(
        ["dataset", "info", "--root", str(tmp_path), "--json", "--seed", "3"], capsys
    )
    assert code == 0
    assert "checking Savarese images" in err
    info = json.loads(out)
    assert info["name"] == "savarese"
    assert info["categories"] == ["stapler"] and info["instances"] == 3
    assert info["images"] == 3 * 16
    assert info["missing_views"] == 3 * 72 - 3 * 16
    assert info["per_category"]["stapler"] == {
        "instances": 3,
        "images": 48,
        "missing_views": 3 * 72 - 48,
    }
    labels = assign_splits(3, {"stapler": [0, 1, 2]})
    assert info["splits"]["test"]["stapler"] == [
        i for i in range(3) if labels[("stapler", i)] == "test"
    ]


def test_info_on_a_broken_savarese_folder_names_the_file(tmp_path, capsys):
    write_savarese_instance(tmp_path, "iron", 1)
    (tmp_path / "iron/iron_1/mask/Iron_1_A5_H1_S1.mask").unlink()
    argv = ["dataset", "info", "--root", str(tmp_path), "--no-progress"]
    code, _, err = run([*argv, "--errors", "raise"], capsys)
    assert code == 1
    assert "Iron_1_A5_H1_S1" in err and "Traceback" not in err
    assert "no index.csv" in err  # says how the folder was read
    # by default the bad file is reported, and every other image used
    code, out, err = run([*argv, "--json"], capsys)
    assert code == 0
    info = json.loads(out)
    assert info["images"] == 7 and len(info["problems"]) == 1
    problem = info["problems"][0]
    assert (
        Path(problem["path"]).name == "Iron_1_A5_H1_S1.bmp" and "missing mask" in problem["message"]
    )
    assert "1 file(s) of the dataset" in err and "iron/iron_1/Iron_1_A5_H1_S1.bmp" in err


def test_info_on_an_unfinished_synthetic_folder(dataset_root, tmp_path, capsys):
    """Images with PNG masks but no index yet (an interrupted make): an error, with the way out."""
    import shutil

    shutil.copytree(dataset_root / "car", tmp_path / "car")
    code, _, err = run(["dataset", "info", "--root", str(tmp_path)], capsys)
    assert code == 1
    assert "missing mask" in err and "car_1_A1_H1_S1" in err
    assert "scrppl dataset make" in err


@pytest.mark.parametrize("command", ["info", "sheet"])
def test_missing_root_is_a_clear_error(tmp_path, capsys, command):
    missing = tmp_path / "no-such-dataset"
    argv = ["dataset", command, "--root", str(missing)]
    if command == "sheet":
        argv += ["--out", str(tmp_path)]
    code, _, err = run(argv, capsys)
    assert code == 1
    assert str(missing) in err
    assert "scrppl dataset make" in err
    assert "Traceback" not in err
    assert not (tmp_path / "figures").exists()


def test_default_root_comes_from_the_cache_variable(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path / "cache"))
    code, _, err = run(["dataset", "info", "--profile", "quick", "--seed", "5"], capsys)
    assert code == 1
    assert str(tmp_path / "cache" / "synthetic-quick-seed5") in err
    # and a dataset found there is used
    make_fixture_dataset(tmp_path / "cache" / "synthetic-tiny-seed2")
    code, out, _ = run(["dataset", "info", "--profile", "tiny", "--seed", "2", "--json"], capsys)
    assert code == 0 and json.loads(out)["images"] == 72


# -- help -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("sub", ["make", "info", "sheet"])
def test_help_of_each_subcommand(sub, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dataset", sub, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for option in ("--root", "--seed", "--profile"):
        assert option in out
    assert "tiny" in out
    if sub == "make":
        assert "--workers" in out and "--no-progress" in out
    if sub == "info":
        assert "--json" in out
    if sub == "sheet":
        assert "--out" in out


def test_help_of_dataset_and_no_subcommand(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dataset", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert all(word in out for word in ("make", "info", "sheet"))
    assert main(["dataset"]) == 2
    assert "make" in capsys.readouterr().out


# -- make -----------------------------------------------------------------------------------------
def test_make_passes_profile_seed_workers_and_progress(tmp_path, capsys, monkeypatch):
    """The handler's wiring to scrppl.datasets.synthetic, with that module replaced by a recorder."""
    calls = []

    class SyntheticConfig:
        @classmethod
        def for_profile(cls, name, preset="clean"):
            return ("config", name) if preset == "clean" else ("config", name, preset)

    def make_synthetic(root, config, seed=0, *, workers=None, progress=True):
        calls.append((Path(root), config, seed, workers, progress))
        return make_fixture_dataset(Path(root))

    fake = types.ModuleType("scrppl.datasets.synthetic")
    fake.SyntheticConfig, fake.make_synthetic = SyntheticConfig, make_synthetic
    monkeypatch.setitem(sys.modules, "scrppl.datasets.synthetic", fake)
    root = tmp_path / "made"
    code, out, _ = run(
        ["dataset", "make", "--root", str(root), "--profile", "tiny", "--seed", "9",
         "--workers", "2", "--no-progress"],
        capsys,
    )  # fmt: skip
    assert code == 0
    assert calls == [(root, ("config", "tiny"), 9, 2, False)]
    assert "72 images" in out
    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path / "cache"))
    # the full profile's default preset is the paper's regime, in its own cache folder
    default = DEFAULT_PRESETS["full"]
    assert default != "clean"
    assert main(["dataset", "make"]) == 0
    assert calls[-1] == (
        tmp_path / "cache" / f"synthetic-full-{default}-seed0",
        ("config", "full", default),
        0,
        None,
        True,
    )
    # the clean preset keeps the folder name datasets had before presets existed
    assert main(["dataset", "make", "--preset", "clean"]) == 0
    assert calls[-1][:2] == (tmp_path / "cache" / "synthetic-full-seed0", ("config", "full"))
    # the smaller profiles render the clean images by default
    assert main(["dataset", "make", "--profile", "book"]) == 0
    assert calls[-1][:2] == (tmp_path / "cache" / "synthetic-book-seed0", ("config", "book"))


def test_the_parser_and_the_generator_agree_on_default_presets():
    from scrppl.datasets.synthetic.config import DEFAULT_PRESETS as generator_defaults
    from scrppl.datasets.synthetic.config import default_preset

    for profile, preset in DEFAULT_PRESETS.items():
        assert generator_defaults[profile] == preset == default_preset(profile)
    assert default_preset("full", "hard") == "hard"
    with pytest.raises(ValueError, match="profile"):
        default_preset("huge")


# -- sheet and figures ----------------------------------------------------------------------------
def test_sheet_writes_pngs(dataset_root, tmp_path, capsys):
    out_dir = tmp_path / "results"
    code, out, _ = run(
        ["dataset", "sheet", "--root", str(dataset_root), "--out", str(out_dir)], capsys
    )
    assert code == 0
    for name in ("dataset-sheet.png", "view-sphere.png"):
        path = out_dir / "figures" / name
        assert str(path) in out
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = cv2.imread(str(path))
        assert img is not None and img.shape[0] > 200 and img.shape[1] > 400
        assert img.std() > 10  # not a blank canvas
    assert sorted(p.name for p in (out_dir / "figures").iterdir()) == [
        "dataset-sheet.png",
        "view-sphere.png",
    ]  # no temporary files left behind


def test_sheet_bad_options_are_clear_errors(dataset_root, tmp_path, capsys):
    base = ["dataset", "sheet", "--root", str(dataset_root), "--out", str(tmp_path)]
    code, _, err = run([*base, "--instance", "7"], capsys)
    assert code == 1 and "instance 7" in err
    code, _, err = run([*base, "--elevation", "2"], capsys)
    assert code == 1 and "elevation" in err
    code, _, err = run([*base, "--category", "plane"], capsys)
    assert code == 1 and "plane" in err


def test_contact_sheet_layout(dataset_root):
    import matplotlib.pyplot as plt

    from scrppl.plotting.dataset import contact_sheet, sheet_instances

    ds = MultiviewDataset.load(dataset_root)
    chosen = sheet_instances(ds)
    labels = assign_splits(7, {c: range(N_INSTANCES) for c in CATEGORIES})
    for c in CATEGORIES:  # the first test instance of each category
        assert chosen[c] == min(i for i in range(N_INSTANCES) if labels[(c, i)] == "test")
    assert sheet_instances(ds, 2) == dict.fromkeys(CATEGORIES, 2)
    assert sheet_instances(ds, {"shoe": 1}) == {"shoe": 1}
    with pytest.raises(KeyError, match="instance 5"):
        sheet_instances(ds, 5)

    fig = contact_sheet(ds, instance=1)
    axes = fig.axes
    assert len(axes) == len(CATEGORIES) * 8
    # row r, column a shows instance 1 of category r at azimuth a
    for r in range(len(CATEGORIES)):
        for a in range(8):
            shown = axes[r * 8 + a].get_images()[0].get_array()
            assert np.array_equal(np.asarray(shown), draw(r, 1, a)[0])
    assert axes[0].get_title().startswith("A1") and axes[2].get_title().startswith("A3  90")
    assert axes[8].get_ylabel().startswith("mouse")
    plt.close(fig)

    # a missing view is a labelled grey panel, not an invented image
    index = ds.index[~((ds.index["category"] == "car") & (ds.index["azimuth"] == 3))]
    holed = MultiviewDataset(ds.root, index, ds.grid, ds.name)
    fig = contact_sheet(holed, instance=0, categories=["car"])
    assert len(fig.axes) == 8
    assert fig.axes[3].get_images() == [] and fig.axes[3].texts[0].get_text() == "missing"
    plt.close(fig)


def test_view_sphere_and_camera_positions(tmp_path):
    import matplotlib.pyplot as plt

    from scrppl.plotting.dataset import camera_positions, show_image, view_sphere

    grid = ViewGrid()
    xyz = camera_positions(grid, base_distance=2.0)
    assert xyz.shape == (8, 3, 3, 3)
    # azimuth 0 looks at the front (+x), azimuth 2 (90 deg) at the left side (+y)
    el = np.deg2rad(10.0)
    np.testing.assert_allclose(xyz[0, 0, 0], [2 * np.cos(el), 0, 2 * np.sin(el)], atol=1e-12)
    np.testing.assert_allclose(xyz[2, 0, 0], [0, 2 * np.cos(el), 2 * np.sin(el)], atol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(xyz, axis=-1), 2.0 * np.broadcast_to(grid.scales, (8, 3, 3))
    )

    # a 2-instance dataset on the full 72-view grid, with one height missing for one instance
    rows = []
    (tmp_path / "img").mkdir()
    img, mask = draw(0, 0, 0)
    cv2.imwrite(str(tmp_path / "img/a.png"), img[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "img/m.png"), mask.astype(np.uint8) * 255)
    for a, e, s in grid.all_views():
        if e == 2:
            continue
        rows.append(dict(category="toaster", instance=0, azimuth=a, elevation=e, scale=s,
                         split="test", image="img/a.png", mask="img/m.png",
                         x0=-1, y0=-1, x1=-1, y1=-1))  # fmt: skip
    ds = MultiviewDataset(tmp_path, pd.DataFrame(rows), grid)
    fig = view_sphere(ds, "toaster", 0)
    three_d = [ax for ax in fig.axes if ax.name == "3d"]
    thumbs = [ax for ax in fig.axes if ax.name != "3d"]
    assert len(three_d) == 1 and len(thumbs) == 72
    n_images = sum(len(ax.get_images()) for ax in thumbs)
    assert n_images == 48
    assert sum(t.get_text() == "missing" for ax in thumbs for t in ax.texts) == 24
    plt.close(fig)
    with pytest.raises(KeyError):
        view_sphere(ds, "toaster", 4)

    ax = show_image(ds, ds.index.iloc[0])
    assert len(ax.patches) == 1  # the box
    x0, y0, x1, y1 = ds.bbox(ds.index.iloc[0])
    rect = ax.patches[0]
    assert (rect.get_width(), rect.get_height()) == (x1 - x0, y1 - y0)
    shown = np.asarray(ax.get_images()[0].get_array())
    assert not np.array_equal(shown, img)  # the mask is tinted
    assert np.array_equal(shown[~mask], img[~mask])
    plt.close(ax.figure)


def test_show_image_draws_the_proto_object_window(dataset_root):
    """``window=margin`` adds a dashed rectangle exactly where proto_object_window cuts the crop."""
    import matplotlib.pyplot as plt

    from scrppl.detectors import proto_object_window
    from scrppl.plotting.dataset import show_image

    ds = MultiviewDataset.load(dataset_root)
    # boxes near the left (a = 0) and the right (a = 7) edge: the window is clipped
    for k in (0, 7):
        row = ds.index.iloc[k]
        ax = show_image(ds, row, window=1.0)
        assert len(ax.patches) == 2  # the box, then the window
        crop, (cx, cy) = proto_object_window(ds.load_image(row), ds.bbox(row), margin=1.0)
        win = ax.patches[1]
        assert win.get_xy() == (cx - 0.5, cy - 0.5)
        assert (win.get_width(), win.get_height()) == (crop.shape[1], crop.shape[0])
        assert win.get_linestyle() == "--"
        x0, y0, x1, y1 = ds.bbox(row)
        assert cx <= x0 and cy <= y0 and cx + crop.shape[1] >= x1 and cy + crop.shape[0] >= y1
        assert cx + crop.shape[1] <= W and cy + crop.shape[0] <= H
        assert cx == 0 or cx + crop.shape[1] == W  # clipped to the image
        plt.close(ax.figure)
    ax = show_image(ds, ds.index.iloc[0], box=False, mask=False, title=False)
    assert not ax.patches and not ax.get_title()
    plt.close(ax.figure)


def test_show_images_lays_out_panels(dataset_root):
    import matplotlib.pyplot as plt

    from scrppl.plotting.dataset import show_images

    ds = MultiviewDataset.load(dataset_root)
    rows = ds.select(category="car", azimuth=3)
    fig = show_images(ds, rows, ncols=2, window=0.15, mask=False)
    axes = fig.axes
    assert len(axes) == 4 and [ax.get_visible() for ax in axes] == [True, True, True, False]
    for ax, (_, row) in zip(axes, rows.iterrows(), strict=False):
        assert ax.get_title().startswith(f"car #{row['instance']}")
        assert len(ax.patches) == 2  # box and window
    plt.close(fig)
    fig = show_images(ds, rows.iloc[:2], box=False, title=False)
    assert len(fig.axes) == 2 and not any(ax.patches for ax in fig.axes)
    plt.close(fig)
    with pytest.raises(ValueError, match="empty"):
        show_images(ds, rows.iloc[:0])


# -- the real synthetic generator, end to end -----------------------------------------------------
@pytest.mark.slow
def test_make_info_sheet_on_the_tiny_synthetic_profile(tmp_path, capsys):
    """`make --profile tiny` renders 3 categories x 2 instances x 8 azimuths; info and sheet read it.

    One worker: on 2 busy cores, starting a second rendering process costs more than it saves here.
    """
    root, out_dir = tmp_path / "tiny", tmp_path / "results"
    make = ["dataset", "make", "--profile", "tiny", "--root", str(root), "--seed", "1"]
    make += ["--workers", "1", "--no-progress"]
    code, _, _ = run(make, capsys)
    assert code == 0
    code, out, _ = run(["dataset", "info", "--root", str(root), "--json"], capsys)
    assert code == 0
    info = json.loads(out)
    assert (info["n_categories"], info["instances"], info["images"]) == (3, 6, 48)
    assert (info["azimuths"], info["elevations"], info["scales"]) == (8, 1, 1)
    assert info["missing_views"] == 0
    for c in info["categories"]:
        assert len(info["splits"]["test"][c]) >= 1
    ds = MultiviewDataset.load(root)
    first = ds.index.iloc[0]
    assert (root / first["image"]).exists() and (root / first["mask"]).exists()
    img = ds.load_image(first)
    assert img.shape[:2] == (240, 320)
    x0, y0, x1, y1 = ds.bbox(first)
    assert 0 <= x0 < x1 <= 320 and 0 <= y0 < y1 <= 240
    # a second make with the same profile and seed loads what is there, rendering nothing
    stamp = (root / first["image"]).stat().st_mtime_ns
    code, _, _ = run(make, capsys)
    assert code == 0 and (root / first["image"]).stat().st_mtime_ns == stamp
    code, _, _ = run(["dataset", "sheet", "--root", str(root), "--out", str(out_dir)], capsys)
    assert code == 0
    assert cv2.imread(str(out_dir / "figures" / "dataset-sheet.png")) is not None
    assert cv2.imread(str(out_dir / "figures" / "view-sphere.png")) is not None
