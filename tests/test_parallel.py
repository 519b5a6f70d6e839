"""Stages on a Dask cluster give what they give in process: same bytes, same arrays, no lost work.

One ``LocalCluster`` of two single-threaded worker processes serves the module; the code under test
reaches it through its ``tcp://`` address, as it would reach a cluster on other machines
(``--scheduler tcp://host:port``). ``--scheduler local`` (a cluster started by the command) is tested
through ``scrppl detect``.
"""

import hashlib
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import cloudpickle
import numpy as np
import pandas as pd
import pytest
import xarray as xr
from test_detectors_scoring import _make_toy

from scrppl.datasets.core import MultiviewDataset
from scrppl.detectors import SiftMatcher
from scrppl.detectors.scoring import partial_path, score_dataset
from scrppl.detectors.train import train_detectors
from scrppl.parallel import Executor, check_scheduler, executor, local_cluster

# the helpers below run on the workers: send them by value (the workers cannot import this file)
cloudpickle.register_pickle_by_value(sys.modules[__name__])

FAMILIES = ["sift", "bof"]


@pytest.fixture(scope="module")
def cluster():
    with local_cluster(2) as c:
        yield c


@pytest.fixture
def remote(cluster):
    """An executor on the module's cluster, reached by its address."""
    assert cluster.scheduler_address.startswith("tcp://")
    with executor(cluster.scheduler_address) as ex:
        yield ex


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy")
    _make_toy(root).save()
    return MultiviewDataset.load(root)


@pytest.fixture(scope="module")
def trained(toy, tmp_path_factory):
    out = tmp_path_factory.mktemp("trained")
    return train_detectors(toy, FAMILIES, None, seed=3, out_dir=out, progress=False)


# -- the executor --------------------------------------------------------------------------------------
def _jax_task(i, seed, delay):
    import jax

    time.sleep(delay[i])  # later items finish first on the cluster
    k = jax.random.fold_in(jax.random.key(seed), i)
    a = jax.random.normal(k, (64, 64))
    return np.asarray(a @ a.T).tobytes(), jax.local_device_count(), os.getpid()


def test_executor_results_are_ordered_and_identical_in_process_and_on_a_cluster(remote):
    import jax

    delay = [0.3, 0.2, 0.1, 0.0, 0.0, 0.0]
    with executor(None) as ex:
        assert type(ex) is Executor and not ex.distributed and ex.n_workers == 1
        here = ex.map(_jax_task, range(6), 11, delay, progress=False)
    remote.client.wait_for_workers(2, timeout=60)  # a worker killed by another test is back
    there = remote.map(_jax_task, range(6), 11, delay, progress=False)
    assert remote.distributed and remote.n_workers == 2
    # same bytes, in the order of the items, from the workers' processes
    assert [h[0] for h in here] == [t[0] for t in there]
    assert len({h[0] for h in here}) == 6
    assert {t[2] for t in there}.isdisjoint({os.getpid()})
    # the workers run JAX with this process's XLA flags (the host device count among them)
    assert {t[1] for t in there} == {jax.local_device_count()}


def _fails_once(i, marker_dir):
    marker = marker_dir / f"failed-{i}"
    if i == 2 and not marker.exists():
        marker.touch()
        raise OSError("transient failure")
    return i * i


def test_a_task_that_raises_is_retried_and_errors_reach_the_caller(remote, tmp_path):
    assert remote.map(_fails_once, range(4), tmp_path, progress=False) == [0, 1, 4, 9]
    assert (tmp_path / "failed-2").exists()
    with pytest.raises(ZeroDivisionError):
        remote.map(divmod, [1, 2], 0, progress=False)


def _logged_square(item, folder):
    (folder / f"{item}-{time.perf_counter_ns()}-{os.getpid()}").touch()  # one file per run
    return item * item


class _CancellingClient:
    """A Dask client that cancels the first submission of chosen items, as Dask cancels the tasks whose
    scattered shared inputs were lost with their workers; everything else goes to the real client."""

    def __init__(self, client, cancel):
        self._client = client
        self.cancel_once = set(cancel)
        self.submitted: list = []  # the items, in the order their tasks were submitted

    def __getattr__(self, name):
        return getattr(self._client, name)

    def submit(self, func, *args, **kwargs):
        fut = self._client.submit(func, *args, **kwargs)
        item = args[2]  # DaskExecutor submits _call(ref, env, item, *shared)
        self.submitted.append(item)
        if item in self.cancel_once:
            self.cancel_once.discard(item)
            self._client.cancel([fut])
        return fut


@pytest.mark.parametrize("how", ["as_completed", "map"])
def test_resubmitted_tasks_land_on_their_items_and_finished_ones_are_not_rerun(tmp_path, how):
    """Catches the executor's resubmission after lost shared inputs putting results on the wrong items
    (e.g. the unfinished tasks renumbered from 0) or rerunning tasks that had finished."""
    from distributed import Client

    from scrppl.parallel import DaskExecutor

    items = [10, 11, 12, 13, 14, 15]  # values unlike their indices 0..5
    with Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=":0") as real:
        client = _CancellingClient(real, cancel=[12, 14])
        ex = DaskExecutor(client, retries=2)
        if how == "map":
            assert ex.map(_logged_square, items, tmp_path, progress=False) == [
                100, 121, 144, 169, 196, 225,
            ]  # fmt: skip
        else:
            got = list(ex.as_completed(_logged_square, items, tmp_path))
            assert sorted(got) == [(0, 100), (1, 121), (2, 144), (3, 169), (4, 196), (5, 225)]
    # the two cancelled tasks were submitted again, once; every other task exactly once
    assert sorted(client.submitted) == [10, 11, 12, 12, 13, 14, 14, 15]
    assert client.submitted[6:] in ([12, 14], [14, 12])
    runs = [int(p.name.split("-")[0]) for p in tmp_path.iterdir()]
    assert all(runs.count(i) == 1 for i in (10, 11, 13, 15))  # finished tasks never rerun


def test_scheduler_values_are_checked():
    assert check_scheduler(None) is None and check_scheduler("local") == "local"
    assert check_scheduler("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    for bad in ("cluster", "tcp://", "10.0.0.5:8786"):
        with pytest.raises(ValueError, match="unknown scheduler"):
            check_scheduler(bad)


# -- training and scoring --------------------------------------------------------------------------------
def test_training_and_scoring_on_a_cluster_write_the_same_bytes(toy, trained, remote, tmp_path):
    out = tmp_path / "cluster"
    dets = train_detectors(
        toy, FAMILIES, None, seed=3, out_dir=out, progress=False, executor=remote
    )
    assert list(dets) == FAMILIES and all(list(d) == toy.categories for d in dets.values())
    for fam in FAMILIES:
        for t in toy.categories:
            assert dets[fam][t].fingerprint() == trained[fam][t].fingerprint()
            assert (out / "detectors" / f"{fam}-{t}.npz").exists()
    here = score_dataset(toy, trained, path=tmp_path / "here.nc", progress=False, workers=1)
    there = score_dataset(toy, dets, path=tmp_path / "there.nc", progress=False, executor=remote)
    xr.testing.assert_identical(here, there)
    assert (tmp_path / "here.nc").read_bytes() == (tmp_path / "there.nc").read_bytes()


def test_training_in_a_pool_of_processes_gives_the_same_detectors(toy, trained, tmp_path):
    dets = train_detectors(toy, FAMILIES, None, seed=3, out_dir=tmp_path, progress=False, workers=2)
    assert list(dets) == FAMILIES and all(list(d) == toy.categories for d in dets.values())
    saved = {}
    for fam in FAMILIES:
        for t in toy.categories:
            assert dets[fam][t].fingerprint() == trained[fam][t].fingerprint()
            saved[f"{fam}-{t}"] = (tmp_path / "detectors" / f"{fam}-{t}.npz").stat().st_mtime_ns
    # every detector and its settings were saved: a rerun loads them all instead of training
    again = train_detectors(
        toy, FAMILIES, None, seed=3, out_dir=tmp_path, progress=False, workers=2
    )
    for fam in FAMILIES:
        for t in toy.categories:
            assert again[fam][t].fingerprint() == trained[fam][t].fingerprint()
            path = tmp_path / "detectors" / f"{fam}-{t}.npz"
            assert path.stat().st_mtime_ns == saved[f"{fam}-{t}"]
    for bad in (0, 1.5):
        with pytest.raises(ValueError, match="workers must be a positive integer"):
            train_detectors(toy, FAMILIES, None, seed=3, progress=False, workers=bad)


class _KillsItsWorker(SiftMatcher):
    """SIFT that logs every image it prepares and kills its worker process on one image, once."""

    family = "sift-kill"
    log = None
    marker = None
    victim = None  # sha1 of the image whose preparation kills the worker
    home = None  # the test process (never killed)

    def prepare(self, image, box):
        digest = hashlib.sha1(image.tobytes()).hexdigest()
        with open(self.log, "a") as f:
            f.write(digest + "\n")
        if os.getpid() != self.home and digest == self.victim and not self.marker.exists():
            self.marker.touch()
            time.sleep(1.5)  # let the results this worker finished reach the client
            os.kill(os.getpid(), signal.SIGKILL)
        return super().prepare(image, box)


def _killer(trained, toy, tmp_path, victim_row):
    det = _KillsItsWorker("cat")
    det._set_state(trained["sift"]["cat"]._get_state())
    det.log, det.marker, det.home = str(tmp_path / "log"), tmp_path / "killed", os.getpid()
    det.victim = hashlib.sha1(toy.load_image(victim_row).tobytes()).hexdigest()
    return det


def test_a_killed_worker_loses_no_finished_work(toy, trained, cluster, remote, tmp_path):
    victim = toy.row("coffee", 1, 2, 1)
    det = _killer(trained, toy, tmp_path, victim)
    detectors = {"sift-kill": {"cat": det}}
    remote.client.wait_for_workers(2, timeout=120)  # a worker restarted by an earlier test is back
    before = set(cluster.scheduler.workers)
    table = score_dataset(toy, detectors, progress=False, executor=remote)
    assert (tmp_path / "killed").exists()  # a worker died mid-stage ...
    assert set(cluster.scheduler.workers) != before  # ... and its nanny started a new one
    log = (tmp_path / "log").read_text().split()
    det.log = str(tmp_path / "log-here")
    ref = score_dataset(toy, detectors, progress=False)  # in process: nothing is killed
    np.testing.assert_array_equal(table["score"].values, ref["score"].values)
    # every image was prepared; only the views of the instance being scored when the worker died
    # were prepared again
    counts = {d: log.count(d) for d in set(log)}
    assert len(counts) == len(toy)
    again = {d for d, n in counts.items() if n > 1}
    coffee1 = {
        hashlib.sha1(toy.load_image(r).tobytes()).hexdigest()
        for _, r in toy.select(category="coffee", instance=1).iterrows()
    }
    assert det.victim in again and again <= coffee1
    assert max(counts.values()) == 2


def test_an_interrupted_cluster_run_resumes(toy, trained, remote, tmp_path):
    path = tmp_path / "responses.nc"
    seen = []

    def stop_after_four(chunk, timing):
        seen.append(chunk)
        if len(seen) == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        score_dataset(
            toy, trained, path=path, progress=False, executor=remote, on_chunk=stop_after_four,
            checkpoint_seconds=0,
        )  # fmt: skip
    assert partial_path(path).exists() and not path.exists()
    first = list(seen)
    seen.clear()
    table = score_dataset(
        toy,
        trained,
        path=path,
        progress=False,
        executor=remote,
        on_chunk=lambda c, t: seen.append(c),
    )
    # only the instances not finished before are scored, and the table is an uninterrupted run's
    assert sorted(first + seen) == sorted(
        (str(c), int(i))
        for c, i in zip(toy.instances["category"], toy.instances["instance"], strict=True)
    )
    ref = score_dataset(toy, trained, progress=False)
    np.testing.assert_array_equal(table["score"].values, ref["score"].values)


# -- fits and experiments --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def responses(tmp_path_factory):
    import jax

    from scrppl.models.simulate import random_true_model, simulate_response_table
    from scrppl.responses import save_response_table
    from tests.test_models_hierarchical import RECOVERY_GRID

    params = {
        ("dpm", t): random_true_model(jax.random.key(i), RECOVERY_GRID, kappa=0.0)
        for i, t in enumerate(["c0", "c1"])
    }
    table = simulate_response_table(
        jax.random.key(7), params, ["c0", "c1"], 8, RECOVERY_GRID, {"fit": 5, "test": 3}
    )
    path = tmp_path_factory.mktemp("responses") / "responses.nc"
    save_response_table(table, path)
    return path


@pytest.mark.slow
def test_fits_and_experiments_on_a_cluster_equal_those_in_process(responses, remote, tmp_path):
    import jax

    from scrppl.models.mcmc import SamplerConfig
    from scrppl.models.study import fit_study
    from scrppl.planning import PlannerConfig
    from scrppl.responses import load_response_table
    from scrppl.sim.study import run_study

    # short chains (compiling dominates); at the highest acceptance target a failed fit is not retried
    config = SamplerConfig(30, 30, num_chains=2, chunk=30, target_accept_prob=0.99)
    key = jax.random.key(5)

    def fit_and_simulate(name, ex):
        models = tmp_path / name / "models"
        fits = fit_study(key, responses, models, config, progress=False, executor=ex)
        study = run_study(
            1, load_response_table(responses), models, "dpm", ["c0", "c1"],
            trials=6, large_trials=8, config=PlannerConfig(n_samples=8),
            kinds=["gaussian", "hierarchical"], executor=ex,
        )  # fmt: skip
        return fits, study

    # the cluster's run waits on its workers in a thread while this process computes its own
    with ThreadPoolExecutor(1) as pool:
        there = pool.submit(fit_and_simulate, "there", remote)
        fits, study = fit_and_simulate("here", None)
        fits2, study2 = there.result()
    assert list(fits2.fits) == list(fits.fits) == [("dpm", "c0"), ("dpm", "c1")]
    for pair in fits.fits:
        a, b = fits.fits[pair].posterior, fits2.fits[pair].posterior
        for var in a["posterior"].data_vars:
            np.testing.assert_array_equal(a["posterior"][var].values, b["posterior"][var].values)
        np.testing.assert_array_equal(
            fits.fits[pair].hierarchical.mu, fits2.fits[pair].hierarchical.mu
        )
    assert fits.diagnostics == fits2.diagnostics
    # the held-out scores, computed by each fit's task there and after the fits here
    assert fits.heldout is not None and len(fits.heldout) > 0
    pd.testing.assert_frame_equal(fits.heldout, fits2.heldout)
    # the pairs differ from each other (each has its own key and data): the check above can fail
    assert not np.array_equal(
        fits.fits["dpm", "c0"].hierarchical.mu, fits.fits["dpm", "c1"].hierarchical.mu
    )
    xr.testing.assert_identical(study.trials, study2.trials)
    assert list(study2.trials["target"].values) == ["c0", "c1"]
    # the large experiment ran as one task per target and model kind there, in one piece here
    xr.testing.assert_identical(study.large, study2.large)
    assert study.large.sizes["method"] == 3  # gaussian + naive Bayes, hierarchical + both filters
    assert study.calibration == study2.calibration
    assert study.summary["settings"] == study2.summary["settings"]
    drop = ("seconds", "seconds_total", "large_seconds")
    for t in ("c0", "c1"):
        a = {k: v for k, v in study.summary["targets"][t].items() if k not in drop}
        b = {k: v for k, v in study2.summary["targets"][t].items() if k not in drop}
        assert a == b
        np.testing.assert_array_equal(study.examples[t][0], study2.examples[t][0])


# -- the command line ------------------------------------------------------------------------------------
@pytest.mark.slow  # `scrppl detect` three times, on a Dask cluster too
def test_detect_command_gives_the_same_table_in_process_on_a_local_and_on_a_running_cluster(
    toy, cluster, tmp_path
):
    from scrppl.cli import main

    base = ["detect", "--root", str(toy.root), "--families", "sift", "--targets", "cat,astro"]
    base += ["--no-figures", "--quiet"]
    runs = {
        "here": ["--workers", "1"],
        "local": ["--scheduler", "local", "--workers", "2"],
        "running": ["--scheduler", cluster.scheduler_address],
    }
    for name, extra in runs.items():
        assert main([*base, "--out", str(tmp_path / name), *extra]) == 0
    tables = {name: (tmp_path / name / "responses.nc").read_bytes() for name in runs}
    assert tables["local"] == tables["here"] and tables["running"] == tables["here"]
    assert main([*base, "--out", str(tmp_path / "bad"), "--scheduler", "nowhere"]) != 0


def test_reproduce_passes_the_scheduler_to_the_stages_that_use_it(tmp_path):
    from scrppl.pipeline import stages

    plain = stages(tmp_path / "data", tmp_path / "out", seed=0, profile="quick")
    assert not any("--scheduler" in argv for s in plain for argv in s.argv)
    addr = "tcp://10.0.0.5:8786"
    chain = stages(tmp_path / "data", tmp_path / "out", seed=0, profile="quick", scheduler=addr)
    with_flag = {s.name for s in chain for argv in s.argv if argv[-2:] == ("--scheduler", addr)}
    assert with_flag == {"detect", "fit", "simulate"}
    # nothing else changes: the same outputs are checked for being current
    assert [s.outputs for s in chain] == [s.outputs for s in plain]


def test_asking_for_host_devices_after_jax_started_leaves_the_environment_true():
    """A command run in a session that already used JAX cannot change its device count; XLA_FLAGS must
    keep saying what JAX runs with, since workers started later copy it (worker_env)."""
    code = (
        "import os\n"
        "os.environ['XLA_FLAGS'] = '--xla_force_host_platform_device_count=2'\n"
        "import jax, re\n"
        "from scrppl.cli.fit import _configure_host_devices\n"
        "from scrppl.parallel import worker_env\n"
        "jax.numpy.zeros(1)\n"
        "_configure_host_devices(4)\n"
        "n = int(re.search(r'device_count=(\\d+)', worker_env()['XLA_FLAGS']).group(1))\n"
        "print(n, jax.local_device_count())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["2", "2"]
