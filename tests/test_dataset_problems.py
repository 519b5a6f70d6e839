"""Bad files in a dataset: truncated images are detected, and the Savarese loader's ``errors="report"``
loads every valid image and names every bad file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from test_savarese import H, W, view_box, write_tree, write_view

from scrppl.datasets import (
    MultiviewDataset,
    Problem,
    format_problems,
    open_dataset,
    read_problems,
    write_problems,
)
from scrppl.datasets.core import assign_splits, read_ascii_mask
from scrppl.datasets.images import decode_image, image_defect, read_image
from scrppl.datasets.savarese import load_savarese


# -- complete or truncated ------------------------------------------------------------------------
def encoded(ext: str, params=(), gray=False, width=56) -> bytes:
    y, x = np.mgrid[0:40, 0:width]
    img = np.stack([x * 4 % 256, y * 6 % 256, (x + y) % 256], -1).astype(np.uint8)
    ok, buf = cv2.imencode(ext, img[:, :, 0] if gray else img, list(params))
    assert ok
    return buf.tobytes()


def with_thumbnail_marker(jpeg: bytes) -> bytes:
    """An APP1 (EXIF-like) segment whose payload holds an end-of-image marker, as thumbnails do."""
    payload = b"Exif\x00\x00\xff\xd8\xff\xd9"
    return jpeg[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + jpeg[2:]


FILES = {
    "baseline jpeg": lambda: encoded(".jpg"),
    "progressive jpeg": lambda: encoded(".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
    "jpeg with restart markers": lambda: encoded(".jpg", [cv2.IMWRITE_JPEG_RST_INTERVAL, 1]),
    "jpeg with a thumbnail": lambda: with_thumbnail_marker(encoded(".jpg")),
    "png": lambda: encoded(".png"),
    "grey png": lambda: encoded(".png", gray=True),
    "bmp": lambda: encoded(".bmp"),
    "grey bmp": lambda: encoded(".bmp", gray=True),
    # rows padded to 4 bytes: 5 x 3 = 15 bytes -> 16, 7 x 3 = 21 -> 24, 5 x 1 = 5 -> 8 (a check that
    # forgets the padding accepts files cut inside the last rows' padding)
    "bmp 5 pixels wide": lambda: encoded(".bmp", width=5),
    "bmp 7 pixels wide": lambda: encoded(".bmp", width=7),
    "grey bmp 5 pixels wide": lambda: encoded(".bmp", gray=True, width=5),
}


def rejected(data: bytes) -> bool:
    try:
        decode_image(data, cv2.IMREAD_UNCHANGED)
    except ValueError:
        return True
    return False


@pytest.mark.parametrize("name", FILES)
def test_every_truncation_is_detected(name):
    """Brute force: the whole file passes (with bytes appended too), every strict prefix fails.

    The BMPs of odd widths catch a BMP check that ignores row padding (row stride taken as
    ``width * bytes per pixel`` instead of rounded up to 4 bytes).

    Prefixes long enough to show the format's signature are caught by the structure check itself;
    shorter ones do not decode.
    """
    data = FILES[name]()
    assert image_defect(data) is None
    assert image_defect(data + b"\x00" * 9) is None  # padding after the end is allowed
    np.testing.assert_array_equal(
        decode_image(data, cv2.IMREAD_UNCHANGED),
        cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED),
    )
    assert [k for k in range(8, len(data)) if image_defect(data[:k]) is None] == []
    assert [k for k in range(len(data)) if not rejected(data[:k])] == []


def test_opencv_decodes_half_a_jpeg_silently_but_read_image_refuses_it(tmp_path):
    """The reason for the check: cv2.imread returns a full-size image for half a JPEG."""
    y, x = np.mgrid[0:240, 0:320]
    img = np.stack([x % 256, y % 256, (x + y) % 256], -1).astype(np.uint8)
    data = cv2.imencode(".jpg", img)[1].tobytes()
    path = tmp_path / "Car_1_A1_H1_S1.jpg"
    path.write_bytes(data[: len(data) // 2])
    assert cv2.imread(str(path)).shape == (240, 320, 3)  # libjpeg warns on stderr, naming no file
    with pytest.raises(ValueError, match="truncated JPEG") as err:
        read_image(path)
    assert str(path) in str(err.value)


def test_corrupt_png_chunk_and_not_an_image(tmp_path):
    data = bytearray(encoded(".png"))
    data[60] ^= 0xFF  # inside the first data chunk: its CRC no longer matches
    assert "CRC" in image_defect(bytes(data))
    assert image_defect(b"") == "empty file (0 bytes)"
    assert image_defect(b"GIF89a....") is None  # formats without a check are only decoded
    (tmp_path / "x.png").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="x.png"):
        read_image(tmp_path / "x.png")
    (tmp_path / "y.jpg").write_bytes(b"not an image at all")
    with pytest.raises(ValueError, match=r"not a decodable image\): .*y.jpg"):
        read_image(tmp_path / "y.jpg")
    with pytest.raises(FileNotFoundError, match="missing"):
        read_image(tmp_path / "z.png")


def test_read_image_equals_imread_on_complete_files(tmp_path):
    """Also when the extension lies (a PNG named .jpg): the format is told by the file's signature."""
    for ext, name in ((".jpg", "x.jpg"), (".png", "x.png"), (".bmp", "x.bmp"), (".png", "png.JPG")):
        path = tmp_path / name
        path.write_bytes(encoded(ext))
        np.testing.assert_array_equal(read_image(path), cv2.imread(str(path)))


def test_mask_that_is_not_utf8_names_the_file(tmp_path):
    path = tmp_path / "Car_1_A1_H1_S1.mask"
    path.write_bytes(b"2 2\n0 1\n1 \xe9\n")
    with pytest.raises(ValueError, match=r"not a text file \(byte 0xE9 at offset 10") as err:
        read_ascii_mask(path)
    assert str(path) in str(err.value)


# -- the loader ------------------------------------------------------------------------------------
def quirky_tree(root: Path) -> tuple[Path, dict[Path, str], set[tuple]]:
    """A Savarese tree with the quirks of a real download, and what is wrong with it.

    Returns the root, ``{bad path: artefact}`` and the set of valid views ``(category, instance, a, h, s)``
    (0-based instance, 1-based view numbers as in the file names).
    """
    views = [(a, 1, 1) for a in range(1, 9)]
    write_tree(root, {"car": ("Car", [1, 2, 3], views), "head": ("head", [1, 2, 3], views)})
    valid = {(c, n - 1, *v) for c in ("car", "head") for n in (1, 2, 3) for v in views}
    bad: dict[Path, str] = {}

    def drop(cat, n, a):
        valid.discard((cat, n - 1, a, 1, 1))

    # a missing view (image and mask gone): absent, not a problem
    (root / "car/car_2/Car_2_A5_H1_S1.bmp").unlink()
    (root / "car/car_2/mask/Car_2_A5_H1_S1.mask").unlink()
    drop("car", 2, 5)
    # a JPEG cut to half its bytes (OpenCV would decode it)
    jpg = write_view(root / "car/car_1", "Car", 1, 3, 1, 1, ext=".jpg")
    (root / "car/car_1/Car_1_A3_H1_S1.bmp").unlink()
    jpg.write_bytes(jpg.read_bytes()[: jpg.stat().st_size // 2])
    bad[jpg] = "image"
    drop("car", 1, 3)
    # a mask that is not UTF-8 text, a mask of the wrong size, a missing mask
    m = root / "head/head_1/mask/head_1_A2_H1_S1.mask"
    m.write_bytes(m.read_bytes().replace(b"1", b"\xb9", 1))
    bad[m] = "mask"
    drop("head", 1, 2)
    m = root / "head/head_2/mask/head_2_A7_H1_S1.mask"
    m.write_text(f"{H} {W + 2}\n" + " ".join(["1"] * (H * (W + 2))))
    bad[m] = "mask"
    drop("head", 2, 7)
    (root / "head/head_3/mask/head_3_A8_H1_S1.mask").unlink()
    bad[root / "head/head_3/head_3_A8_H1_S1.bmp"] = "image"
    drop("head", 3, 8)
    # a misnamed image, an image of another instance, an empty instance folder
    bad[root / "car/car_3/Car_3_A9_H1_S1.bmp"] = "image"
    (root / "car/car_3/Car_3_A9_H1_S1.bmp").write_bytes(
        (root / "car/car_3/Car_3_A1_H1_S1.bmp").read_bytes()
    )
    write_view(root / "car/car_3", "Car", 2, 6, 1, 1)  # Car_2_... in car_3
    bad[root / "car/car_3/Car_2_A6_H1_S1.bmp"] = "image"
    (root / "head/head_4/mask").mkdir(parents=True)
    bad[root / "head/head_4"] = "instance folder"
    # stray files everywhere: ignored
    (root / "README.txt").write_text("3D Object Category dataset")
    (root / "car/car_1/Thumbs.db").write_bytes(b"junk")
    (root / "car/car_1/._Car_1_A1_H1_S1.bmp").write_bytes(b"\x00\x05")
    (root / "head/list.txt").write_text("head_1 head_2 head_3")
    (root / "car/car_1/mask/notes.doc").write_bytes(b"\xff\xfe")
    return root, bad, valid


@pytest.fixture(scope="module")
def quirky(tmp_path_factory):
    return quirky_tree(tmp_path_factory.mktemp("quirky"))


def test_report_loads_every_valid_image_and_names_every_bad_file(quirky):
    root, bad, valid = quirky
    ds = load_savarese(root, split_seed=4, errors="report", progress=False)
    found = {
        (r.category, r.instance, r.azimuth + 1, r.elevation + 1, r.scale + 1)
        for r in ds.index.itertuples()
    }
    assert found == valid and len(ds) == len(valid)  # nothing valid dropped, nothing bad kept
    for r in ds.index.itertuples():  # the boxes come from the (valid) masks
        assert (r.x0, r.y0, r.x1, r.y1) == view_box(r.instance + 1, r.azimuth + 1, 1, 1)
    assert {p.path: p.artefact for p in ds.problems} == bad  # one problem per bad file, each named
    assert all(isinstance(p, Problem) and p.message for p in ds.problems)
    messages = {p.path.name: p.message for p in ds.problems}
    assert "truncated JPEG" in messages["Car_1_A3_H1_S1.jpg"]
    assert "not a text file" in messages["head_1_A2_H1_S1.mask"]
    assert "24x34" in messages["head_2_A7_H1_S1.mask"]
    assert "missing mask" in messages["head_3_A8_H1_S1.bmp"]
    assert "out of range" in messages["Car_3_A9_H1_S1.bmp"]
    # splits are those of the instance folders found, whatever failed to decode
    assert all(
        ds.split_of(c, i) == s
        for (c, i), s in assign_splits(4, {"car": [0, 1, 2], "head": [0, 1, 2]}).items()
    )


def test_report_without_validation_finds_the_naming_problems_only(quirky):
    root, bad, valid = quirky
    ds = load_savarese(root, validate=False, errors="report")
    names = {p.path for p in ds.problems}
    assert names == {p for p, a in bad.items() if p.suffix != ".mask" and p.suffix != ".jpg"}
    assert len(ds) == len(valid) + 3  # the truncated image and the two bad masks are not read yet


def test_raise_stops_at_the_first_problem_naming_it(quirky):
    root, bad, _ = quirky
    with pytest.raises((ValueError, FileNotFoundError)) as err:
        load_savarese(root, progress=False)
    assert any(str(p) in str(err.value) for p in bad)


def test_open_dataset_passes_errors_on(quirky, tmp_path):
    root, bad, valid = quirky
    ds = open_dataset(root, errors="report", progress=False)
    assert len(ds) == len(valid) and len(ds.problems) == len(bad)
    with pytest.raises(ValueError, match="errors must be one of"):
        open_dataset(root, errors="ignore")
    with pytest.raises(ValueError, match="read as a copy of the Savarese dataset"):
        open_dataset(root, errors="raise", progress=False)
    assert ds.with_splits(1).problems == ds.problems


def test_a_tree_without_a_usable_image_is_an_error_in_report_mode_too(tmp_path):
    write_tree(tmp_path, {"car": ("Car", [1], [(1, 1, 1), (2, 1, 1)])})
    for p in (tmp_path / "car/car_1/mask").iterdir():
        p.write_bytes(b"\xff")
    with pytest.raises(ValueError, match="no usable image") as err:
        load_savarese(tmp_path, errors="report", progress=False)
    assert "Car_1_A1_H1_S1.mask" in str(err.value)


def test_problems_table_and_file(tmp_path, quirky):
    root, bad, _ = quirky
    ds = load_savarese(root, errors="report", progress=False)
    path = write_problems(ds.problems, tmp_path / "dataset-problems.csv")
    assert read_problems(path) == list(ds.problems)
    text = format_problems(ds.problems, root=root)
    lines = text.splitlines()
    assert lines[0].split() == ["file", "artefact", "problem"] and len(lines) == 2 + len(bad)
    assert "car/car_1/Car_1_A3_H1_S1.jpg" in text and str(root) not in text
    short = format_problems(ds.problems, limit=2)
    assert short.splitlines()[-1] == f"... and {len(bad) - 2} more"
    assert isinstance(ds, MultiviewDataset)
