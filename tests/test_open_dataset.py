"""`open_dataset` on both layouts, every command on a Savarese tree, and `reproduce` on one end to end."""

import json
from pathlib import Path

import cv2
import pytest
from test_cli_dataset import make_fixture_dataset
from test_savarese import view_box, write_tree

from scrppl.cli import main
from scrppl.cli.reproduce import stages
from scrppl.datasets import MultiviewDataset, dataset_layout, open_dataset
from scrppl.datasets.core import assign_splits, write_ascii_mask
from scrppl.pipeline import uses_existing_dataset
from scrppl.views import SAVARESE_GRID


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def quirky_tree(root: Path) -> Path:
    """A Savarese tree with the quirks of the real one.

    car: capitalised file prefix, 3 instances x 8 azimuths at H1 S1, one view (A5 of car_2) missing;
    head: lower-case prefix, 3 instances x 8 azimuths at H1 S1 and H2 S1; stray files everywhere.
    """
    one_height = [(a, 1, 1) for a in range(1, 9)]
    write_tree(root, {"car": ("Car", [1, 2, 3], one_height)})
    write_tree(
        root, {"head": ("head", [1, 2, 3], [(a, h, 1) for a in range(1, 9) for h in (1, 2)])}
    )
    (root / "car/car_2/Car_2_A5_H1_S1.bmp").unlink()
    (root / "car/car_2/mask/Car_2_A5_H1_S1.mask").unlink()  # a missing view
    (root / "README.txt").write_text("3D Object Category dataset")
    (root / "car/car_1/Thumbs.db").write_bytes(b"junk")
    (root / "car/car_1/._Car_1_A1_H1_S1.bmp").write_bytes(b"\x00\x05")
    (root / "head/list.txt").write_text("head_1 head_2 head_3")
    return root


@pytest.fixture(scope="module")
def savarese_root(tmp_path_factory):
    return quirky_tree(tmp_path_factory.mktemp("savarese-copy"))


# -- recognising the layout -------------------------------------------------------------------------
def test_layout_of_each_kind_of_folder(tmp_path, savarese_root):
    assert dataset_layout(savarese_root) == "savarese"
    assert dataset_layout(tmp_path / "missing") is None
    assert dataset_layout(tmp_path) is None  # empty
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "photos").mkdir()  # folders, but no <cat>_<N> instance folder
    assert dataset_layout(tmp_path) is None
    fixture = make_fixture_dataset(tmp_path / "fixture")
    assert dataset_layout(fixture.root) == "index"  # a saved index of another source
    fixture.meta["generator"] = "scrppl.datasets.synthetic"
    fixture.save()
    assert dataset_layout(fixture.root) == "synthetic"
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / "synthetic.json").write_text("{}")
    assert dataset_layout(partial) == "unfinished-synthetic"


def test_open_dataset_on_a_savarese_tree(savarese_root):
    ds = open_dataset(savarese_root, split_seed=5, progress=False)
    assert ds.name == "savarese" and ds.grid == SAVARESE_GRID
    assert ds.categories == ["car", "head"]
    assert len(ds) == 3 * 8 - 1 + 3 * 16
    assert ds.summary()["missing_views"] == 6 * 72 - len(ds)
    with pytest.raises(KeyError):
        ds.row("car", 1, 4)  # the missing view is absent, not invented
    r = ds.row("head", 2, 3, 1, 0)
    assert r["image"] == "head/head_3/head_3_A4_H2_S1.bmp"
    assert ds.bbox(r) == view_box(3, 4, 2, 1)
    labels = assign_splits(5, {"car": [0, 1, 2], "head": [0, 1, 2]})
    assert all(ds.split_of(c, i) == s for (c, i), s in labels.items())


def test_open_dataset_on_a_saved_index(tmp_path):
    saved = make_fixture_dataset(tmp_path, split_seed=7)
    ds = open_dataset(tmp_path, split_seed=99)  # a saved index keeps its own splits
    assert ds.name == "fixture" and ds.index.equals(saved.index)


def test_open_dataset_on_the_tiny_synthetic_cache(tmp_path):
    """The synthetic cache as make_synthetic writes it (index + provenance), without rendering."""
    saved = make_fixture_dataset(tmp_path)
    saved.meta.update(generator="scrppl.datasets.synthetic", seed=0, render_version=1)
    saved.name = "synthetic"
    saved.save()
    (tmp_path / "synthetic.json").write_text(json.dumps({"generator": "scrppl.datasets.synthetic"}))
    ds = open_dataset(tmp_path)
    assert ds.name == "synthetic" and len(ds) == len(saved)


@pytest.mark.parametrize(
    ("folder", "error", "words"),
    [
        ("missing", FileNotFoundError, ["does not exist", "scrppl dataset make"]),
        ("empty", ValueError, ["no dataset", "index.csv", "_A<a>_H<h>_S<s>"]),
        ("unfinished", ValueError, ["unfinished synthetic", "scrppl dataset make"]),
    ],
)
def test_open_dataset_errors_name_the_folder_and_the_layouts(tmp_path, folder, error, words):
    root = tmp_path / folder
    if folder != "missing":
        root.mkdir()
        (root / "notes.txt").write_text("not a dataset")
    if folder == "unfinished":
        (root / "synthetic.json").write_text("{}")
    with pytest.raises(error) as err:
        open_dataset(root)
    assert str(root) in str(err.value)
    for w in words:
        assert w in str(err.value)


def test_open_dataset_names_the_broken_file_of_a_savarese_tree(tmp_path):
    write_tree(tmp_path, {"car": ("Car", [1], [(a, 1, 1) for a in range(1, 9)])})
    (tmp_path / "car/car_1/mask/Car_1_A3_H1_S1.mask").unlink()
    with pytest.raises(FileNotFoundError, match="Car_1_A3_H1_S1") as err:
        open_dataset(tmp_path, progress=False)
    assert "read as a copy of the Savarese dataset" in str(err.value)


# -- the commands on a Savarese tree ----------------------------------------------------------------
def test_make_refuses_a_savarese_tree_and_writes_nothing(savarese_root, capsys):
    before = sorted(p.relative_to(savarese_root) for p in savarese_root.rglob("*"))
    code, _, err = run(["dataset", "make", "--root", savarese_root, "--profile", "tiny"], capsys)
    assert code == 1
    assert "copy of the Savarese dataset" in err and "only generates" in err
    assert "Traceback" not in err
    assert sorted(p.relative_to(savarese_root) for p in savarese_root.rglob("*")) == before


def test_reproduce_uses_a_savarese_tree_instead_of_generating(savarese_root, tmp_path):
    import argparse

    args = argparse.Namespace(root=savarese_root, out=tmp_path, seed=2, profile="quick")
    assert uses_existing_dataset(savarese_root)
    chain = stages(args)
    commands = [argv[:2] for argv in chain[0].argv]
    assert commands == [("dataset", "info"), ("dataset", "sheet")]
    assert ("--seed", "2") == chain[0].argv[0][-2:]
    assert chain[1].inputs == (savarese_root,)  # detect reruns when the tree changes
    # the synthetic cache is still generated (and resumed) by `dataset make`
    args.root = tmp_path / "cache"
    assert not uses_existing_dataset(args.root)
    assert stages(args)[0].argv[0][:2] == ("dataset", "make")


def test_a_savarese_tree_with_a_saved_index_or_a_foreign_dataset_json(tmp_path, capsys):
    """The folder of the bug report: a Savarese copy holding a dataset.json is used, never generated into."""
    root = quirky_tree(tmp_path / "copy")
    (root / "dataset.json").write_text('{"note": "written by another tool"}')
    assert dataset_layout(root) == "savarese" and uses_existing_dataset(root)
    (root / "dataset.json").unlink()
    open_dataset(root, split_seed=3, progress=False).save()  # an index saved beside the images
    assert dataset_layout(root) == "index" and uses_existing_dataset(root)
    ds = open_dataset(root)
    assert ds.name == "savarese" and ds.meta["split_seed"] == 3 and len(ds) == 71
    code, _, err = run(["dataset", "make", "--root", root, "--profile", "tiny"], capsys)
    assert code == 1 and "saved dataset index" in err and "another configuration" not in err


# -- end to end -------------------------------------------------------------------------------------
def savarese_copy_of(dataset: MultiviewDataset, root: Path, prefixes: dict[str, str]) -> Path:
    """Write a saved (synthetic) dataset's views into the Savarese layout: ``.bmp`` and ASCII masks.

    View ``(a, e, s)`` becomes ``<Prefix>_<i+1>_A<a+1>_H<e+1>_S<s+1>``; ``prefixes`` gives each
    category's file prefix (the real dataset mixes ``Car_1_...`` and ``head_1_...``).
    """
    for _, r in dataset.index.iterrows():
        c, n = r["category"], int(r["instance"]) + 1
        folder = root / c / f"{c}_{n}"
        (folder / "mask").mkdir(parents=True, exist_ok=True)
        stem = f"{prefixes[c]}_{n}_A{r['azimuth'] + 1}_H{r['elevation'] + 1}_S{r['scale'] + 1}"
        img = dataset.load_image(r)
        assert cv2.imwrite(str(folder / f"{stem}.bmp"), img[:, :, ::-1])
        write_ascii_mask(folder / "mask" / f"{stem}.mask", dataset.load_mask(r))
    return root


@pytest.fixture(scope="module")
def rendered_trees(tmp_path_factory):
    """2 categories x 4 instances x 8 azimuths rendered (~7 s): the synthetic cache and its Savarese copy."""
    from scrppl.datasets.synthetic import SyntheticConfig, make_synthetic
    from scrppl.views import ViewGrid

    config = SyntheticConfig(
        categories=("bicycle", "mouse"), n_instances=4, grid=ViewGrid(8, (10.0,), (1.0,))
    )
    rendered = make_synthetic(
        tmp_path_factory.mktemp("renders"), config, 0, workers=1, progress=False
    )
    root = tmp_path_factory.mktemp("savarese-renders")
    savarese_copy_of(rendered, root, {"bicycle": "Bicycle", "mouse": "mouse"})
    (root / "README.txt").write_text("a stray file")
    return rendered.root, root


def add_download_quirks(root: Path) -> tuple[set[Path], set[tuple[str, int, int]]]:
    """Give a Savarese copy of the rendered trees the quirks of a real download.

    A missing view (image and mask gone), a JPEG cut to half its bytes (OpenCV would decode it), a mask
    that is not UTF-8 text, and stray files; all in instances of the training split (with one fit and
    one test instance per category, the fit needs every view of its instance and the simulator a
    complete azimuth ring). Returns the bad files and the views ``(category, instance,
    azimuth)`` (0-based) that must not be used: the missing and the bad ones.
    """
    (root / "bicycle/bicycle_1/Bicycle_1_A8_H1_S1.bmp").unlink()
    (root / "bicycle/bicycle_1/mask/Bicycle_1_A8_H1_S1.mask").unlink()
    bmp = root / "bicycle/bicycle_4/Bicycle_4_A3_H1_S1.bmp"
    jpg = bmp.with_suffix(".jpg")
    assert cv2.imwrite(str(jpg), cv2.imread(str(bmp)))
    bmp.unlink()
    jpg.write_bytes(jpg.read_bytes()[: jpg.stat().st_size // 2])
    mask = root / "mouse/mouse_2/mask/mouse_2_A6_H1_S1.mask"
    mask.write_bytes(mask.read_bytes().replace(b"1", b"\xb9", 1))
    (root / "bicycle/bicycle_1/Thumbs.db").write_bytes(b"junk")
    (root / "mouse/mouse_2/._mouse_2_A1_H1_S1.bmp").write_bytes(b"\x00\x05")
    (root / "mouse/list.txt").write_text("mouse_1 mouse_2")
    return {jpg, mask}, {("bicycle", 0, 7), ("bicycle", 3, 2), ("mouse", 1, 5)}


@pytest.mark.slow
def test_reproduce_quick_on_a_savarese_tree(rendered_trees, tmp_path, capsys, monkeypatch):
    """`scrppl reproduce --profile quick --root <Savarese tree>`: no generation, every stage, the report.

    The tree has the quirks of a real download (case, stray files, a missing view, a truncated JPEG, a
    mask that is not UTF-8): the bad files are reported and every valid image is used.
    """
    from scrppl.cli import fit, simulate
    from scrppl.datasets.problems import read_problems

    synthetic_root, root = rendered_trees
    # the same views through both layouts: the synthetic cache and its Savarese copy
    assert (dataset_layout(synthetic_root), dataset_layout(root)) == ("synthetic", "savarese")
    cache, copy = open_dataset(synthetic_root), open_dataset(root, split_seed=1, progress=False)
    assert (cache.name, copy.name) == ("synthetic", "savarese") and len(copy) == len(cache) == 64
    view = ["category", "instance", "azimuth", "elevation", "scale", "x0", "y0", "x1", "y1"]
    assert copy.index[view].equals(cache.index[view])  # boxes from the ASCII masks agree

    bad, unused = add_download_quirks(root)
    valid = cache.index[
        [
            (c, i, a) not in unused
            for c, i, a in cache.index[["category", "instance", "azimuth"]].values
        ]
    ]
    assert len(valid) == 64 - 3

    # a smoke run of the pipeline, not of the statistics: short chains, few trials
    monkeypatch.setitem(fit.PROFILE_DRAWS, "quick", (60, 60))
    quick = {"trials": 16, "large_trials": 0, "n_samples": 16, "max_draws": 4}
    monkeypatch.setitem(
        simulate.PROFILE_SETTINGS, "quick", {**simulate.PROFILE_SETTINGS["quick"], **quick}
    )
    out = tmp_path / "results"
    argv = ["reproduce", "--profile", "quick", "--root", root, "--out", out, "--seed", "1"]
    code, stdout, err = run(argv, capsys)
    assert code == 0, err
    assert f"using the dataset at {root}" in stdout
    assert not (root / "index.csv").exists() and not (root / "synthetic.json").exists()
    # the problems: printed as a table, written beside the outputs, one per bad file
    problems = read_problems(out / "dataset-problems.csv")
    assert {p.path for p in problems} == bad
    assert {p.path.name: p.artefact for p in problems} == {
        "Bicycle_4_A3_H1_S1.jpg": "image",
        "mouse_2_A6_H1_S1.mask": "mask",
    }
    assert "bicycle/bicycle_4/Bicycle_4_A3_H1_S1.jpg" in err and "truncated JPEG" in err
    # nothing valid dropped: every valid view of the held-out instances (the splits scrppl detect
    # scores), and only those, was scored
    from scrppl.responses import load_response_table

    table = load_response_table(out / "responses.nc")
    assert sorted(str(t) for t in table["target"].values) == ["bicycle", "mouse"]
    assert sorted(set(table["category"].values.astype(str).ravel())) == ["bicycle", "mouse"]
    scored = table["score"].isel(detector=0, target=0).notnull()
    split = table["split"]  # the Savarese copy's own split (seed 1), not the synthetic cache's
    held = valid[
        [
            str(split.sel(category=c, instance=i).values) in ("fit", "test")
            for c, i in valid[["category", "instance"]].values
        ]
    ]
    assert 0 < len(held) < len(valid) and int(scored.sum()) == len(held)
    for c, i, a, e, s in held[["category", "instance", "azimuth", "elevation", "scale"]].values:
        assert bool(scored.sel(category=c, instance=i, azimuth=a, elevation=e, scale=s))
    diagnostics = json.loads((out / "models" / "diagnostics.json").read_text())
    assert {"sift/mouse", "bof/bicycle", "dpm/mouse"} <= set(diagnostics)
    assert (out / "trials.nc").exists()
    report = (out / "report.md").read_text()
    assert "savarese" in report
    assert (
        "2 file(s) of the dataset could not be used" in report and "mouse_2_A6_H1_S1.mask" in report
    )
    assert cv2.imread(str(out / "figures" / "dataset-sheet.png")) is not None
    run_info = json.loads((out / "run.json").read_text())
    assert Path(run_info["dataset_root"]) == root.resolve()
    # a second run finds every stage current
    code, stdout, _ = run(argv, capsys)
    assert code == 0
    assert ": running" not in stdout and stdout.count("up to date, skipped") >= 4
    # with --errors raise the first bad file stops the run, named
    code, _, err = run(
        ["detect", "--root", root, "--out", tmp_path / "strict", "--errors", "raise", "--quiet"],
        capsys,
    )
    assert code == 1 and ("Bicycle_4_A3_H1_S1.jpg" in err or "mouse_2_A6_H1_S1.mask" in err)


def test_detect_opens_a_savarese_tree(savarese_root, tmp_path, capsys):
    """detect needs no index.csv: it opens the tree, and a bad --targets is named against its categories."""
    argv = ["detect", "--root", savarese_root, "--out", tmp_path, "--targets", "toaster", "--quiet"]
    code, _, err = run(argv, capsys)
    assert code == 1
    assert "unknown category 'toaster'" in err and "'car', 'head'" in err
    assert "index.csv" not in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


def test_detect_without_a_dataset_says_how_to_make_one(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path / "cache"))
    code, _, err = run(["detect", "--profile", "quick", "--seed", "4", "--out", tmp_path], capsys)
    assert code == 1
    assert str(tmp_path / "cache" / "synthetic-quick-seed4") in err
    assert "scrppl dataset make --profile quick --seed 4" in err
