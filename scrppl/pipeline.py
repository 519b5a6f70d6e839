"""The reproduction pipeline: its stages, what each reads and writes, and running them in order.

``scrppl reproduce`` builds the stages with :func:`stages` and runs them with :func:`run_stages`;
each stage is a list of ``scrppl`` command lines, so the runner takes the function that executes one
(``scrppl.cli.main``) rather than importing the command line.

* :class:`Stage` -- one step: command lines, inputs, outputs;
* :func:`is_current` -- whether a stage's outputs are newer than its inputs (then it is skipped);
* :func:`stages` -- dataset, detect, fit, simulate, kway, sweep (not in the book profile) and decompose (the
  full profile only) for one dataset folder, output folder, seed and profile;
* :func:`uses_existing_dataset` -- whether the dataset folder is used as it is rather than generated;
* :func:`run_stages` -- run the stages that are not current;
* :func:`failed_fits` -- the hierarchical fits that failed their diagnostics (``diagnostics.json``).
"""

from __future__ import annotations

import importlib.util
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from scrppl._io import read_json

__all__ = [
    "Stage",
    "DECOMPOSE_ROWS",
    "NO_SWEEP_PROFILES",
    "is_current",
    "stages",
    "uses_existing_dataset",
    "run_stages",
    "failed_fits",
]

#: Profiles whose pipeline has no sweep stage (``scrppl sweep --profile book`` still runs it on its own).
NO_SWEEP_PROFILES = ("book",)

#: The rows of the full run's decomposition stage (``scrppl decompose --rows``).
DECOMPOSE_ROWS = ("random", "greedy_joint", "confident", "clairvoyant")


@dataclass(frozen=True)
class Stage:
    """One step of the pipeline: the command lines it runs, what it reads and what it writes."""

    name: str
    module: str
    argv: tuple[tuple[str, ...], ...]
    inputs: tuple[Path, ...]
    outputs: tuple[Path, ...]
    #: whether the stage's command takes ``--force`` (detect needs none: it reuses only identical work)
    takes_force: bool = False
    #: what the outputs must also say for the stage to count as done (the fit stage writes its
    #: diagnostics even when a fit fails them; a rerun must not then go on as if it had passed)
    complete: Callable[[], bool] | None = field(default=None, compare=False)
    #: where a background stage's output goes: it runs in a child process beside the stages after it
    #: (none of which reads its outputs), at a lower priority, so that it takes the cycles they leave
    #: idle; :func:`run_stages` waits for it before returning. ``None``: the stage runs in turn, here.
    background_log: Path | None = None
    #: ``module:function`` that runs one command line of a background stage in its child process
    runner: str = "scrppl.cli:main"

    @property
    def background(self) -> bool:
        """Whether the stage runs in a child process beside the stages after it."""
        return self.background_log is not None


def is_current(stage: Stage) -> bool:
    """Whether ``stage`` is done: its outputs exist, are newer than its inputs and are complete.

    Every output must exist and be at least as new as every existing input, and ``stage.complete``
    (when the stage has one) must say so.
    """
    if not stage.outputs or not all(p.exists() for p in stage.outputs):
        return False
    if stage.complete is not None and not stage.complete():
        return False
    newest_input = max((p.stat().st_mtime for p in stage.inputs if p.exists()), default=0.0)
    return min(p.stat().st_mtime for p in stage.outputs) >= newest_input


def stages(
    root: str | Path,
    out: str | Path,
    *,
    seed: int,
    profile: str,
    preset: str | None = None,
    errors: str = "report",
    scheduler: str | None = None,
) -> list[Stage]:
    """The pipeline in order: dataset, detect, fit, simulate, kway, sweep and (full profile) decompose.

    The sweep (``scrppl sweep``) renders new images, so it runs only for a generated synthetic dataset,
    and not in the profiles of :data:`NO_SWEEP_PROFILES` (the book's, whose time it would
    increase by about two thirds).
    The decomposition (``scrppl decompose``, rows :data:`DECOMPOSE_ROWS`) runs in the full profile.

    Parameters
    ----------
    root
        The dataset folder: the synthetic cache to generate into, or a dataset used as it is
        (:func:`uses_existing_dataset`; then the dataset stage only checks it and draws its sheet).
    out
        The output folder of every stage.
    seed, profile
        Passed to every command (``--seed``, ``--profile``). In the ``quick`` profile the fit stage
        accepts failed MCMC diagnostics (its short chains are a smoke run).
    preset
        The imaging domain of the synthetic dataset (`scrppl.datasets.synthetic.domain`), passed to every
        command as ``--preset``; ``None`` leaves each command the profile's default.
    errors
        For a dataset used as it is: ``--errors`` of the commands that read it (``"report"``: skip bad
        files and list them in ``<out>/dataset-problems.csv``; ``"raise"``: stop at the first).
    scheduler
        ``--scheduler`` of the detect, fit and simulate commands: the address of a Dask scheduler (or
        ``"local"``: each command starts its own cluster); ``None`` runs them in process.

    Returns
    -------
    list of Stage
    """
    from scrppl.datasets.core import INDEX_FILE

    root, out = Path(root), Path(out)
    common = ("--seed", str(seed), "--profile", profile)
    if preset is not None:
        common += ("--preset", preset)
    where = ("--root", str(root))
    outdir = ("--out", str(out))
    # the stages whose tasks can run on a Dask cluster
    dask = ("--scheduler", scheduler) if scheduler is not None else ()
    sheet = out / "figures" / "dataset-sheet.png"
    existing = uses_existing_dataset(root)
    on_errors = ("--errors", errors) if existing else ()
    if existing:
        # A Savarese tree has no index file: the folder itself stands for its contents.
        index = root / INDEX_FILE if (root / INDEX_FILE).exists() else root
        dataset = Stage(
            "dataset",
            "scrppl.cli.dataset",
            (
                ("dataset", "info", *where, *on_errors, "--seed", str(seed)),
                (
                    "dataset",
                    "sheet",
                    *where,
                    *outdir,
                    *on_errors,
                    "--seed",
                    str(seed),
                    "--no-validate",
                ),
            ),
            (index,),
            (sheet,),
        )
    else:
        index = root / INDEX_FILE
        dataset = Stage(
            "dataset",
            "scrppl.cli.dataset",
            (
                ("dataset", "make", *where, *common),
                ("dataset", "sheet", *where, *outdir, "--seed", str(seed)),
            ),
            (),
            (index, sheet),
        )
    pipeline = [
        dataset,
        Stage(
            "detect",
            "scrppl.cli.detect",
            (("detect", *where, *outdir, *on_errors, *common, *dask),),
            (index,),
            (out / "responses.nc",),
        ),
    ]
    # the sweep renders new images of a synthetic dataset; the book profile leaves it out (it would add
    # about two thirds to that run's time), and ch. 9 reads the one recorded from it
    # (benchmarks/results/sweep-book.nc, benchmarks/record_sweep.py) when the run has none. It needs
    # only the detectors and the response table, and no later stage reads what it writes: it runs in
    # the background from the end of the detect stage, beside fit, simulate, kway and decompose, and
    # takes the cycles they leave idle (their JIT compiles and single-threaded steps)
    if not existing and profile not in NO_SWEEP_PROFILES:
        pipeline.append(
            Stage(
                "sweep",
                "scrppl.cli.sweep",
                # views saved by planning vs random across imaging difficulty, with the run's detectors
                (("sweep", *where, *outdir, *common),),
                (out / "responses.nc",),
                (out / "sweep.nc", out / "sweep-summary.json"),
                takes_force=True,
                # a sweep made with other levels, trials or chains than the profile's is rerun (its
                # cached points at the same levels and settings are reused)
                complete=lambda: _sweep_made_with(out / "sweep-summary.json", profile),
                background_log=out / "logs" / "sweep.log",
            )
        )
    pipeline += [
        Stage(
            "fit",
            "scrppl.cli.fit",
            # The quick profile's short chains are a smoke run: its diagnostics are reported, not enforced.
            (
                (
                    "fit",
                    *outdir,
                    *common,
                    *(("--accept-diagnostics",) if profile == "quick" else ()),
                    *dask,
                ),
            ),
            (out / "responses.nc",),
            (out / "models" / "diagnostics.json",),
            takes_force=True,
            # refit when a fit failed its diagnostics (except in the quick profile) or was made by
            # another version of the model
            complete=(lambda: not stale_fits(out / "models"))
            if profile == "quick"
            else lambda: (
                not failed_fits(out / "models" / "diagnostics.json")
                and not stale_fits(out / "models")
            ),
        ),
        Stage(
            "simulate",
            "scrppl.cli.simulate",
            (("simulate", *outdir, *common, *dask),),
            (out / "models" / "diagnostics.json",),
            (out / "trials.nc",),
            takes_force=True,
        ),
        Stage(
            "kway",
            "scrppl.cli.kway",
            # K-way recognition with the DPM family's target detectors (their fits come from the fit stage)
            (
                (
                    "kway",
                    *outdir,
                    *common,
                    *(("--accept-diagnostics",) if profile == "quick" else ()),
                ),
            ),
            # it reads the fits; chained after simulate (which reruns whenever they change) to stay linear
            (out / "trials.nc",),
            (out / "kway-trials.nc", out / "kway-summary.json"),
            takes_force=True,
            # a summary whose temperature was fitted before the fit objects were left out is rerun
            complete=lambda: _kway_calibration_current(out / "kway-summary.json"),
        ),
    ]
    if profile == "full":
        # where planning gains or loses views (scrppl decompose) on the experiment's trials: random, the
        # paper's planner, the confident planner and the clairvoyant bound; the full run only (the book
        # profile keeps its time). Last; it reads the fits through the experiment's trials.
        pipeline.append(
            Stage(
                "decompose",
                "scrppl.cli.decompose",
                (("decompose", *outdir, *common, "--rows", ",".join(DECOMPOSE_ROWS), "--quiet"),),
                (out / "trials.nc",),
                (out / "decomposition.json", out / "decomposition.md"),
            )
        )
    return pipeline


def _kway_calibration_current(summary: Path) -> bool:
    """Whether ``kway-summary.json`` records how its temperature's trials were run.

    Every summary since the fit objects are left out of the models for those trials says so (``method``);
    an older one does not, and its stage is rerun.
    """
    import json

    try:
        fitted = json.loads(summary.read_text()).get("calibration_fit")
    except (OSError, ValueError):
        return False
    return fitted is None or "method" in fitted


def _sweep_made_with(summary: Path, profile: str) -> bool:
    from scrppl.cli.sweep import made_with_profile

    return made_with_profile(summary, profile)


def uses_existing_dataset(root: Path) -> bool:
    """Whether ``root`` holds a dataset that is used as it is rather than generated.

    True for a copy of the Savarese dataset and for a saved index of another source; false for the
    synthetic cache (complete or unfinished), a missing folder and anything else, which the dataset
    stage hands to ``scrppl dataset make``.
    """
    from scrppl.datasets import dataset_layout

    return dataset_layout(root) in ("savarese", "index")


def run_stages(
    pipeline: Sequence[Stage],
    run_command: Callable[[list[str]], int],
    *,
    force: bool = False,
    log: Callable[[str], None] = lambda msg: print(msg, flush=True),
    cpu_seconds: dict[str, float] | None = None,
    machine_seconds: dict[str, float] | None = None,
) -> tuple[int, dict[str, float | str]]:
    """Run every stage that is not current, in order, stopping at the first failing command.

    A stage whose module is not installed is skipped (``"not available"``), as is a current one
    (:func:`is_current`; ``"up to date"``) unless ``force``. A background stage (``stage.background``)
    starts in a child process (:func:`_background_main`, niced by :data:`BACKGROUND_NICENESS`, its
    output in ``stage.background_log``) and the stages after it go on at once; it is waited for after
    the last of them, its log lines relayed meanwhile. A failing stage stops the background ones (a
    rerun resumes them from their caches).

    Parameters
    ----------
    pipeline
        The stages (:func:`stages`).
    run_command
        Runs one ``scrppl`` command line and returns its exit status (``scrppl.cli.main``).
    force
        Rerun current stages, passing ``--force`` to the commands that take it.
    log
        Where progress lines go; a failing command is reported on ``sys.stderr``.
    cpu_seconds
        If given, filled with the CPU seconds (user + system) of each stage that ran: this process's and
        those of its child processes that ended during the stage (the spawned pools of rendering,
        training and scoring, a local Dask cluster's workers): :func:`cpu_time`; a background stage's
        are its child process's own (and its children's), which no other stage counts.
    machine_seconds
        If given, filled with the busy CPU seconds of the whole machine during each stage that ran in
        turn (:func:`machine_busy_seconds`; a background stage's beside it included): over the stage's
        wall time, how many cores were busy. Left empty where the machine does not say.

    Returns
    -------
    status
        0, or the exit status of the failing command.
    timings
        ``{stage name: seconds or "up to date" / "not available"}`` of the stages run so far (a background
        stage's seconds run from its start to its end, beside the stages after it).
    """
    timings: dict[str, float | str] = {}
    running: list[_Background] = []
    try:
        for stage in pipeline:
            if importlib.util.find_spec(stage.module) is None:
                log(f"[reproduce] {stage.name}: not available in this version, skipped")
                timings[stage.name] = "not available"
                continue
            if not force and is_current(stage):
                log(f"[reproduce] {stage.name}: up to date, skipped")
                timings[stage.name] = "up to date"
                continue
            argvs = [
                list(argv) + (["--force"] if force and stage.takes_force else [])
                for argv in stage.argv
            ]
            if stage.background:
                running.append(_Background.start(stage, argvs))
                log(
                    f"[reproduce] {stage.name}: running in the background beside the next stages "
                    f"(its output: {stage.background_log})"
                )
                continue
            log(f"[reproduce] {stage.name}: running")
            t0 = time.perf_counter()
            c0 = cpu_time()
            b0 = machine_busy_seconds()
            for argv in argvs:
                status = run_command(argv)
                if status:
                    print(
                        f"[reproduce] {stage.name} failed (exit {status}): scrppl {' '.join(argv)}",
                        file=sys.stderr,
                    )
                    return status, timings
            timings[stage.name] = round(time.perf_counter() - t0, 1)
            cpu = round(cpu_time() - c0, 1)
            if cpu_seconds is not None:
                cpu_seconds[stage.name] = cpu
            b1 = machine_busy_seconds()
            if machine_seconds is not None and b0 is not None and b1 is not None:
                machine_seconds[stage.name] = round(b1 - b0, 1)
            log(f"[reproduce] {stage.name}: done in {timings[stage.name]} s ({cpu} CPU-seconds)")
        while running:
            job = running.pop(0)
            log(f"[reproduce] {job.stage.name}: waiting for it (running in the background)")
            status = job.wait(log)
            if status:
                print(
                    f"[reproduce] {job.stage.name} failed (exit {status}) in the background; "
                    f"its output is in {job.stage.background_log}:\n{job.tail()}",
                    file=sys.stderr,
                )
                return status, timings
            timings[job.stage.name] = job.wall
            if cpu_seconds is not None:
                cpu_seconds[job.stage.name] = job.cpu
            log(
                f"[reproduce] {job.stage.name}: done in {job.wall} s ({job.cpu} CPU-seconds), "
                "in the background"
            )
        return 0, timings
    finally:
        for job in running:
            log(
                f"[reproduce] {job.stage.name}: stopped (a rerun resumes it); its output is in "
                f"{job.stage.background_log}"
            )
            job.stop()


#: How much lower a background stage's priority is (``os.nice``): the stages in turn keep the cores they
#: use, the background one takes what they leave idle.
BACKGROUND_NICENESS = 10


#: The child process of a background stage.
_CHILD = "import sys; from scrppl.pipeline import _background_main; sys.exit(_background_main(sys.argv[1]))"


class _Background:
    """A background stage's child process (:func:`run_stages`)."""

    def __init__(self, stage: Stage, proc, record: Path, logfile) -> None:
        self.stage, self.proc, self.record, self.logfile = stage, proc, record, logfile
        self.started = time.time()
        self.wall = self.cpu = 0.0
        self._relayed = 0

    @classmethod
    def start(cls, stage: Stage, argvs: list[list[str]]) -> _Background:
        import json
        import subprocess

        assert stage.background_log is not None
        logpath = Path(stage.background_log)
        logpath.parent.mkdir(parents=True, exist_ok=True)
        record = logpath.with_suffix(".exit.json")
        record.unlink(missing_ok=True)
        spec = {
            "argvs": argvs,
            "runner": stage.runner,
            "nice": BACKGROUND_NICENESS,
            "record": str(record),
        }
        logfile = open(logpath, "w")  # noqa: SIM115 (closed by wait / stop)
        proc = subprocess.Popen(
            [sys.executable, "-c", _CHILD, json.dumps(spec)],
            stdout=logfile,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
        )
        return cls(stage, proc, record, logfile)

    def _relay(self, log: Callable[[str], None]) -> None:
        """Log the child's new complete lines that are messages (``[...]``), not progress bars."""
        try:
            text = Path(self.stage.background_log).read_text(errors="replace")
        except OSError:
            return
        import re

        end = text.rfind("\n") + 1
        for line in text[self._relayed : end].splitlines():
            # a message may follow a progress bar's last update on the same line
            found = re.search(r"\[[a-z][a-z-]*\] .*", line.rsplit("\r", 1)[-1])
            if found:
                log(f"  {found.group(0)}")
        self._relayed = max(self._relayed, end)

    def wait(self, log: Callable[[str], None]) -> int:
        """Wait for the child, relaying its messages; fills ``wall`` and ``cpu``; its exit status."""
        import json
        import subprocess

        self._relayed = 0
        c0 = cpu_time()
        while True:
            try:
                status = self.proc.wait(timeout=2.0)
                break
            except subprocess.TimeoutExpired:
                self._relay(log)
        self._relay(log)
        self.logfile.close()
        # the child is reaped: its CPU (with its own children's) is in this process's children's now
        self.cpu = round(cpu_time() - c0, 1)
        self.wall = round(time.time() - self.started, 1)
        try:
            mine = json.loads(self.record.read_text())
            self.wall = round(mine["ended"] - self.started, 1)
            self.cpu = round(mine["cpu"], 1)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # ended before it wrote its record: the times seen from here
        return int(status)

    def tail(self, lines: int = 20) -> str:
        """The last ``lines`` lines of the child's output."""
        try:
            text = Path(self.stage.background_log).read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(x.rsplit("\r", 1)[-1] for x in text.splitlines()[-lines:])

    def stop(self) -> None:
        """Stop the child (if running) and close its log."""
        import subprocess

        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.logfile.close()


def _background_main(spec_text: str) -> int:
    """A background stage's child process: run its command lines in order, record wall and CPU seconds.

    ``spec_text`` is the JSON written by :meth:`_Background.start`: the command lines, the runner
    (``module:function``), the niceness and where to write ``{"status", "ended", "cpu"}`` (atomically:
    the time it ended and the CPU seconds of this process and its children).
    """
    import importlib
    import json
    import os

    from scrppl._io import atomic_path

    spec = json.loads(spec_text)
    try:
        os.nice(int(spec.get("nice", 0)))
    except (OSError, AttributeError):  # pragma: no cover - no os.nice (Windows), or not allowed
        pass
    module, _, name = spec["runner"].partition(":")
    run = getattr(importlib.import_module(module), name)
    status = 0
    for argv in spec["argvs"]:
        status = int(run(list(argv)) or 0)
        if status:
            break
    record = {"status": status, "ended": time.time(), "cpu": cpu_time()}
    with atomic_path(spec["record"]) as tmp:
        Path(tmp).write_text(json.dumps(record))
    return status


def cpu_time() -> float:
    """CPU seconds (user + system) of this process and of its ended, waited-for child processes."""
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def machine_busy_seconds(stat: str | Path = "/proc/stat") -> float | None:
    """CPU seconds the whole machine has spent busy since it started, summed over its cores.

    From the first line of Linux's ``/proc/stat``: user, nice, system, irq, softirq and steal time (not
    idle or waiting on I/O), in clock ticks. The difference over a stage is what every process did in
    it, this stage's and a background stage's beside it (and anything else running). ``None`` where the
    file cannot be read (not Linux).
    """
    import os

    try:
        first = Path(stat).read_text().splitlines()[0].split()
        ticks = os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError, AttributeError):
        return None
    if not first or first[0] != "cpu" or len(first) < 9:
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(x) for x in first[1:9])
    return (user + nice + system + irq + softirq + steal) / ticks


def machine_description() -> dict:
    """The core count and a short description of the CPU (for timing records)."""
    import os
    import platform

    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cores": os.cpu_count(), "cpu": model, "machine": platform.machine()}


def stale_fits(models_dir: str | Path) -> list[str]:
    """Saved hierarchical fits in ``models_dir`` that are not the pipeline's model (file stems).

    A fit is stale when another version of the model made it, or when it has (lacks) the instance x
    azimuth effect where the pipeline's ``--azimuth-effect auto`` would not (would) give it one: the
    effect exactly where the fit's grid has more than one ring
    (:func:`scrppl.models.study.wants_azimuth_effect`). ``scrppl fit`` refits them
    (:func:`scrppl.models.study.fit_pair`); a fit stage that holds one is not up to date, however new
    its files are.
    """
    import json

    import h5py

    from scrppl.models.io import MODEL_VERSION

    stale = []
    for path in sorted(Path(models_dir).glob("hierarchical-*.nc")):
        try:
            with h5py.File(path, "r") as fh:
                meta = fh.attrs.get("meta")
            meta = json.loads((meta.decode() if isinstance(meta, bytes) else meta) or "{}")
            version = meta.get("model_version")
            grid = meta.get("grid") or {}
            rings = len(grid.get("elevations", ())) * len(grid.get("scales", ()))
            effect_as_asked = bool(meta.get("azimuth_effect")) == (rings > 1)
        except (OSError, ValueError, TypeError, AttributeError):
            version, effect_as_asked = None, False
        if version != MODEL_VERSION or not effect_as_asked:
            stale.append(path.stem)
    return stale


def failed_fits(path: str | Path) -> list[str]:
    """Sorted ``detector/target`` names whose report in ``diagnostics.json`` at ``path`` is not ok."""
    path = Path(path)
    if not path.exists():
        return []
    diag = read_json(path, "MCMC diagnostics", remedy="rerun `scrppl fit --force` to regenerate it")
    return sorted(k for k, v in diag.items() if isinstance(v, dict) and v.get("ok") is False)
