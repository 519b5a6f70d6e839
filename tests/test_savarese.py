"""The Savarese loader on fixture trees written here in the dataset's exact naming, and on broken trees."""

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from scrppl.datasets.core import SPLITS, assign_splits, read_ascii_mask, write_ascii_mask
from scrppl.datasets.savarese import _read_mask, load_savarese, parse_view_name
from scrppl.views import SAVARESE_GRID

H, W = 24, 32  # image rows, columns


def view_colour(inst: int, a: int, h: int, s: int) -> tuple[int, int, int]:
    """The RGB colour of the fixture image of one view (1-based numbers as in the file name)."""
    return (20 * a, 60 * h + inst, 70 * s)


def view_box(inst: int, a: int, h: int, s: int) -> tuple[int, int, int, int]:
    """The half-open box (x0, y0, x1, y1) of the fixture mask of one view (1-based numbers)."""
    x0, y0 = a + inst, h + 2 * s
    return x0, y0, x0 + 10 + s, y0 + 6 + h


def write_view(
    folder: Path, prefix: str, inst: int, a: int, h: int, s: int, ext=".bmp", mask_ext=".mask"
) -> Path:
    """Write one image (numpy-drawn, cv2) and its ASCII mask in Savarese naming; return the image path."""
    stem = f"{prefix}_{inst}_A{a}_H{h}_S{s}"
    img = np.empty((H, W, 3), np.uint8)
    img[:] = view_colour(inst, a, h, s)
    x0, y0, x1, y1 = view_box(inst, a, h, s)
    img[y0:y1, x0:x1] = 255 - img[y0:y1, x0:x1]
    path = folder / f"{stem}{ext}"
    folder.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img[:, :, ::-1])
    mask = np.zeros((H, W), bool)
    mask[y0:y1, x0:x1] = True
    (folder / "mask").mkdir(exist_ok=True)
    write_ascii_mask(folder / "mask" / f"{stem}{mask_ext}", mask)
    return path


def write_tree(root: Path, spec: dict) -> Path:
    """Write a Savarese-layout tree.

    ``spec``: ``{category_folder: (file_prefix, instance_numbers, views)}`` with 1-based
    ``views = [(a, h, s), ...]``.
    """
    for cat, (prefix, instances, views) in spec.items():
        for n in instances:
            for a, h, s in views:
                write_view(root / cat / f"{cat}_{n}", prefix, n, a, h, s)
    return root


def all_views(heights=(1, 2, 3)):
    return list(itertools.product(range(1, 9), heights, range(1, 4)))


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """car (capitalised prefix, 3 heights) and head (lower-case prefix, only 2 heights), 3 instances each."""
    root = tmp_path_factory.mktemp("savarese")
    return write_tree(
        root,
        {
            "car": ("Car", [1, 2, 3], all_views()),
            "head": ("head", [1, 2, 3], all_views(heights=(1, 2))),
        },
    )


def small_tree(root: Path, views=None) -> Path:
    """One category, one instance, the 8 azimuths at H1 S1: the base of the broken-tree tests."""
    views = views or [(a, 1, 1) for a in range(1, 9)]
    return write_tree(root, {"car": ("Car", [1], views)})


# -- parsing --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("stem", "expected"),
    [
        ("Car_1_A1_H1_S1", ("Car", 0, 0, 0, 0)),
        ("bicycle_10_A8_H3_S3", ("bicycle", 9, 7, 2, 2)),
        ("cellphone_4_a5_h2_s1", ("cellphone", 3, 4, 1, 0)),
        ("my_cat_2_A3_H2_S3", ("my_cat", 1, 2, 1, 2)),
    ],
)
def test_parse_view_name(stem, expected):
    assert parse_view_name(stem) == expected


@pytest.mark.parametrize(
    ("stem", "match"),
    [
        ("Car_1_A1_H1", "malformed"),
        ("Car_A1_H1_S1", "malformed"),
        ("Car_1_A1_H1_S1_copy", "malformed"),
        ("Car_x_A1_H1_S1", "malformed"),
        ("Car_0_A1_H1_S1", "instance number"),
        ("Car_1_A0_H1_S1", "azimuth"),
        ("Car_1_A9_H1_S1", "azimuth"),
        ("Car_1_A1_H4_S1", "height"),
        ("Car_1_A1_H0_S1", "height"),
        ("Car_1_A1_H1_S4", "scale"),
    ],
)
def test_parse_view_name_rejects(stem, match):
    with pytest.raises(ValueError, match=match) as err:
        parse_view_name(stem)
    assert stem in str(err.value)


# -- the fixture tree -----------------------------------------------------------------------------
def test_loads_fixture_tree(tree):
    ds = load_savarese(tree, split_seed=4, progress=False)
    assert ds.name == "savarese" and ds.grid == SAVARESE_GRID
    assert ds.categories == ["car", "head"]
    assert ds.n_instances("car") == 3 and ds.n_instances("head") == 3
    assert len(ds) == 3 * 72 + 3 * 48
    s = ds.summary()
    assert s["missing_views"] == 3 * 24  # head's third height is recorded as missing
    assert ds.select(category="head", elevation=2).empty
    assert len(ds.select(category="car", elevation=2)) == 3 * 24
    assert sorted(ds.index["instance"].unique()) == [0, 1, 2]
    # splits: assign_splits on the instances found, every split non-empty per category
    labels = assign_splits(4, {"car": [0, 1, 2], "head": [0, 1, 2]})
    for c in ("car", "head"):
        for i in range(3):
            assert ds.split_of(c, i) == labels[(c, i)]
        assert {ds.split_of(c, i) for i in range(3)} == set(SPLITS)
    # file names: the prefix as written on disk
    r = ds.row("car", 1, 4, 2, 0)
    assert r["image"] == "car/car_2/Car_2_A5_H3_S1.bmp"
    assert r["mask"] == "car/car_2/mask/Car_2_A5_H3_S1.mask"


def test_views_map_to_grid_indices_and_boxes(tree):
    """Every row's pixels and box are the ones written for its 1-based (N, A, H, S)."""
    ds = load_savarese(tree, progress=False)
    for _, r in ds.index.iterrows():
        n, a, h, s = (int(r[k]) + 1 for k in ("instance", "azimuth", "elevation", "scale"))
        assert ds.bbox(r) == view_box(n, a, h, s)
        assert tuple(int(r[k]) for k in ("x0", "y0", "x1", "y1")) == view_box(n, a, h, s)
    for _, r in ds.index.sample(12, random_state=0).iterrows():
        n, a, h, s = (int(r[k]) + 1 for k in ("instance", "azimuth", "elevation", "scale"))
        img = ds.load_image(r)
        assert tuple(img[0, 0]) == view_colour(n, a, h, s)
        m = ds.load_mask(r)
        x0, y0, x1, y1 = view_box(n, a, h, s)
        assert m.sum() == (x1 - x0) * (y1 - y0)


def test_without_validation_boxes_are_lazy(tree):
    full = load_savarese(tree, progress=False)
    lazy = load_savarese(tree, validate=False, progress=False)
    assert (lazy.index[["x0", "y0", "x1", "y1"]] == -1).all().all()
    cols = ["category", "instance", "azimuth", "elevation", "scale", "split", "image", "mask"]
    assert lazy.index[cols].equals(full.index[cols])
    assert lazy.meta["validated"] is False and full.meta["validated"] is True
    for k in (0, 100, 300):
        assert lazy.bbox(lazy.index.iloc[k]) == full.bbox(full.index.iloc[k])


def test_extension_case_ignored_files_and_mask_variants(tmp_path):
    folder = tmp_path / "mouse" / "mouse_2"
    write_view(folder, "Mouse", 2, 1, 1, 1, ext=".BMP", mask_ext=".txt")
    write_view(folder, "mouse", 2, 2, 1, 1, ext=".png", mask_ext=".MASK")
    write_view(folder, "MOUSE", 2, 3, 2, 3, ext=".jpg")
    # things that are not views: hidden resource forks, notes, other folders, stray masks, root files
    (folder / "._Mouse_2_A1_H1_S1.bmp").write_bytes(b"\x00\x05\x16\x07")
    (folder / "Thumbs.db").write_bytes(b"junk")
    (folder / "notes.txt").write_text("taken on a turntable")
    (folder / "mask" / "Mouse_2_A7_H1_S1.mask").write_text("1 1\n1\n")
    (tmp_path / "README.txt").write_text("dataset")
    (tmp_path / ".cache").mkdir()
    (tmp_path / "mouse" / "list.txt").write_text("mouse_2")
    ds = load_savarese(tmp_path, progress=False)
    assert len(ds) == 3 and ds.categories == ["mouse"]
    assert ds.instances["instance"].tolist() == [1]
    assert sorted(
        zip(ds.index["azimuth"], ds.index["elevation"], ds.index["scale"], strict=True)
    ) == [
        (0, 0, 0),
        (1, 0, 0),
        (2, 1, 2),
    ]
    assert ds.index["image"].str.endswith((".BMP", ".png", ".jpg")).all()
    assert ds.bbox(ds.index.iloc[2]) == view_box(2, 3, 2, 3)


def test_fast_mask_reader_agrees_with_read_ascii_mask(tmp_path, rng):
    for k, shape in enumerate([(1, 1), (5, 3), (40, 60)]):
        path = tmp_path / f"m{k}.mask"
        vals = rng.choice([0, 1, 255], size=shape)
        path.write_text(f"{shape[0]} {shape[1]}\n" + "\n".join(" ".join(map(str, r)) for r in vals))
        assert np.array_equal(_read_mask(path), read_ascii_mask(path))
    # the fast path for 0/1 masks: as written by write_ascii_mask, on one line, with CRLF and tabs
    for k, mask in enumerate([rng.random((30, 50)) < 0.3, np.ones((2, 3), bool)]):
        path = tmp_path / f"b{k}.mask"
        write_ascii_mask(path, mask)
        assert np.array_equal(_read_mask(path), mask)
        flat = " ".join(path.read_text().split())
        path.write_text(flat)
        assert np.array_equal(_read_mask(path), mask)
        path.write_bytes(flat.replace(" ", "\t").encode() + b"\r\n")
        assert np.array_equal(_read_mask(path), mask)
    # multi-character tokens are numbers, not digits: "10 01" is two non-zero values
    path = tmp_path / "multi.mask"
    path.write_text("1 3\n10 01 0\n")
    assert _read_mask(path).tolist() == read_ascii_mask(path).tolist() == [[True, True, False]]
    bad = tmp_path / "bad_one.mask"
    bad.write_text("2 2\n1 0 q 1\n")
    with pytest.raises(ValueError, match="bad_one.mask"):
        _read_mask(bad)
    short = tmp_path / "short_one.mask"
    short.write_text("2 2\n1 0 1\n")
    with pytest.raises(ValueError, match="short_one.mask"):
        _read_mask(short)


# -- broken trees: each a clear error naming the file ---------------------------------------------
def test_missing_root(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_savarese(tmp_path / "nowhere")


def test_root_without_categories(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="no category folders"):
        load_savarese(tmp_path)


def test_missing_mask(tmp_path):
    small_tree(tmp_path)
    (tmp_path / "car/car_1/mask/Car_1_A3_H1_S1.mask").unlink()
    with pytest.raises(FileNotFoundError, match="Car_1_A3_H1_S1"):
        load_savarese(tmp_path, progress=False)


def test_missing_mask_folder(tmp_path):
    small_tree(tmp_path)
    for p in (tmp_path / "car/car_1/mask").iterdir():
        p.unlink()
    (tmp_path / "car/car_1/mask").rmdir()
    with pytest.raises(FileNotFoundError, match="mask") as err:
        load_savarese(tmp_path, validate=False)
    assert "car_1" in str(err.value)


@pytest.mark.parametrize(
    "name",
    [
        "Car_1_A1_H1.bmp",  # no scale
        "Car_1_A1_H1_S1_copy.bmp",  # trailing text
        "Car_1_A1-H1-S1.bmp",  # wrong separators
        "Car_one_A1_H1_S1.bmp",  # instance not a number
        "Car_1_A9_H1_S1.bmp",  # azimuth out of range
        "Car_1_A0_H1_S1.bmp",
        "Car_1_A1_H4_S1.bmp",  # height out of range
        "Car_1_A1_H1_S5.bmp",  # scale out of range
        "Car_2_A1_H2_S1.bmp",  # another instance's image in this folder
        "Bicycle_1_A1_H2_S1.bmp",  # another category's image
        "IMG_0042.JPG",  # a camera file name
    ],
)
def test_malformed_or_misplaced_image_name(tmp_path, name):
    small_tree(tmp_path)
    folder = tmp_path / "car/car_1"
    src = folder / "Car_1_A1_H1_S1.bmp"
    (folder / name).write_bytes(src.read_bytes())
    stem = Path(name).stem
    (folder / "mask" / f"{stem}.mask").write_bytes(
        (folder / "mask/Car_1_A1_H1_S1.mask").read_bytes()
    )
    with pytest.raises(ValueError) as err:
        load_savarese(tmp_path, validate=False)
    assert name in str(err.value)


@pytest.mark.parametrize("name", ["car1", "car_", "bicycle_1", "car_0", "Car_x"])
def test_malformed_instance_folder(tmp_path, name):
    small_tree(tmp_path)
    write_view(tmp_path / "car" / name, "Car", 1, 1, 2, 1)
    with pytest.raises(ValueError, match="instance folder") as err:
        load_savarese(tmp_path, validate=False)
    assert name in str(err.value)


def test_same_instance_in_two_folders(tmp_path):
    small_tree(tmp_path)
    write_view(tmp_path / "car" / "Car_1", "Car", 1, 1, 2, 1)
    with pytest.raises(ValueError, match="two folders"):
        load_savarese(tmp_path, validate=False)


def test_report_mode_leaves_out_an_instance_found_in_two_folders(tmp_path):
    """Catches report mode loading an instance found in two folders (``car_1`` and ``car_01``, both
    instance 1): neither folder may be used, the clash is reported once, and the other instances load."""
    write_tree(tmp_path, {"car": ("Car", [1, 2], [(a, 1, 1) for a in range(1, 9)])})
    write_view(tmp_path / "car" / "car_01", "Car", 1, 1, 2, 1)  # instance 1 again, another view
    ds = load_savarese(tmp_path, errors="report", progress=False)
    # instance 2 only (0-based 1): nothing of instance 1
    assert sorted(set(ds.index["instance"])) == [1]
    assert len(ds) == 8 and (ds.index["elevation"] == 0).all()
    assert len(ds.problems) == 1
    (problem,) = ds.problems
    assert problem.artefact == "instance folder" and problem.path.parent == tmp_path / "car"
    assert problem.path.name in ("car_1", "car_01")
    assert "car_1" in problem.message and "car_01" in problem.message


def test_empty_category_folder(tmp_path):
    small_tree(tmp_path)
    (tmp_path / "iron").mkdir()
    (tmp_path / "iron" / "readme.txt").write_text("to do")
    with pytest.raises(ValueError, match="empty category folder") as err:
        load_savarese(tmp_path, validate=False)
    assert "iron" in str(err.value)


def test_empty_instance_folder(tmp_path):
    small_tree(tmp_path)
    (tmp_path / "car/car_2/mask").mkdir(parents=True)
    with pytest.raises(ValueError, match="empty instance folder") as err:
        load_savarese(tmp_path, validate=False)
    assert "car_2" in str(err.value)


def test_unreadable_image(tmp_path):
    small_tree(tmp_path)
    bad = tmp_path / "car/car_1/Car_1_A6_H1_S1.bmp"
    bad.write_bytes(b"BM" + bytes(40))  # a header that does not decode
    with pytest.raises(ValueError, match="Car_1_A6_H1_S1.bmp"):
        load_savarese(tmp_path, progress=False)
    # without validation the name checks pass and the error comes when the image is used
    ds = load_savarese(tmp_path, validate=False)
    row = ds.row("car", 0, 5, 0, 0)
    with pytest.raises(ValueError, match="Car_1_A6_H1_S1.bmp"):
        ds.load_image(row)


def test_view_listed_twice(tmp_path):
    small_tree(tmp_path)
    # the same view again as a lower-case .jpg (sharing the existing mask)
    write_view(tmp_path / "car/car_1", "car", 1, 4, 1, 1, ext=".jpg", mask_ext=".txt")
    (tmp_path / "car/car_1/mask/car_1_A4_H1_S1.txt").unlink()
    with pytest.raises(ValueError, match="twice") as err:
        load_savarese(tmp_path, validate=False)
    assert "car_1_A4_H1_S1.jpg" in str(err.value) and "Car_1_A4_H1_S1.bmp" in str(err.value)


def test_two_masks_for_one_image(tmp_path):
    small_tree(tmp_path)
    mask_dir = tmp_path / "car/car_1/mask"
    (mask_dir / "Car_1_A2_H1_S1.txt").write_bytes((mask_dir / "Car_1_A2_H1_S1.mask").read_bytes())
    with pytest.raises(ValueError, match="two mask files") as err:
        load_savarese(tmp_path, validate=False)
    assert "Car_1_A2_H1_S1" in str(err.value)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (f"{H} {W + 1}\n" + " ".join(["1"] * (H * (W + 1))), "is 24x33"),  # wrong size
        (f"{H} {W}\n" + " ".join(["0"] * (H * W)), "empty"),  # no object pixel
        (f"{H} {W}\n1 0 1\n", "malformed"),  # truncated
    ],
)
def test_bad_mask_content(tmp_path, content, match):
    small_tree(tmp_path)
    (tmp_path / "car/car_1/mask/Car_1_A7_H1_S1.mask").write_text(content)
    with pytest.raises(ValueError, match=match) as err:
        load_savarese(tmp_path, progress=False)
    assert "Car_1_A7_H1_S1.mask" in str(err.value)
    load_savarese(tmp_path, validate=False)  # names are fine: only validation reads the mask
