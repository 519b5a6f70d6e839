import argparse
import json
import os
import time

import pytest

from scrppl._io import atomic_path, default_cache_dir
from scrppl.cli import build_parser, main
from scrppl.cli.reproduce import Stage, is_current, stages
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
    assert [s.name for s in chain] == ["dataset", "detect", "fit", "simulate"]
    for before, after in zip(chain, chain[1:], strict=False):
        assert set(after.inputs) <= set(before.outputs), (before.name, after.name)
    for s in chain:
        for argv in s.argv:
            assert "--seed" in argv and "3" in argv


def test_report_lists_numbers_and_figures(tmp_path):
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "fig5-car.png").write_bytes(b"\x89PNG")
    (tmp_path / "figures" / "other.png").write_bytes(b"\x89PNG")
    method = {
        "views_to_confidence": {"sampled": 2.5, "random": 3.25},
        "views_to_confidence_difference_95ci": {"mean": -0.75, "lo": -1.0, "hi": -0.5},
        "ece": 0.04,
    }
    summary = {
        "detector": "dpm",
        "targets": {"car": {"paper_experiment": {"gaussian+naive_bayes": method}}},
    }
    (tmp_path / "simulate-summary.json").write_text(json.dumps(summary))
    (tmp_path / "models").mkdir()
    diag = {
        "thresholds": {"rhat_max": 1.01},
        "dpm/car": {
            "ok": False,
            "rhat_max": {"a": 1.02},
            "ess_bulk_min": {"a": 300.0},
            "ess_tail_min": {"a": 250.0},
            "divergences": 2,
            "ebfmi": [0.8],
            "failures": ["R-hat > 1.01: a (1.020)"],
            "attempts": [
                {"target_accept_prob": 0.9, "ok": False, "divergences": 3},
                {"target_accept_prob": 0.99, "ok": False, "divergences": 2},
            ],
        },
    }
    (tmp_path / "models" / "diagnostics.json").write_text(json.dumps(diag))
    path = write_report(tmp_path, profile="quick", seed=1)
    text = path.read_text()
    assert (
        "| car | paper | gaussian+naive_bayes | 2.5 | 3.25 | -0.750 [-1.000, -0.500] | 0.04 |"
        in text
    )
    assert (
        "0 of 1 fits pass" in text
        and "| dpm/car | NO | 1.02 | 300 | 250 | 2 | 0.8 | 0.9 -> 0.99 |" in text
    )
    assert text.index("fig5-car") < text.index("other")  # paper figures first
    assert "--profile quick --seed 1" in text


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
