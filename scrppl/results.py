"""The outputs of one ``scrppl reproduce`` run, opened as one object.

A run folder (``results/`` by default) holds every stage's output: the response table, the saved
detectors, the fitted viewpoint models and their diagnostics, the trials, the figures and the report.
:func:`open_results` finds such a folder and returns a :class:`Results` whose methods load each stage
with the loader the pipeline itself uses, so a notebook (or a chapter of the book) starts from any stage
in one line::

    import scrppl as sp

    run = sp.open_results()                 # $SCRPPL_RESULTS, else ./results
    table = run.responses()                 # the response table (xarray.Dataset)
    m = run.model("hierarchical", "dpm", "car")   # m.response_model, m.transform, m.grid
    trials = run.trials()                   # the 160-trial experiment

``scrppl reproduce`` writes ``run.json`` (profile, seed, dataset folder) beside its outputs; a folder
without it still opens, but :attr:`Results.profile` is then ``"unknown"`` and the dataset folder must be
passed to :meth:`Results.dataset`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from scrppl._io import CorruptFileError, read_json

__all__ = ["RESULTS_ENV", "RUN_FILE", "Results", "open_results", "write_run_info"]

#: Environment variable naming the run folder that :func:`open_results` opens by default.
RESULTS_ENV = "SCRPPL_RESULTS"
#: The file ``scrppl reproduce`` writes to describe a run.
RUN_FILE = "run.json"


def write_run_info(out: str | Path, *, profile: str, seed: int, dataset_root: str | Path) -> Path:
    """Write ``run.json`` (profile, seed, dataset folder) into the run folder ``out``."""
    from scrppl._io import atomic_path

    path = Path(out) / RUN_FILE
    info = {
        "profile": profile,
        "seed": int(seed),
        "dataset_root": str(Path(dataset_root).resolve()),
    }
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(info, indent=2) + "\n")
    return path


@dataclass(frozen=True)
class Results:
    """A run folder written by ``scrppl reproduce`` (or by its stage commands one by one).

    Attributes
    ----------
    root
        The run folder.
    profile
        The profile of the run (``"full"``, ``"book"``, ``"quick"``), ``"unknown"`` without ``run.json``.
    seed
        The seed of the run (``None`` without ``run.json``).
    dataset_root
        The dataset folder the run used (``None`` without ``run.json``).
    """

    root: Path
    profile: str = "unknown"
    seed: int | None = None
    dataset_root: Path | None = None

    # -- paths ---------------------------------------------------------------------------------------
    def path(self, *parts: str) -> Path:
        """A path inside the run folder; raises ``FileNotFoundError`` naming the stage that writes it."""
        p = self.root.joinpath(*parts)
        if not p.exists():
            stage = {
                "responses.nc": "scrppl detect",
                "detectors": "scrppl detect",
                "models": "scrppl fit",
                "trials.nc": "scrppl simulate",
                "trials-large.nc": "scrppl simulate",
                "simulate-summary.json": "scrppl simulate",
            }.get(parts[0] if parts else "", "scrppl reproduce")
            raise FileNotFoundError(
                f"{p} does not exist (it is written by `{stage} --out {self.root}`)"
            )
        return p

    @property
    def figures(self) -> Path:
        """The folder of the run's figures."""
        return self.root / "figures"

    # -- stages --------------------------------------------------------------------------------------
    def dataset(self, root: str | Path | None = None, *, errors: str = "report"):
        """The multiview dataset the run was computed on (a :class:`~scrppl.datasets.MultiviewDataset`).

        The synthetic cache or a copy of the Savarese dataset (:func:`~scrppl.datasets.open_dataset`;
        a Savarese tree is split with the run's seed, as ``scrppl detect`` split it, and its bad files
        are skipped and listed in ``problems``, as the command line does by default; ``errors="raise"``
        stops at the first).
        """
        from scrppl.datasets import open_dataset

        where = Path(root) if root is not None else self.dataset_root
        if where is None:
            raise ValueError(
                f"{self.root} has no {RUN_FILE} naming its dataset folder: pass it, "
                "e.g. run.dataset('path/to/dataset')"
            )
        return open_dataset(where, split_seed=self.seed or 0, progress=False, errors=errors)

    def responses(self):
        """The response table (``responses.nc``), see :mod:`scrppl.responses`."""
        from scrppl.responses import load_response_table

        return load_response_table(self.path("responses.nc"))

    def detector(self, family: str, target: str):
        """A trained detector (``detectors/<family>-<target>.npz``)."""
        from scrppl.detectors import load_detector

        return load_detector(self.path("detectors", f"{family}-{target}.npz"))

    def detector_quality(self) -> dict[str, Any]:
        """Held-out average precision and azimuth dependence per detector (``detectors/quality.json``)."""
        return read_json(
            self.path("detectors", "quality.json"),
            "detector quality report",
            remedy="rerun `scrppl detect` to regenerate it",
        )

    def model(self, kind: str, detector: str, target: str, n_draws: int | None = None):
        """A fitted viewpoint model: :func:`scrppl.models.load_response_model` on this run's ``models/``.

        A :class:`~scrppl.models.io.ViewpointModel`: ``.response_model`` with its transform and grid.
        """
        from scrppl.models import load_response_model

        return load_response_model(self.path("models"), kind, detector, target, n_draws=n_draws)

    def posterior(self, detector: str, target: str):
        """The ArviZ ``DataTree`` of a hierarchical fit (posterior, sample stats, observed data)."""
        from scrppl.models import load_posterior, model_path

        return load_posterior(model_path(self.path("models"), "hierarchical", detector, target))

    def diagnostics(self) -> dict[str, Any]:
        """The MCMC diagnostics of every hierarchical fit (``models/diagnostics.json``)."""
        return read_json(
            self.path("models", "diagnostics.json"),
            "MCMC diagnostics",
            remedy="rerun `scrppl fit --force` to regenerate it",
        )

    def heldout(self):
        """The held-out comparison of the viewpoint models (``models/heldout.csv``) as a DataFrame."""
        import pandas as pd

        return pd.read_csv(self.path("models", "heldout.csv"))

    def trials(self, large: bool = False):
        """The experiment's trials: the paper's 160 (``trials.nc``) or the large one (``trials-large.nc``)."""
        from scrppl.sim import load_trials

        return load_trials(self.path("trials-large.nc" if large else "trials.nc"))

    def simulate_summary(self) -> dict[str, Any]:
        """The headline numbers of the experiment (``simulate-summary.json``)."""
        return read_json(
            self.path("simulate-summary.json"),
            "experiment summary",
            remedy="rerun `scrppl simulate` to regenerate it",
        )

    # -- description ---------------------------------------------------------------------------------
    def describe(self) -> str:
        """One sentence saying which run this is (for a page that shows its numbers)."""
        if self.profile == "unknown":
            return f"the run in `{self.root.name}/` (profile unknown: it has no {RUN_FILE})"
        kind = {
            "full": "a full run",
            "book": "the small `book` profile",
            "quick": "the `quick` smoke-test profile",
        }.get(self.profile, f"the `{self.profile}` profile")
        return (
            f"{kind} of the pipeline (`scrppl reproduce --profile {self.profile} --seed {self.seed}`, "
            f"in `{self.root.name}/`)"
        )


def open_results(path: str | Path | None = None) -> Results:
    """Open a run folder.

    Parameters
    ----------
    path
        The folder; by default ``$SCRPPL_RESULTS``, else ``results`` in the working directory.

    Raises
    ------
    FileNotFoundError
        If the folder does not exist, with the command that creates it.
    ValueError
        If its ``run.json`` is not valid JSON.
    """
    if path is None:
        path = os.environ.get(RESULTS_ENV) or "results"
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(
            f"no results folder at {root}: run `make reproduce` (or `scrppl reproduce --out {root}`), "
            f"or point ${RESULTS_ENV} at an existing run"
        )
    info_path = root / RUN_FILE
    if not info_path.exists():
        return Results(root=root)
    info = read_json(info_path, "run description", remedy="rerun `scrppl reproduce` to rewrite it")
    if not isinstance(info, dict):
        raise CorruptFileError(
            info_path,
            "run description",
            "not a JSON object",
            remedy="rerun `scrppl reproduce` to rewrite it",
        )
    ds = info.get("dataset_root")
    return Results(
        root=root,
        profile=str(info.get("profile", "unknown")),
        seed=info.get("seed"),
        dataset_root=Path(ds) if ds else None,
    )
