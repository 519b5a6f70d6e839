"""The reproduction pipeline as a library (:mod:`scrppl.pipeline`): running stages, reading failures."""

import json
from pathlib import Path

from scrppl.pipeline import Stage, failed_fits, run_stages


def test_run_stages_skips_current_and_unavailable_stages_and_stops_at_a_failure(tmp_path):
    inp, outp = tmp_path / "in", tmp_path / "out"
    inp.write_text("x")
    outp.write_text("y")
    current = Stage("current", "scrppl.pipeline", (("a",),), (inp,), (outp,), takes_force=True)
    missing = Stage("missing", "scrppl.no_such_module", (("b",),), (), ())
    failing = Stage("failing", "scrppl.pipeline", (("c", "1"), ("d",)), (), (tmp_path / "none",))
    calls, lines = [], []

    def run_command(argv):
        calls.append(argv)
        return 5 if argv[0] == "c" else 0

    status, timings = run_stages([current, missing, failing], run_command, log=lines.append)
    assert status == 5 and calls == [["c", "1"]]
    assert timings == {"current": "up to date", "missing": "not available"}
    assert any("current: up to date" in line for line in lines)
    calls.clear()
    cpu = {}
    status, timings = run_stages(
        [current], run_command, force=True, log=lines.append, cpu_seconds=cpu
    )
    assert status == 0 and calls == [["a", "--force"]] and isinstance(timings["current"], float)
    assert set(cpu) == {"current"} and cpu["current"] >= 0.0


def test_failed_fits_reads_diagnostics(tmp_path):
    path = tmp_path / "diagnostics.json"
    assert failed_fits(path) == []
    diag = {"thresholds": {"rhat_max": 1.01}, "sift/car": {"ok": False}, "dpm/car": {"ok": False}}
    path.write_text(json.dumps({**diag, "dpm/shoe": {"ok": True}}))
    assert failed_fits(path) == ["dpm/car", "sift/car"]


def test_errors_reach_every_command_that_reads_a_savarese_tree(tmp_path):
    """``--errors`` goes to the commands that open the dataset, and each accepts it."""
    from test_savarese import small_tree

    from scrppl.cli import build_parser
    from scrppl.pipeline import stages

    root = small_tree(tmp_path / "copy")
    parser = build_parser()
    readers = set()
    for errors in ("raise", "report"):
        for stage in stages(root, tmp_path / "out", seed=2, profile="quick", errors=errors):
            for argv in stage.argv:
                args = parser.parse_args(list(argv))
                if getattr(args, "errors", None) is not None:
                    assert args.errors == errors
                    readers.add(" ".join(argv[:2]))
    assert readers == {"dataset info", "dataset sheet", "detect --root"}
    # the synthetic cache has no bad files to report: its commands are unchanged
    cache = stages(tmp_path / "cache", tmp_path / "out", seed=2, profile="quick", errors="raise")
    assert all("--errors" not in argv for stage in cache for argv in stage.argv)


def test_failed_fits_names_a_corrupt_diagnostics_file(tmp_path):
    import pytest

    from scrppl._io import CorruptFileError

    path = tmp_path / "diagnostics.json"
    path.write_text('{"dpm/car": {"ok": fal')
    with pytest.raises(CorruptFileError, match="scrppl fit --force") as err:
        failed_fits(path)
    assert str(path) in str(err.value) and "MCMC diagnostics" in str(err.value)


def test_reproduce_reruns_every_stage_of_a_folder_made_with_other_settings(tmp_path, monkeypatch):
    """A run folder written with another seed (or profile, preset, numerics) is not up to date, however
    new its files are: reproduce forces every stage and says why."""
    import scrppl.cli.reproduce as rep
    from scrppl.cli import main

    calls = []

    def fake_run_stages(pipeline, run_command, *, force=False, **kw):
        calls.append(force)
        return 0, {}

    monkeypatch.setattr(rep, "run_stages", fake_run_stages)
    monkeypatch.setattr("scrppl.report.write_report", lambda out, **kw: Path(out) / "report.md")
    out = tmp_path / "out"
    base = ["reproduce", "--profile", "quick", "--root", str(tmp_path / "data"), "--out", str(out)]
    assert main([*base, "--seed", "0"]) == 0
    assert main([*base, "--seed", "0"]) == 0  # same settings: stages decide by their files
    assert main([*base, "--seed", "1"]) == 0  # another seed in the same folder
    assert calls == [False, False, True]
    assert json.loads((out / "run.json").read_text())["seed"] == 1


def test_cpu_time_counts_this_process_and_its_ended_children():
    """A stage's CPU seconds include its worker processes: a child that burns CPU and ends is counted."""
    import subprocess
    import sys

    from scrppl.pipeline import cpu_time

    t0 = cpu_time()
    subprocess.run([sys.executable, "-c", "x = 0\nfor i in range(3_000_000): x += i"], check=True)
    assert cpu_time() - t0 > 0.05


def test_machine_busy_seconds_reads_the_busy_fields_of_proc_stat(tmp_path):
    """user + nice + system + irq + softirq + steal, in clock ticks; idle and iowait left out; None for a
    file that is not Linux's /proc/stat."""
    import os

    from scrppl.pipeline import machine_busy_seconds

    stat = tmp_path / "stat"
    stat.write_text("cpu  100 20 30 1000 50 5 7 11 0 0\ncpu0 50 10 15 500 25 2 3 5 0 0\n")
    ticks = os.sysconf("SC_CLK_TCK")
    assert machine_busy_seconds(stat) == (100 + 20 + 30 + 5 + 7 + 11) / ticks
    for bad in ("", "intr 1 2 3\n", "cpu 1 2\n"):
        stat.write_text(bad)
        assert machine_busy_seconds(stat) is None
    assert machine_busy_seconds(tmp_path / "missing") is None


def test_run_stages_records_how_busy_the_machine_was_during_each_stage(tmp_path):
    """A stage that burns CPU in a child process: the machine's busy seconds over the stage cover it
    (at least the child's own CPU, less a tick's rounding), and only stages run in turn get them."""
    import subprocess
    import sys

    import pytest

    from scrppl.pipeline import machine_busy_seconds

    if machine_busy_seconds() is None:
        pytest.skip("not Linux: no /proc/stat to read the machine's busy time from")
    burn = Stage("burn", "scrppl.pipeline", (("x",),), (), (tmp_path / "never",))

    def run_command(argv):
        subprocess.run(
            [sys.executable, "-c", "x = 0\nfor i in range(6_000_000): x += i"], check=True
        )
        return 0

    cpu, busy = {}, {}
    status, _ = run_stages(
        [burn], run_command, log=lambda m: None, cpu_seconds=cpu, machine_seconds=busy
    )
    assert status == 0 and set(busy) == {"burn"}
    assert busy["burn"] >= cpu["burn"] - 0.05 > 0.1


def test_a_fit_stage_with_fits_of_another_model_version_is_not_up_to_date(tmp_path):
    """After the model changes (MODEL_VERSION), `scrppl reproduce` must refit, not report 'up to date' and
    then fail in the next stage on a fit it refuses to load."""
    import h5py

    from scrppl.models.io import MODEL_VERSION
    from scrppl.pipeline import is_current, stages, stale_fits

    out = tmp_path / "out"
    models = out / "models"
    models.mkdir(parents=True)
    (out / "responses.nc").write_bytes(b"")
    (models / "diagnostics.json").write_text(json.dumps({"dpm/car": {"ok": True}}))
    for name, version in (
        ("hierarchical-dpm-car.nc", MODEL_VERSION),
        ("hierarchical-dpm-bus.nc", 1),
    ):
        with h5py.File(models / name, "w") as fh:
            fh.attrs["meta"] = json.dumps({"model_version": version})
    assert stale_fits(models) == ["hierarchical-dpm-bus"]
    fit = next(s for s in stages(tmp_path / "data", out, seed=0, profile="book") if s.name == "fit")
    assert not is_current(fit)
    (models / "hierarchical-dpm-bus.nc").unlink()
    assert is_current(fit)


def test_a_fit_stage_whose_fits_lack_the_azimuth_effect_auto_gives_is_not_up_to_date(tmp_path):
    """The pipeline fits the instance x azimuth effect exactly where the grid has more than one ring
    (`scrppl fit --azimuth-effect auto`): a run folder fitted before that default, or by hand with the
    other setting, must be refitted by `scrppl reproduce`, not read as the pipeline's model."""
    import h5py

    from scrppl.models.io import MODEL_VERSION
    from scrppl.pipeline import is_current, stages, stale_fits

    out = tmp_path / "out"
    models = out / "models"
    models.mkdir(parents=True)
    (out / "responses.nc").write_bytes(b"")
    (models / "diagnostics.json").write_text(json.dumps({}))
    rings = {"n_azimuth": 8, "elevations": [10.0, 25.0], "scales": [1.0]}
    one_ring = {"n_azimuth": 8, "elevations": [25.0], "scales": [1.4]}
    for name, grid, effect in (
        ("hierarchical-dpm-car.nc", rings, True),  # as auto gives it
        ("hierarchical-dpm-bus.nc", rings, False),  # fitted before the default
        ("hierarchical-dpm-cup.nc", one_ring, False),  # as auto gives it
        ("hierarchical-dpm-mug.nc", one_ring, True),  # by hand, `--azimuth-effect on`
    ):
        with h5py.File(models / name, "w") as fh:
            meta = {"model_version": MODEL_VERSION, "grid": grid, "azimuth_effect": effect}
            fh.attrs["meta"] = json.dumps(meta)
    assert stale_fits(models) == ["hierarchical-dpm-bus", "hierarchical-dpm-mug"]
    fit = next(s for s in stages(tmp_path / "data", out, seed=0, profile="book") if s.name == "fit")
    assert not is_current(fit)
    for stem in stale_fits(models):
        (models / f"{stem}.nc").unlink()
    assert is_current(fit)


def test_a_sweep_made_with_other_settings_than_the_profiles_is_not_up_to_date(tmp_path):
    """Sizing a profile's sweep anew (other levels, trials or chains) must rerun the sweep stage of an
    existing run folder, not leave the old sweep in place because its files are newer."""
    import dataclasses

    from scrppl.cli.sweep import PROFILE_SETTINGS, made_with_profile
    from scrppl.pipeline import is_current, stages
    from scrppl.sim.sweep import SweepSettings

    want = PROFILE_SETTINGS["quick"]  # the book profile has no sweep stage
    settings = SweepSettings(
        n_trials=want["trials"], num_warmup=want["warmup"], num_samples=want["draws"],
        num_chains=want["chains"], n_samples=want["n_samples"], max_draws=want["max_draws"],
        retry_longer=want["retry_longer"],
    )  # fmt: skip
    levels = [float(x) for x in want["levels"].split(",")]
    families = want["families"].split(",")
    out = tmp_path / "out"
    out.mkdir()
    (out / "responses.nc").write_bytes(b"")
    (out / "sweep.nc").write_bytes(b"")
    summary = out / "sweep-summary.json"

    def write(**change):
        made = {"levels": levels, "families": families, "settings": dataclasses.asdict(settings)}
        for k, v in change.items():
            if k in made:
                made[k] = v
            else:
                made["settings"] = {**made["settings"], k: v}
        summary.write_text(json.dumps(made))

    sweep = next(
        s for s in stages(tmp_path / "data", out, seed=0, profile="quick") if s.name == "sweep"
    )
    write()
    assert made_with_profile(summary, "quick") and is_current(sweep)
    assert not made_with_profile(summary, "full")  # the full profile has other levels and trials
    for change in (
        {"levels": [0.0, 1.0, 1.4, 2.0]},
        {"families": ["sift", "dpm"]},
        {"n_trials": want["trials"] * 5},
        {"num_samples": want["draws"] // 2},
        {"num_chains": want["chains"] + 2},
    ):
        write(**change)
        assert not made_with_profile(summary, "quick"), change
        assert not is_current(sweep), change
    summary.write_text("{not json")
    assert not made_with_profile(summary, "quick")
    summary.unlink()
    assert not made_with_profile(summary, "quick")
    assert not made_with_profile(out / "sweep-summary.json", "no-such-profile")


def test_a_kway_stage_whose_temperature_saw_its_fit_objects_is_not_up_to_date(tmp_path):
    """A K-way summary written before the temperature's trials left each fit object out of the models
    (its calibration_fit has no ``method``) reruns the stage; one without a temperature, or with the
    method recorded, is current; an unreadable summary is not."""
    from scrppl.pipeline import is_current, stages

    out = tmp_path / "out"
    out.mkdir()
    (out / "trials.nc").write_bytes(b"")
    (out / "kway-trials.nc").write_bytes(b"")
    summary = out / "kway-summary.json"
    kway = next(
        s for s in stages(tmp_path / "data", out, seed=0, profile="book") if s.name == "kway"
    )
    for fitted, current in (
        ({"temperature": 1.2}, False),
        ({"temperature": 1.2, "method": "leave-one-object-out"}, True),
        ({"temperature": 1.2, "method": "fit-instances"}, True),
        (None, True),
    ):
        body = {"categories": ["a"]} if fitted is None else {"calibration_fit": fitted}
        summary.write_text(json.dumps(body))
        assert is_current(kway) == current, fitted
    summary.write_text("{not json")
    assert not is_current(kway)


def _background_stage(tmp_path, name, *script, runner="subprocess:call"):
    """A background stage whose child runs ``script`` (shell command lines) with ``runner``."""
    return Stage(
        name,
        "scrppl.pipeline",
        tuple(("sh", "-c", line) for line in script),
        (),
        (tmp_path / f"{name}.out",),
        background_log=tmp_path / "logs" / f"{name}.log",
        runner=runner,
    )


def test_a_background_stage_runs_beside_the_stages_after_it(tmp_path):
    """The sweep's way of running: the stages after a background stage go on while it runs (its child
    waits here for a file that only the next stage writes, so a runner that waited for it first would
    never end), its messages reach the log, its CPU seconds are its child's and its output is in its
    log file."""
    flag, done = tmp_path / "flag", tmp_path / "bg.out"
    bg = _background_stage(
        tmp_path,
        "bg",
        f"i=0; while [ ! -e {flag} ] && [ $i -lt 600 ]; do sleep 0.05; i=$((i+1)); done; "
        f"test -e {flag} && echo '[bg] saw the flag' && echo 'a progress bar' "
        f"&& printf 'bar: 50%%|#  | 1/2 [00:01<00:01]\\r[bg] after a bar\\n' && touch {done}",
        # some CPU for the record: a busy loop of the child's own
        "i=0; while [ $i -lt 20000 ]; do i=$((i+1)); done",
    )
    nxt = Stage("next", "scrppl.pipeline", (("write",),), (), (tmp_path / "next.out",))
    calls, lines, cpu = [], [], {}

    def run_command(argv):
        calls.append(argv)
        flag.write_text("go")
        return 0

    status, timings = run_stages([bg, nxt], run_command, log=lines.append, cpu_seconds=cpu)
    assert status == 0 and calls == [["write"]] and done.exists()
    assert isinstance(timings["bg"], float) and timings["bg"] >= 0.0
    assert set(cpu) == {"bg", "next"} and cpu["bg"] > 0.0
    assert any("bg: running in the background" in line for line in lines)
    assert any(line.strip() == "[bg] saw the flag" for line in lines)  # relayed
    assert any(line.strip() == "[bg] after a bar" for line in lines)
    assert not any("a progress bar" in line for line in lines)  # not a message: left in the log
    assert "a progress bar" in (tmp_path / "logs" / "bg.log").read_text()
    order = [i for i, line in enumerate(lines) if "next: done" in line or "bg: done" in line]
    assert "next: done" in lines[order[0]] and "bg: done" in lines[order[1]]


def test_a_failing_background_stage_fails_the_run_and_shows_its_output(tmp_path, capsys):
    bg = _background_stage(tmp_path, "bg", "echo 'what went wrong'; exit 3", "touch never")
    status, timings = run_stages([bg], lambda argv: 0, log=lambda msg: None)
    assert status == 3 and "bg" not in timings
    err = capsys.readouterr().err
    assert "bg failed (exit 3) in the background" in err and "what went wrong" in err
    assert str(tmp_path / "logs" / "bg.log") in err


def test_a_failing_stage_stops_the_background_ones(tmp_path):
    """A run that stops at a failing stage does not leave a background stage running on its own."""
    import time

    marker = tmp_path / "late"
    bg = _background_stage(tmp_path, "bg", f"sleep 30; touch {marker}")
    fail = Stage("fail", "scrppl.pipeline", (("x",),), (), (tmp_path / "none",))
    lines = []
    t0 = time.perf_counter()
    status, _ = run_stages([bg, fail], lambda argv: 4, log=lines.append)
    assert status == 4 and time.perf_counter() - t0 < 20
    assert any("bg: stopped (a rerun resumes it)" in line for line in lines)
    assert not marker.exists()


def test_no_stage_reads_what_a_background_stage_writes(tmp_path):
    """A background stage runs beside the stages after it: none of them may take its outputs as
    inputs (they could read them half made). The full profile's sweep is one, started after detect."""
    from scrppl.pipeline import stages

    for profile in ("full", "quick", "book"):
        pipeline = stages(tmp_path / "data", tmp_path / "out", seed=0, profile=profile)
        names = [s.name for s in pipeline]
        background = [s for s in pipeline if s.background]
        assert [s.name for s in background] == ([] if profile == "book" else ["sweep"])
        for s in background:
            assert names.index(s.name) == names.index("detect") + 1
            later = pipeline[names.index(s.name) + 1 :]
            assert not set(s.outputs) & {p for t in later for p in t.inputs}
            assert s.background_log.parent == tmp_path / "out" / "logs"
