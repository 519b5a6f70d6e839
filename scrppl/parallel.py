"""Run independent tasks in this process or on a Dask cluster, with the same results.

The stages of the pipeline (Meger et al. 2010, Secs. III-IV) are embarrassingly parallel: every
detector x target is trained on its own, every image is scored on its own, every detector x target is
fitted on its own and every target's experiment is run on its own. :func:`executor` gives those stages
one interface, :class:`Executor`, with two implementations:

* ``scheduler=None`` -- everything runs in this process, in order, exactly as without this module;
* ``scheduler="local"`` -- a :class:`distributed.LocalCluster` of ``workers`` single-threaded worker
  *processes* on this machine, started for the block and closed after it;
* ``scheduler="tcp://host:port"`` -- an existing Dask cluster (``dask scheduler`` / ``dask worker``,
  dask-jobqueue on SLURM or PBS, dask-kubernetes); its workers must see the dataset and output folders
  (a shared file system) and have scrppl installed in the same version.

Results are identical wherever a task runs:

* every task gets its inputs and seed from the caller (never from the worker it lands on), and
  :meth:`Executor.map` returns results in the order of the items;
* worker processes are started with the *spawn* method (JAX is not fork-safe) and get this process's
  JAX/XLA settings (:func:`worker_env`: ``XLA_FLAGS`` -- among them the host device count that decides
  how MCMC chains are spread --, ``JAX_PLATFORMS``, ``JAX_ENABLE_X64``, ...), one thread each for
  BLAS and OpenCV. On an existing cluster a worker that has not yet imported JAX takes those settings
  from the task; one that already runs JAX with other settings fails the task with an error naming
  the difference instead of returning different numbers.

Faults: a task whose worker dies is rescheduled by Dask on another worker (up to
``distributed.scheduler.allowed-failures`` times) and a task that raises is retried ``retries`` times;
each result is fetched as soon as its task finishes, so a worker that dies later loses no finished work.
The inputs shared by a stage's tasks (dataset index, detectors, response table) are copied to every
worker once, so they survive as long as one worker does. The stages keep their own checkpoints (the
partial response table, saved detectors and fits), so a run that is interrupted altogether -- or loses
every worker -- resumes where it stopped.

Examples
--------
>>> from scrppl.parallel import executor
>>> with executor(None) as ex:  # in process; "local" or "tcp://host:8786" for a cluster
...     ex.map(pow, [1, 2, 3], 2, progress=False)
[1, 4, 9]
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Any

__all__ = [
    "DEFAULT_RETRIES",
    "JAX_ENV",
    "Executor",
    "DaskExecutor",
    "executor",
    "local_cluster",
    "worker_env",
    "single_threaded_children",
    "spawned_pool_map",
    "check_scheduler",
]

#: Times a task that raises is retried on a cluster (a task whose worker dies is rescheduled anyway).
DEFAULT_RETRIES = 2

#: Environment variables that change what JAX computes; workers get this process's values.
JAX_ENV = (
    "XLA_FLAGS",
    "JAX_PLATFORMS",
    "JAX_ENABLE_X64",
    "JAX_DEFAULT_MATMUL_PRECISION",
    "JAX_DEFAULT_PRNG_IMPL",
    "JAX_THREEFRY_PARTITIONABLE",
)

#: Single-threaded numerical libraries in every worker (one worker per core).
_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """While open, processes started from here run BLAS, OpenMP and XLA single-threaded (one per core).

    Sets :data:`_THREAD_ENV` and turns off XLA's multi-threaded Eigen in ``os.environ`` (which spawned
    children inherit) and restores the previous values on leaving.
    """
    names = (*_THREAD_ENV, "XLA_FLAGS")
    saved = {k: os.environ.get(k) for k in names}
    os.environ.update(_THREAD_ENV)
    os.environ["XLA_FLAGS"] = (
        (saved["XLA_FLAGS"] or "") + " --xla_cpu_multi_thread_eigen=false"
    ).strip()
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def spawned_pool_map(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
) -> Iterator[Any]:
    """Yield ``fn(item)`` for every item as it finishes, computed in ``workers`` spawned processes.

    The processes are started with the *spawn* method (JAX is not fork-safe) inside
    :func:`single_threaded_children`; ``initializer(*initargs)`` runs once in each (the place to hand it
    large shared inputs). Results come in the order they finish, not the order of ``items``: pass the
    index along with the item where it matters. An exception of ``fn`` is raised here.
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with (
        single_threaded_children(),
        ProcessPoolExecutor(
            max_workers=workers,
            mp_context=mp.get_context("spawn"),
            initializer=initializer,
            initargs=initargs,
        ) as pool,
    ):
        futures = [pool.submit(fn, item) for item in items]
        for fut in as_completed(futures):
            yield fut.result()


def worker_env() -> dict[str, str]:
    """The JAX settings of this process that every worker must share (:data:`JAX_ENV` that are set)."""
    return {k: os.environ[k] for k in JAX_ENV if k in os.environ}


def check_scheduler(scheduler: str | None) -> str | None:
    """Check a ``--scheduler`` value: ``None``, ``"local"`` or a scheduler address (``tcp://host:port``).

    Raises
    ------
    ValueError
        For anything else.
    """
    if scheduler is None or scheduler == "local":
        return scheduler
    if isinstance(scheduler, str) and "://" in scheduler and scheduler.split("://", 1)[1]:
        return scheduler
    raise ValueError(
        f"unknown scheduler {scheduler!r}: use 'local' (a cluster on this machine) or the address of "
        "a running Dask scheduler, e.g. 'tcp://10.0.0.5:8786'"
    )


# -- what runs on a worker -----------------------------------------------------------------------------
def _task_ref(fn: Callable) -> Callable | str:
    """``"module:qualname"`` for scrppl's own functions, else the function itself.

    A worker resolves the name after it has applied the JAX settings (unpickling a function imports its
    module, and with it JAX).
    """
    module, name = getattr(fn, "__module__", ""), getattr(fn, "__qualname__", "")
    if module.split(".")[0] == "scrppl" and "<" not in name:
        return f"{module}:{name}"
    return fn


def _resolve(ref: Callable | str) -> Callable:
    if callable(ref):
        return ref
    module, name = ref.split(":")
    obj: Any = importlib.import_module(module)
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


def _apply_env(env: dict[str, str]) -> None:
    """Give this worker the caller's JAX settings, or fail if JAX already runs with others."""
    if "jax" not in sys.modules:
        for k in JAX_ENV:
            if k in env:
                os.environ[k] = env[k]
            else:
                os.environ.pop(k, None)
        return
    differ = {
        k: (env.get(k), os.environ.get(k)) for k in JAX_ENV if env.get(k) != os.environ.get(k)
    }
    if differ:
        raise RuntimeError(
            "this Dask worker already runs JAX with other settings than the process that submitted "
            "the task, so its results could differ: "
            + "; ".join(
                f"{k}: submitted with {a!r}, worker has {b!r}" for k, (a, b) in differ.items()
            )
            + ". Start the workers with the same environment (scrppl.parallel.worker_env() lists it)."
        )


def _call(ref: Callable | str, env: dict[str, str], item: Any, *args: Any) -> Any:
    """One task on a worker: the caller's JAX settings, one OpenCV thread, then ``fn(item, *args)``."""
    _apply_env(env)
    with contextlib.suppress(ImportError):
        import cv2

        cv2.setNumThreads(1)
    return _resolve(ref)(item, *args)


# -- executors -----------------------------------------------------------------------------------------
class Executor:
    """Runs ``fn(item, *args)`` for every item in this process, in order (``scheduler=None``).

    :class:`DaskExecutor` does the same on a Dask cluster; code written against this class runs on
    either.
    """

    #: Whether tasks run in other processes (on a cluster).
    distributed = False
    #: The scheduler: ``None`` in process, else the cluster's address.
    scheduler: str | None = None

    @property
    def n_workers(self) -> int:
        """Worker processes available (1 in process)."""
        return 1

    def as_completed(self, fn: Callable, items: Iterable, *args: Any) -> Iterator[tuple[int, Any]]:
        """``(index, fn(item, *args))`` for every item, as each finishes (in order here).

        ``fn`` must be picklable (a module-level function) for a cluster; ``args`` are shared by every
        call and sent to each worker once.
        """
        for i, item in enumerate(items):
            yield i, fn(item, *args)

    def map(
        self,
        fn: Callable,
        items: Iterable,
        *args: Any,
        desc: str | None = None,
        progress: bool = True,
    ) -> list:
        """``[fn(item, *args) for item in items]``, in the order of ``items``, with a progress bar.

        Parameters
        ----------
        fn
            The task; a module-level function when it runs on a cluster.
        items
            One task per item.
        *args
            Arguments shared by every task (sent to each worker once).
        desc
            Label of the progress bar.
        progress
            Show a progress bar over tasks.

        Returns
        -------
        list
            The results, ordered like ``items``.
        """
        from tqdm.auto import tqdm

        items = list(items)
        out: list = [None] * len(items)
        with tqdm(total=len(items), desc=desc, disable=not progress) as bar:
            for i, result in self.as_completed(fn, items, *args):
                out[i] = result
                bar.update(1)
        return out


class DaskExecutor(Executor):
    """Runs tasks on a Dask cluster through a :class:`distributed.Client` (see the module docstring).

    Parameters
    ----------
    client
        A connected client.
    retries
        Times a task that raises is retried.
    """

    distributed = True

    def __init__(self, client, *, retries: int = DEFAULT_RETRIES):
        self.client = client
        self.retries = int(retries)
        self.scheduler = client.scheduler.address

    @property
    def n_workers(self) -> int:
        """Workers connected to the scheduler now."""
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    def as_completed(self, fn: Callable, items: Iterable, *args: Any) -> Iterator[tuple[int, Any]]:
        """``(index, fn(item, *args))`` as tasks finish on the cluster; each result is fetched at once.

        The shared arguments are scattered to every worker. If the workers holding them all die before
        every task has run (Dask then cancels the tasks that needed them), they are scattered again and
        the unfinished tasks resubmitted, up to ``retries`` times; finished tasks are never rerun.
        Interrupting the iteration (an error, Ctrl-C) cancels the tasks not yet finished.
        """
        from distributed import as_completed

        remaining = dict(enumerate(items))
        env, ref = worker_env(), _task_ref(fn)
        for _ in range(self.retries + 1):
            if not remaining:
                return
            # shared arguments go to every worker once (a restarted worker copies them from another one)
            shared = [self.client.scatter([a], broadcast=True, hash=False)[0] for a in args]
            futures = {
                self.client.submit(
                    _call, ref, env, item, *shared, pure=False, retries=self.retries
                ): i
                for i, item in remaining.items()
            }
            try:
                for fut, result in as_completed(list(futures), with_results=True):
                    if fut.status == "cancelled":  # its shared inputs were lost with their workers
                        continue
                    i = futures[fut]
                    del remaining[i]
                    yield i, result
                    fut.release()
            finally:
                self.client.cancel(list(futures))
                del shared
        if remaining:
            raise RuntimeError(
                f"{len(remaining)} of the stage's tasks lost their shared inputs {self.retries + 1} times "
                "(workers dying faster than they are replaced); rerun the command to resume"
            )


def local_cluster(n_workers: int | None = None, **kwargs):
    """A :class:`distributed.LocalCluster` of single-threaded worker processes on this machine.

    The workers get this process's JAX settings (:func:`worker_env`) and one BLAS thread each; they are
    started with the spawn method (JAX is not fork-safe) and without a dashboard.

    Parameters
    ----------
    n_workers
        Worker processes (default: one per core).
    **kwargs
        Passed to :class:`distributed.LocalCluster` (they override the defaults above).
    """
    from scrppl._extras import require

    dask = require("dask", "dask")
    LocalCluster = require("dask", "distributed").LocalCluster

    options = dict(
        n_workers=int(n_workers or os.cpu_count() or 1),
        threads_per_worker=1,
        processes=True,
        # no dashboard; its HTTP server (health checks) on a free port, not 8787 (another cluster's)
        dashboard_address=":0",
        scheduler_kwargs={"dashboard": False},
        env={**_THREAD_ENV, **worker_env()},
        silence_logs=logging.ERROR,
    )
    options.update(kwargs)
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn"}):
        return LocalCluster(**options)


@contextlib.contextmanager
def executor(
    scheduler: str | None = None,
    *,
    workers: int | None = None,
    retries: int = DEFAULT_RETRIES,
) -> Iterator[Executor]:
    """The executor of ``--scheduler``: in process, a local cluster, or an existing cluster.

    Parameters
    ----------
    scheduler
        ``None`` (in process), ``"local"`` (:func:`local_cluster`, closed when the block ends) or the
        address of a running Dask scheduler (``"tcp://host:port"``).
    workers
        Worker processes of the local cluster (default: one per core); ignored otherwise.
    retries
        Times a task that raises is retried on a cluster.

    Yields
    ------
    Executor
        :class:`Executor` in process, :class:`DaskExecutor` on a cluster.

    Raises
    ------
    ValueError
        For a scheduler that is neither ``"local"`` nor an address.
    OSError
        When no scheduler answers at the address (Dask's error, with the address).
    """
    scheduler = check_scheduler(scheduler)
    if scheduler is None:
        yield Executor()
        return
    from scrppl._extras import require

    Client = require("dask", "distributed").Client
    if scheduler == "local":
        with local_cluster(workers) as cluster, Client(cluster) as client:
            yield DaskExecutor(client, retries=retries)
    else:
        with Client(scheduler, timeout="30s") as client:
            yield DaskExecutor(client, retries=retries)
