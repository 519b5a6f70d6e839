import argparse
import json
import os
import time

import pytest

from scrppl._io import atomic_path, default_cache_dir
from scrppl.cli import build_parser, main
from scrppl.cli.reproduce import stages
from scrppl.pipeline import Stage, is_current
from scrppl.report import write_report


def test_atomic_path_replaces_on_success(tmp_path):
    target = tmp_path / "sub" / "x.json"
    with atomic_path(target) as tmp:
        assert tmp.suffix == ".json" and tmp.parent == target.parent and tmp != target
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert [p.name for p in target.parent.iterdir()] == ["x.json"]


def test_atomic_path_keeps_old_file_when_body_fails(tmp_path):
    target = tmp_path / "x.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(target) as tmp:
            tmp.write_text("half-written")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]  # no temporary left behind


def test_cache_dir_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("SCRPPL_CACHE", str(tmp_path / "c"))
    assert default_cache_dir() == tmp_path / "c"


def test_is_current_compares_modification_times(tmp_path):
    inp, outp = tmp_path / "in", tmp_path / "out"
    stage = Stage("s", "m", (), (inp,), (outp,))
    assert not is_current(stage)  # output missing
    inp.write_text("a")
    outp.write_text("b")
    now = time.time()
    os.utime(inp, (now - 10, now - 10))
    os.utime(outp, (now, now))
    assert is_current(stage)
    os.utime(inp, (now + 10, now + 10))  # input changed after the output was made
    assert not is_current(stage)


def test_pipeline_stages_chain_outputs_to_inputs(tmp_path):
    args = argparse.Namespace(
        root=tmp_path / "data", out=tmp_path / "out", seed=3, profile="quick", strict=True
    )
    chain = stages(args)
    assert [s.name for s in chain] == ["dataset", "detect", "sweep", "fit", "simulate", "kway"]
    # the stages in turn read what the one before them wrote; the sweep (in the background) reads
    # what detect wrote
    in_turn = [s for s in chain if not s.background]
    for before, after in zip(in_turn, in_turn[1:], strict=False):
        assert set(after.inputs) <= set(before.outputs), (before.name, after.name)
    assert set(chain[2].inputs) <= set(chain[1].outputs) and chain[2].background
    for s in chain:
        for argv in s.argv:
            assert "--seed" in argv and "3" in argv
            # every command that names the dataset gets the profile's preset (quick: clean)
            if "--profile" in argv:
                assert argv[argv.index("--preset") + 1] == "clean"
    # a dataset used as it is gets no sweep (the sweep renders new images of a synthetic dataset)
    from scrppl.datasets.core import INDEX_FILE

    (tmp_path / "data").mkdir()
    (tmp_path / "data" / INDEX_FILE).write_text("")
    assert "sweep" not in [s.name for s in stages(args)]


def _fake_run(out):
    """A run folder as the stages write it, with full-precision numbers."""
    (out / "figures").mkdir(parents=True)
    for name in (
        "other",
        "calibration",
        "fig5-car-gaussian",
        "fig3-sift-car",
        "fig1-car",
        "fig2-dpm-car",
        "fig4-car",
        "dataset-sheet",
    ):
        (out / "figures" / f"{name}.png").write_bytes(b"\x89PNG")
    (out / "timings.json").write_text(json.dumps({"detect": 70.123456, "fit": 45.55}))
    (out / "detectors").mkdir()
    quality = {
        "average_precision": {
            "dpm": {"car": 0.98691234, "shoe": 0.9398},
            "sift": {"car": 0.5, "shoe": 0.25524},
        },
        "mean_average_precision": {"dpm": 0.96335617, "sift": 0.37762},
        "azimuth_dependence": {
            "dpm": {
                "car": {"positive": 1.17551, "negative": None},
                "shoe": {"positive": 1.1, "negative": 0.6},
            }
        },
        "seconds": {"scoring": 10.04},
        "split": "test",
    }
    (out / "detectors" / "quality.json").write_text(json.dumps(quality))
    (out / "models").mkdir()
    method = {
        "views_to_confidence": {"sampled": 2.5, "random": 3.25},
        "views_to_confidence_difference_95ci": {"mean": -0.75, "lo": -1.0, "hi": -0.5},
        "ece": 0.0412345,
        "p_correct_by_step": {
            "sampled": {"1": 0.9751234, "2": 1.0},
            "random": {"1": 0.97512, "2": 0.98},
        },
    }
    summary = {
        "detector": "dpm",
        "settings": {"trials": 160, "planners": ["sampled", "random"]},
        "targets": {"car": {"paper_experiment": {"gaussian+naive_bayes": method}}},
        "seconds_total": 42.4567,
    }
    (out / "simulate-summary.json").write_text(json.dumps(summary))
    diag = {
        "thresholds": {"rhat_max": 1.01},
        "dpm/car": {
            "ok": False,
            "rhat_max": {"a": 1.0212345678, "b": 1.0011},
            "ess_bulk_min": {"a": 300.456789, "b": 1000.2},
            "ess_tail_min": {"a": 250.2, "b": 900.9},
            "divergences": 2,
            "ebfmi": [0.812345],
            "failures": ["R-hat > 1.01: a (1.020)"],
            "attempts": [
                {
                    "target_accept_prob": 0.9,
                    "ok": False,
                    "divergences": 3,
                    "noncentered": ["u", "coef[1]"],
                },
                {
                    "target_accept_prob": 0.99,
                    "ok": False,
                    "divergences": 2,
                    "noncentered": ["u", "coef"],
                },
            ],
        },
    }
    (out / "models" / "diagnostics.json").write_text(json.dumps(diag))
    cols = [
        "lpd_single",
        "lpd_single_se",
        "lpd_joint",
        "lpd_joint_se",
        "cover50",
        "cover50_se",
        "cover90",
        "cover90_se",
    ]
    lines = [",".join(["detector", "target", "kind", "class", "n_instances", "n_responses", *cols])]
    i = 0
    for det in ("dpm", "sift"):
        for target in ("car", "shoe"):
            for kind in ("gaussian", "hierarchical"):
                for cls in ("all", "absent", "present"):
                    i += 1
                    vals = [
                        repr(-1.0 - i / 7.0),
                        repr(i / 97.0),
                        repr(-0.5 - i / 11.0),
                        repr(i / 89.0),
                        repr(0.5 + i / 301.0),
                        repr(i / 997.0),
                        repr(0.9 - i / 503.0),
                        repr(i / 991.0),
                    ]
                    lines.append(",".join([det, target, kind, cls, "18", "144", *vals]))
    (out / "models" / "heldout.csv").write_text("\n".join(lines) + "\n")
    return out


def _tables(text):
    """Each Markdown table of ``text`` as a list of rows of cells, keyed by the line before it."""
    tables, current, caption = {}, None, ""
    for line in text.splitlines():
        if line.startswith("|"):
            if current is None:
                current = tables.setdefault(caption, [])
            if not line.startswith("|---"):
                current.append([c.strip() for c in line.strip("|").split("|")])
        else:
            current = None
            if line.strip():
                caption = line.strip()
    return tables


def test_report_rounds_every_number_in_its_tables(tmp_path):
    import re

    text = write_report(_fake_run(tmp_path), profile="quick", seed=1).read_text()
    table_lines = [line for line in text.splitlines() if line.startswith("| ")]
    assert table_lines
    for line in table_lines:
        for decimals in re.findall(r"\d\.(\d+)", line):
            assert len(decimals) <= 3, line
    assert "| dpm | 0.99 | 0.94 | 0.96 |" in text  # average precision: 2 decimals
    assert "| dpm | 1.18 / n/a | 1.10 / 0.60 |" in text  # not estimable stays n/a
    assert "| detect | 70.1 |" in text and "| **total** | 115.7 |" in text  # seconds: 1 decimal
    assert (
        "| dpm/car | NO | 1.021 | 300 | 250 | 2 | 0.81 | 0.9 -> 0.99 | coef[1] |" in text
    )  # R-hat 3, ESS whole; the first attempt's non-centred coefficients
    assert "**1 of 1 needed a second attempt**" in text
    assert "instance x azimuth effect" not in text  # a fit without it: nothing to say
    assert (
        "| car | paper | gaussian+naive_bayes | 2.50 | 3.25 | -0.750 [-1.000, -0.500] | 0.041 |"
        in text
    )
    assert "| car | gaussian+naive_bayes | 0.975 / 0.975 | 1.000 / 0.980 |" in text
    assert "--profile quick --seed 1" in text and "0 of 1 fits pass" in text
    assert "```json" not in text  # no JSON dumps
    # with CPU seconds (timings.json of scrppl reproduce): a CPU column and the ratio, and the machine
    out = tmp_path
    (out / "timings.json").write_text(
        json.dumps(
            {
                "detect": 70.0,
                "fit": 30.0,
                "cpu_seconds": {"detect": 126.0, "fit": 33.0},
                "machine": {"cores": 2, "cpu": "Test CPU"},
            }
        )
    )
    text = write_report(out, profile="quick", seed=1).read_text()
    assert "| detect | 70.0 | 126.0 | 1.80 |" in text
    assert "| **total** | 100.0 | 159.0 | 1.59 |" in text and "on 2 cores (Test CPU)" in text
    assert "background" not in text.split("## Stage timings")[1].split("##")[0]
    # a stage in the background: marked, and the total is the run's own wall time, not the sum
    (out / "timings.json").write_text(
        json.dumps(
            {
                "detect": 70.0,
                "sweep": 50.0,
                "fit": 30.0,
                "cpu_seconds": {"detect": 126.0, "sweep": 60.0, "fit": 33.0},
                "machine": {"cores": 2, "cpu": "Test CPU"},
                "background": ["sweep"],
                "wall_seconds_total": 110.0,
            }
        )
    )
    text = write_report(out, profile="quick", seed=1).read_text()
    assert "| sweep (background) | 50.0 | 60.0 | 1.20 |" in text
    assert "| **total** | 110.0 | 219.0 | 1.99 |" in text and "not the sum" in text
    assert "cores busy" not in text  # a record without the machine's busy seconds: no such column
    # with the machine's busy seconds: a column of cores busy per stage run in turn and for the run
    record = json.loads((out / "timings.json").read_text())
    record["machine_busy_seconds"] = {"detect": 133.0, "fit": 57.0, "total": 215.6}
    (out / "timings.json").write_text(json.dumps(record))
    text = write_report(out, profile="quick", seed=1).read_text()
    assert "| detect | 70.0 | 126.0 | 1.80 | 1.90 |" in text
    assert "| fit | 30.0 | 33.0 | 1.10 | 1.90 |" in text  # the background stage kept the cores busy
    assert "| sweep (background) | 50.0 | 60.0 | 1.20 |  |" in text
    assert "| **total** | 110.0 | 219.0 | 1.99 | 1.96 |" in text and "/proc/stat" in text
    # a fit with the instance x azimuth effect (scrppl fit --azimuth-effect auto on several rings)
    diag_path = out / "models" / "diagnostics.json"
    diag = json.loads(diag_path.read_text())
    diag["dpm/car"]["azimuth_effect"] = True
    diag_path.write_text(json.dumps(diag))
    text = write_report(out, profile="quick", seed=1).read_text()
    assert "1 of 1 fits have the instance x azimuth effect" in text


def test_report_heldout_is_one_row_per_detector_and_target(tmp_path):
    text = write_report(_fake_run(tmp_path)).read_text()
    tables = _tables(text)
    header, *rows = tables["Per detector and target:"]
    assert header[:2] == ["detector", "target"]
    assert "single, Gaussian" in header and "joint, hierarchical" in header
    assert sorted((r[0], r[1]) for r in rows) == [
        ("dpm", "car"),
        ("dpm", "shoe"),
        ("sift", "car"),
        ("sift", "shoe"),
    ]
    first = dict(zip(header, rows[0], strict=True))
    # dpm/car/gaussian/all is row 1 of the CSV, hierarchical/all row 4
    assert first["single, Gaussian"] == f"{-1 - 1 / 7:.3f} ± {1 / 97:.3f}"
    assert first["joint, hierarchical"] == f"{-0.5 - 4 / 11:.3f} ± {4 / 89:.3f}"
    header, *means = tables["Mean over targets, per detector:"]
    assert [r[0] for r in means] == ["dpm", "sift"]
    dpm = dict(zip(header, means[0], strict=True))
    assert dpm["single, Gaussian"] == f"{(-1 - 1 / 7 - 1 - 7 / 7) / 2:.3f}"  # car row 1, shoe row 7


def test_report_writes_full_tables_as_csv_and_links_them(tmp_path):
    import csv

    out = _fake_run(tmp_path)
    text = write_report(out).read_text()
    for name in ("report-heldout.csv", "report-diagnostics.csv", "report-experiment.csv"):
        assert (out / name).exists() and f"]({name})" in text
    with (out / "models" / "heldout.csv").open() as fh:
        source = list(csv.DictReader(fh))
    with (out / "report-heldout.csv").open() as fh:
        wide = list(csv.DictReader(fh))
    assert (
        len(wide) == len(source) // 2
    )  # one row per (detector, target, class), kinds side by side
    for r in source:
        w = next(
            w
            for w in wide
            if (w["detector"], w["target"], w["class"]) == (r["detector"], r["target"], r["class"])
        )
        for col in ("lpd_single", "lpd_joint_se", "cover90"):
            assert float(w[f"{r['kind']}_{col}"]) == float(r[col])  # full precision round-trips
    with (out / "report-diagnostics.csv").open() as fh:
        diag = list(csv.DictReader(fh))
    assert [(d["fit"], d["parameter"], float(d["rhat_max"])) for d in diag] == [
        ("dpm/car", "a", 1.0212345678),
        ("dpm/car", "b", 1.0011),
    ]
    with (out / "report-experiment.csv").open() as fh:
        (exp,) = list(csv.DictReader(fh))
    assert float(exp["ece"]) == 0.0412345 and float(exp["p_correct_by_step.sampled.1"]) == 0.9751234


def test_report_groups_figures_in_paper_order(tmp_path):
    text = write_report(_fake_run(tmp_path)).read_text()
    headings = [line for line in text.splitlines() if line.startswith("### ")]
    assert [h.split(":")[0] for h in headings] == [
        "### Fig. 1",
        "### Fig. 2",
        "### Fig. 3",
        "### Fig. 4",
        "### Fig. 5",
        "### Other figures",
    ]
    pos = {h.split(":")[0]: text.index(h) for h in headings}
    assert pos["### Fig. 3"] < text.index("figures/fig3-sift-car.png") < pos["### Fig. 4"]
    assert (
        pos["### Fig. 5"] < text.index("figures/fig5-car-gaussian.png") < pos["### Other figures"]
    )
    assert (
        text.index("figures/dataset-sheet.png")
        < text.index("figures/calibration.png")
        < text.index("figures/other.png")
    )
    assert "**calibration** — Reliability" in text


def test_report_says_which_stages_did_not_run(tmp_path):
    (tmp_path / "report-heldout.csv").write_text("stale\n")
    text = write_report(tmp_path).read_text()
    for rel, stage in (
        ("detectors/quality.json", "detect"),
        ("models/diagnostics.json", "fit"),
        ("models/heldout.csv", "fit"),
        ("simulate-summary.json", "simulate"),
    ):
        assert f"`{rel}` was not written (the `{stage}` stage did not run)" in text
    assert "no figures under `figures/`" in text
    assert not list(tmp_path.glob("report-*.csv"))  # a table whose input is gone does not linger
    (tmp_path / "simulate-summary.json").write_text("{not json")
    assert "`simulate-summary.json` could not be read" in write_report(tmp_path).read_text()


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert "reproduce" in sub.choices
    for name in sub.choices:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        assert "usage: scrppl" in capsys.readouterr().out


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage: scrppl" in capsys.readouterr().out


def test_atomic_path_gives_ordinary_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        with atomic_path(tmp_path / "f.txt") as tmp:
            tmp.write_text("x")
    finally:
        os.umask(umask)
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == 0o644


def test_every_stage_command_line_is_accepted_by_its_command(tmp_path):
    # reproduce drives the stage commands by their command lines: those must stay in step.
    args = argparse.Namespace(
        root=tmp_path / "data", out=tmp_path / "out", seed=0, profile="quick", strict=False
    )
    parser = build_parser()
    for stage in stages(args):
        for argv in stage.argv:
            parsed = parser.parse_args(list(argv) + (["--force"] if stage.takes_force else []))
            assert parsed.func is not None, argv


def test_netcdf_round_trip_and_missing_file_is_named(tmp_path):
    import numpy as np
    import xarray as xr

    from scrppl._io import read_netcdf, write_netcdf

    ds = xr.Dataset({"x": ("i", np.arange(3.0))})
    write_netcdf(ds, tmp_path / "a.nc")
    assert read_netcdf(tmp_path / "a.nc").equals(ds)
    with pytest.raises(FileNotFoundError, match="trials file not found: .*b.nc"):
        read_netcdf(tmp_path / "b.nc", "trials file")


def test_report_regime_checks_the_stated_criteria(tmp_path):
    from scrppl.report import REGIME_METHOD, regime_numbers

    out = _fake_run(tmp_path)
    summary = json.loads((out / "simulate-summary.json").read_text())

    def large(random, sampled):
        return {
            "views_to_confidence": {"sampled": sampled, "random": random},
            "views_to_confidence_difference_95ci": {"mean": sampled - random, "lo": -1, "hi": 0},
        }

    summary["targets"] = {
        "car": {"large_experiment": {REGIME_METHOD: large(3.5, 2.75)}},
        "shoe": {"large_experiment": {REGIME_METHOD: large(2.9, 2.25), "other": large(9, 9)}},
    }
    (out / "simulate-summary.json").write_text(json.dumps(summary))
    r = regime_numbers(out)
    assert r["random_views"] == pytest.approx((3.5 + 2.9) / 2)
    assert r["planning_views"] == pytest.approx((2.75 + 2.25) / 2)
    assert r["ambiguity_criterion_met"] is True  # 3.2 >= 3
    assert r["dpm_mean_ap"] == pytest.approx(0.96335617)
    assert r["ap_criterion_met"] is False  # above 0.75
    text = write_report(out, preset="robot", profile="full").read_text()
    regime = text.split("## Regime")[1].split("\n## ")[0]
    assert "Imaging preset `robot`" in regime and "--preset robot" in text
    assert "average precision 0.96 (criterion 0.55-0.75: not met)" in regime
    assert "random unseen view 3.20 (criterion at least 3: met)" in regime
    assert "| shoe | 2.90 | 2.25 | -0.650 [-1.000, 0.000] |" in regime
    # a run without the stages' outputs has no regime section
    assert "## Regime" not in write_report(tmp_path / "empty").read_text()


@pytest.mark.parametrize(
    ("random_views", "met"),
    [((3.0,), True), ((2.5, 3.5), True), ((2.99,), False), ((2.5, 3.49), False), ((3.01,), True)],
)
def test_regime_ambiguity_criterion_includes_its_boundary(tmp_path, random_views, met):
    """Catches "at least 3 random views" written as "more than 3": a mean of exactly 3.0 (one target at
    3, or 2.5 and 3.5) meets the criterion, anything below does not."""
    from scrppl.report import REGIME_METHOD, REGIME_MIN_RANDOM_VIEWS, regime_numbers

    assert REGIME_MIN_RANDOM_VIEWS == 3.0  # the criterion as stated
    targets = {
        f"t{k}": {
            "large_experiment": {
                REGIME_METHOD: {"views_to_confidence": {"random": v, "sampled": 2.0}}
            }
        }
        for k, v in enumerate(random_views)
    }
    (tmp_path / "simulate-summary.json").write_text(json.dumps({"targets": targets}))
    r = regime_numbers(tmp_path)
    assert r["random_views"] == pytest.approx(sum(random_views) / len(random_views))
    assert r["ambiguity_criterion_met"] is met


def test_regime_ap_criterion_includes_both_ends(tmp_path):
    """The AP range 0.55-0.75 of the regime is closed: both ends meet it, values just outside do not."""
    from scrppl.report import regime_numbers

    (tmp_path / "detectors").mkdir()
    quality = tmp_path / "detectors" / "quality.json"
    for ap, met in ((0.55, True), (0.75, True), (0.65, True), (0.5499, False), (0.7501, False)):
        quality.write_text(json.dumps({"mean_average_precision": {"dpm": ap}}))
        assert regime_numbers(tmp_path)["ap_criterion_met"] is met, ap


def test_a_fit_stage_whose_fits_failed_their_diagnostics_is_not_current(tmp_path):
    args = argparse.Namespace(
        root=tmp_path / "data", out=tmp_path / "out", seed=3, profile="book", strict=True
    )
    fit = next(s for s in stages(args) if s.name == "fit")
    (tmp_path / "out" / "models").mkdir(parents=True)
    (tmp_path / "out" / "responses.nc").write_text("r")
    diag = tmp_path / "out" / "models" / "diagnostics.json"
    now = time.time()
    for ok, current in ((False, False), (True, True)):
        diag.write_text(json.dumps({"thresholds": {}, "dpm/car": {"ok": ok}}))
        os.utime(tmp_path / "out" / "responses.nc", (now - 10, now - 10))
        assert is_current(fit) is current
    # the quick profile accepts failing diagnostics, so its stage is done either way
    quick = next(
        s
        for s in stages(argparse.Namespace(**{**vars(args), "profile": "quick"}))
        if s.name == "fit"
    )
    diag.write_text(json.dumps({"dpm/car": {"ok": False}}))
    assert is_current(quick)


def test_report_sweep_section_has_one_row_per_point(tmp_path):
    point = {
        "views_to_confidence": {"sampled": 2.25, "random": 2.5},
        "reached_confidence": {"sampled": 1.0, "random": 0.98765},
        "views_saved": 0.25,
        "views_saved_lo": 0.1234,
        "views_saved_hi": 0.37,
        "ap": 0.7123,
        "fit_ok": True,
        "n_trials": 10000,
    }
    summary = {
        "settings": {"n_trials": 10000, "num_chains": 4, "num_samples": 500},
        "points": {
            "level-0": {"dpm/car": point},
            "level-1p5": {"dpm/car": {**point, "fit_ok": False}, "sift/car": point},
        },
    }
    (tmp_path / "sweep-summary.json").write_text(json.dumps(summary))
    text = write_report(tmp_path).read_text()
    sweep = text.split("## When does looking pay off?")[1].split("\n## ")[0]
    rows = [line for line in sweep.splitlines() if line.startswith("| ") and "level" not in line]
    assert len(rows) == 3
    assert (
        "| 1.5 | dpm/car | 0.71 | 2.50 | 2.25 | 0.250 [0.123, 0.370] | 0.988 | 10000 | NO |" in rows
    )
    assert "2 of 3 fits pass every diagnostic gate." in sweep and "10000 paired trials" in sweep
    # trials in blocks until the interval is narrow enough: the text says so, each row how many ran
    summary["settings"].update(half_width=0.05, block_trials=2048, n_trials=10000)
    summary["points"]["level-0"]["dpm/car"] = {**point, "n_trials": 2048}
    (tmp_path / "sweep-summary.json").write_text(json.dumps(summary))
    sweep = write_report(tmp_path).read_text().split("## When does looking pay off?")[1]
    assert "blocks of 2048 until the interval of the views saved is at most +-0.05 views" in sweep
    assert (
        "| 0 | dpm/car | 0.71 | 2.50 | 2.25 | 0.250 [0.123, 0.370] | 0.988 | 2048 | yes |" in sweep
    )


def test_the_book_profile_has_no_sweep_stage_and_its_report_says_how_to_run_it(tmp_path):
    """The sweep would add about two thirds to the book profile's run: that profile leaves it out (ch. 9 reads
    a recorded one) and its report names the command; the other profiles keep the stage."""
    names = {
        profile: [
            s.name
            for s in stages(
                argparse.Namespace(
                    root=tmp_path / "data",
                    out=tmp_path / "out",
                    seed=0,
                    profile=profile,
                    strict=True,
                )
            )
        ]
        for profile in ("quick", "book", "full")
    }
    assert names["book"] == ["dataset", "detect", "fit", "simulate", "kway"]
    assert "sweep" in names["quick"] and "sweep" in names["full"]
    out = tmp_path / "run"
    _fake_run(out)
    book = write_report(out, profile="book").read_text()
    section = book.split("## When does looking pay off? The difficulty sweep")[1].split("\n## ")[0]
    assert "Not run in the book profile" in section
    assert "`scrppl sweep --profile book --out run` writes it" in section
    full = write_report(out, profile="full").read_text()
    assert "_Not available: `sweep-summary.json` is missing._" in full


def _decomposition_entry(random, confident, clairvoyant, interval):
    """One method's rows as summarise_decomposition writes them."""

    def row(v, d):
        return {
            "views_to_confidence": v,
            "difference_vs_random": {"mean": d[0], "lo": d[1], "hi": d[2]},
            "share_of_room": {"mean": 0.1234567, "lo": 0.01, "hi": 0.2},
        }

    return {
        "filter": "instance",
        "rows": {
            "random": row(random, (0.0, 0.0, 0.0)),
            "confident": row(confident, interval),
            "clairvoyant": row(clairvoyant, (clairvoyant - random, -1.0, -0.5)),
        },
        "room": {"mean": random - clairvoyant, "lo": 0.5, "hi": 1.0},
    }


def test_report_shows_the_decomposition_of_a_full_run_and_says_when_it_did_not_run(tmp_path):
    import csv

    from scrppl.pipeline import DECOMPOSE_ROWS

    out = _fake_run(tmp_path)
    text = write_report(out, profile="full").read_text()
    assert "## Where planning gains or loses views" in text
    assert "`decomposition.json` was not written (the `decompose` stage did not run)" in text
    book = write_report(out, profile="book").read_text()
    assert "Not run in the book profile: `scrppl decompose --out" in book
    entry = _decomposition_entry(3.0925, 3.0421, 2.2081, (-0.0505, -0.112, 0.014))
    summary = {
        "settings": {"trials": 160, "rows": ["random", "confident", "clairvoyant"]},
        "targets": {"car": {"methods": {"hierarchical+instance": entry}}},
    }
    (out / "decomposition.json").write_text(json.dumps(summary))
    text = write_report(out, profile="full").read_text()
    section = text.split("## Where planning gains or loses views")[1].split("\n## ")[0]
    assert "on 160 paired trials per target" in section
    assert "| car | hierarchical+instance | 3.09 | 3.04 (-0.05 [-0.11, 0.01]) |" in section
    assert "2.21 (-0.88 [-1.00, -0.50]) | 0.12 [0.01, 0.20] |" in section
    with (out / "report-decomposition.csv").open() as fh:
        (row,) = list(csv.DictReader(fh))
    assert (
        float(row["confident_views"]) == 3.0421 and float(row["confident_minus_random"]) == -0.0505
    )
    # the full profile's stage runs these rows, last in the pipeline
    args = argparse.Namespace(root=tmp_path / "data", out=out, seed=0, profile="full", strict=True)
    chain = stages(args)
    simulate = next(s for s in chain if s.name == "simulate")
    assert chain[-1].name == "decompose" and set(chain[-1].inputs) <= set(simulate.outputs)
    argv = chain[-1].argv[0]
    assert (
        argv[argv.index("--rows") + 1]
        == ",".join(DECOMPOSE_ROWS)
        == ("random,greedy_joint,confident,clairvoyant")
    )
    assert "decompose" not in [
        s.name for s in stages(argparse.Namespace(**{**vars(args), "profile": "book"}))
    ]


def test_report_says_each_large_trial_reads_its_own_draws(tmp_path):
    out = _fake_run(tmp_path)
    assert "reads its own `large_max_draws`" not in write_report(out).read_text()
    path = out / "simulate-summary.json"
    summary = json.loads(path.read_text())
    summary["settings"].update(max_draws=32, large_max_draws=8)
    path.write_text(json.dumps(summary))
    text = write_report(out).read_text()
    assert "| large_max_draws | 8 |" in text
    assert "each trial of the large one reads its own `large_max_draws`" in text
