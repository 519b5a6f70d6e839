"""The trial runner: filter update and planner choice, alternating, compiled and batched.

One trial observes its start view, then for ``n_steps - 1`` steps asks the planner for the next view,
observes it and updates the belief. The whole trial is a ``jax.lax.scan``; trials are mapped over
(``lax.map``, optionally ``vmap``-ed in small batches), split across the CPU devices and run in
fixed-size chunks under one ``jit`` (the last chunk is padded), so a batch of thousands of trials
compiles once.

Determinism: trial ``i`` uses the key ``fold_in(key, i)`` and step ``t`` the key
``fold_in(fold_in(key, i), t)``, so the same key gives the same trial whatever the chunk size, and every
planner sees the same trials (instances, poses and start views come from :class:`~scrppl.sim.Trials`).
"""

from __future__ import annotations

import functools
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from scrppl.belief import FILTERS, init_belief, joint_log_belief, update
from scrppl.models.response import ResponseModel, check_response_model
from scrppl.planning import DEFAULT_PLANNER, PlannerConfig, check_planner_config, choose_view
from scrppl.sim.simulator import Trials, check_starts, robot_frame
from scrppl.views import check_mask_shape

__all__ = [
    "TrialRecord",
    "run_trials",
    "run_trial",
    "run_chunked",
    "trial_draws",
    "trial_draw_index",
    "check_draws_per_trial",
    "DRAW_STREAM",
]

#: Phases of a trial: steps are split into this many scans, each evaluating only the candidate views
#: that can still be unvisited at its first step (more phases: less work, about twice the compilation
#: time). Batches of at least ``_MANY_TRIALS`` trials use ``_PHASES``, smaller ones (and the random
#: planner, which scores no candidates) a single phase.
_PHASES = 3
_MANY_TRIALS = 2048
#: The stream of a trial's own posterior draws (``draws_per_trial``): ``fold_in(trial key, DRAW_STREAM)``
#: (far from the step indices ``t`` that the planner's keys fold in).
DRAW_STREAM = 0xD4A5


class TrialRecord(NamedTuple):
    """What happened in each trial (leading axes ``(T, K)``: trials, steps).

    Attributes
    ----------
    views
        Robot view ``(phi, e, s)`` observed at each step, ``(T, K, 3)``.
    responses
        The (transformed) response observed at each step, ``(T, K)``.
    observed
        ``(T, K)`` boolean; ``False`` when no candidate view was left (the belief is then unchanged and
        ``views``/``responses`` repeat the previous step's values).
    log_belief
        Normalised ``log p(o, theta | f_1..f_k)`` after each step, ``(T, K, O, A)``.
    """

    views: jax.Array
    responses: jax.Array
    observed: jax.Array
    log_belief: jax.Array


def observer(model: ResponseModel, resp_r: jax.Array):
    """The step a trial takes after choosing a view: observe its response and update the belief.

    Returns ``observe_update(belief, visited, current, view, found) -> (belief, visited, view, f)``: when
    ``found`` is false (no candidate was left) the belief and visited mask stay as they were and the robot
    stays at ``current``; ``f`` is the response where it now is. ``resp_r`` holds the trial's responses in
    the robot's frame (:func:`scrppl.sim.simulator.robot_frame`).
    """

    def observe_update(belief, visited, current, view, found):
        f = resp_r[view[0], view[1], view[2]]
        new = update(model, belief, f, view[0], view[1], view[2])
        belief = jax.tree.map(lambda n, o: jnp.where(found, n, o), new, belief)
        visited = visited.at[view[0], view[1], view[2]].set(
            visited[view[0], view[1], view[2]] | found
        )
        view = jnp.where(found, view, current)
        return belief, visited, view, resp_r[view[0], view[1], view[2]]

    return observe_update


def run_trial(
    key: jax.Array,
    model: ResponseModel,
    responses,
    available,
    pose,
    start,
    *,
    filter: str = "naive_bayes",
    config: PlannerConfig = DEFAULT_PLANNER,
    n_steps: int = 8,
    phases: int = 1,
) -> TrialRecord:
    """Run one trial (pure, traceable; see :func:`run_trials` for the batched, checked version).

    Parameters
    ----------
    key
        The trial's PRNG key.
    model
        The response model.
    responses, available
        The trial's object-frame responses and availability, ``(A, E, S)``.
    pose
        Hidden pose ``theta*``.
    start
        Start robot view ``(phi0, e0, s0)``.
    filter, config, n_steps
        See :func:`run_trials` (here ``config.motion_cost`` may be a traced value).
    phases
        Number of scans the steps are split into; each scores only the candidates that can still be
        unvisited at its first step (the result does not depend on it).

    Returns
    -------
    TrialRecord
        Arrays with a leading step axis ``K = n_steps``.
    """
    resp_r, avail_r = robot_frame(responses, available, pose)
    start = jnp.asarray(start, jnp.int32)

    observe_update = observer(model, resp_r)
    belief0 = init_belief(filter, model)
    visited0 = jnp.zeros(avail_r.shape, bool)
    belief, visited, current, f0 = observe_update(
        belief0, visited0, start, start, jnp.asarray(True)
    )
    first = (current, f0, jnp.asarray(True), joint_log_belief(belief))

    def step(carry, t, max_candidates=None):
        belief, visited, current = carry
        k = jax.random.fold_in(key, t)
        view, found, _ = choose_view(
            k, model, belief, current, visited, avail_r, config, max_candidates=max_candidates
        )
        belief, visited, current, f = observe_update(
            belief, visited, current, view.astype(jnp.int32), found
        )
        return (belief, visited, current), (current, f, found, joint_log_belief(belief))

    # After k views at most C - k candidates are left. The steps are split into a few phases, each a
    # scan that evaluates only as many candidates as can be left at its first step.
    n_a, n_e, n_s = avail_r.shape
    n_cand = n_a if config.mode == "azimuth" else n_a * n_e * n_s
    carry = (belief, visited, current)
    parts = [jax.tree.map(lambda x: x[None], first)]
    for lo, hi in _phases(n_steps, phases):
        carry, out = jax.lax.scan(
            partial(step, max_candidates=n_cand - lo), carry, jnp.arange(lo, hi)
        )
        parts.append(out)
    return TrialRecord(*(jnp.concatenate(x) for x in zip(*parts, strict=True)))


def _phases(n_steps: int, n_phases: int) -> list[tuple[int, int]]:
    """Split steps ``1 .. n_steps - 1`` into at most ``n_phases`` contiguous ranges ``[lo, hi)``."""
    edges = np.unique(np.linspace(1, n_steps, n_phases + 1).round().astype(int))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def trial_draws(key: jax.Array, model: ResponseModel, draws_per_trial: int | None) -> ResponseModel:
    """The posterior draws one trial's filter and planner read: ``draws_per_trial`` of the model's.

    Drawn without replacement by the trial's key (``fold_in(key, DRAW_STREAM)``: the ``draws_per_trial``
    largest of ``N`` uniforms), so every planner and filter of a trial reads the same draws, and another
    trial other draws. ``None``, or at least ``N``, keeps the model as it is. Traceable.

    Why: an experiment that reads a fit through a few fixed draws measures those draws as much as the
    posterior -- another set of equally good draws of the same fit moves its mean by more than the trials'
    interval. With each trial's own draws from the whole posterior, the mean is an average over draw sets,
    and the paired bootstrap over trials covers which draws were read.
    """
    idx = trial_draw_index(key, model.mu.shape[0], draws_per_trial)
    if idx is None:
        return model
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=0), model)


def trial_draw_index(key: jax.Array, n_draws: int, draws_per_trial: int | None) -> jax.Array | None:
    """Indices of the ``draws_per_trial`` of ``n_draws`` posterior draws the trial of ``key`` reads.

    The ``draws_per_trial`` largest of ``n_draws`` uniforms drawn with ``fold_in(key, DRAW_STREAM)``
    (without replacement, every draw equally likely); ``None`` when ``draws_per_trial`` is ``None`` or at
    least ``n_draws`` (every draw is read). Shared by :func:`trial_draws` and the K-way experiment, whose
    models carry their draw axis elsewhere. Traceable.
    """
    if draws_per_trial is None or int(draws_per_trial) >= n_draws:
        return None
    k = int(draws_per_trial)
    if k < 1:
        raise ValueError(f"draws_per_trial must be at least 1, got {draws_per_trial}")
    u = jax.random.uniform(jax.random.fold_in(key, DRAW_STREAM), (n_draws,))
    return jax.lax.top_k(u, k)[1]


def check_draws_per_trial(draws_per_trial) -> int | None:
    """``draws_per_trial`` as an ``int`` (or ``None``); a fraction, a bool or a number below 1 refused by name."""
    if draws_per_trial is None:
        return None
    if isinstance(draws_per_trial, bool) or not float(draws_per_trial).is_integer():
        raise ValueError(
            f"draws_per_trial must be a whole number of draws, got {draws_per_trial!r}"
        )
    if int(draws_per_trial) < 1:
        raise ValueError(f"draws_per_trial must be at least 1, got {draws_per_trial}")
    return int(draws_per_trial)


def _trial(key, model, motion_cost, responses, available, pose, start, *, config,
           draws_per_trial=None, **options):  # fmt: skip
    """:func:`run_trial` with the motion cost as a (traced) value beside the compiled ``config``."""
    config = config._replace(motion_cost=motion_cost)
    model = trial_draws(key, model, draws_per_trial)
    return run_trial(key, model, responses, available, pose, start, config=config, **options)


@functools.lru_cache(maxsize=64)
def _chunk_runner(trial_fn, n_devices: int, batch_size: int, static: tuple):
    """A compiled function that runs a chunk of trials with ``trial_fn``.

    ``trial_fn(key, *shared, *per_trial, **dict(static))`` runs one trial: ``shared`` are the arguments
    every trial gets (the model, the motion cost, ...), ``per_trial`` the trial's own arrays. The compiled
    function takes the experiment's key and the chunk's first trial index and folds the per-trial keys
    in itself (no eager work per chunk). ``lax.map`` over small ``vmap`` batches (or single trials) keeps
    the intermediates in cache; the chunk is split across ``n_devices`` CPU devices with ``shard_map``.
    """
    options = dict(static)

    def local(keys, shared, per_trial):
        def one(args):
            k, *own = args
            return trial_fn(k, *shared, *own, **options)

        return jax.lax.map(one, (keys, *per_trial), batch_size=batch_size)

    if n_devices == 1:
        run = local
    else:
        mesh = jax.sharding.Mesh(np.asarray(jax.local_devices()[:n_devices]), ("trials",))
        spec = jax.sharding.PartitionSpec("trials")
        rep = jax.sharding.PartitionSpec()
        run = jax.shard_map(
            local, mesh=mesh, in_specs=(spec, rep, spec), out_specs=spec, check_vma=False
        )

    def chunk(key, first, shared, per_trial):
        index = first + jnp.arange(per_trial[0].shape[0])
        keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(index)
        return run(keys, shared, per_trial)

    return jax.jit(chunk)


def run_chunked(
    trial_fn,
    static: tuple,
    key: jax.Array,
    shared: tuple,
    per_trial: tuple,
    *,
    chunk_size: int = 1024,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
    desc: str = "trials",
) -> list[jax.Array]:
    """Run a batch of trials in compiled, fixed-size chunks; the trial runners' common driver.

    Trial ``i`` gets the key ``fold_in(key, i)``, so the result does not depend on ``chunk_size``,
    ``batch_size`` or ``devices``. Used by :func:`run_trials` and by the multi-detector runner
    (:func:`scrppl.extensions.run_multi_trials`).

    Parameters
    ----------
    trial_fn
        A module-level function ``trial_fn(key, *shared, *own, **dict(static))`` returning a pytree of
        arrays for one trial (hashable: it keys the cache of compiled runners).
    static
        Hashable ``(name, value)`` pairs passed to ``trial_fn`` as keyword arguments (compiled in).
    key
        The experiment's PRNG key.
    shared
        Arguments every trial gets (replicated over the devices).
    per_trial
        Arrays with a leading trial axis ``T``; trial ``i`` gets their ``i``-th rows.
    chunk_size, batch_size, devices, progress
        As in :func:`run_trials`; ``desc`` labels the progress bar.

    Returns
    -------
    list of jax.Array
        The leaves of ``trial_fn``'s output with a leading axis ``T``.
    """
    n = int(np.shape(per_trial[0])[0])
    n_dev = len(jax.local_devices()) if devices is None else int(devices)
    if not 1 <= n_dev <= len(jax.local_devices()):
        raise ValueError(f"devices must lie in 1..{len(jax.local_devices())}, got {devices}")
    batch = max(1, int(batch_size))
    n_dev = max(1, min(n_dev, -(-n // batch)))  # no device without a full batch of work
    unit = n_dev * batch
    chunk = max(unit, -(-min(int(chunk_size), n) // unit) * unit)
    runner = _chunk_runner(trial_fn, n_dev, batch, static)
    # chunks are cut and padded on the host: indexing device arrays from Python costs a dispatch each
    host = [np.asarray(x) for x in per_trial]
    outs = []
    for lo in tqdm(range(0, n, chunk), desc=desc, disable=not progress, leave=False):
        if lo == 0 and chunk == n:
            part = host
        else:
            sel = np.minimum(np.arange(lo, lo + chunk), n - 1)  # pad the last chunk with repeats
            part = [x[sel] for x in host]
        out = runner(key, np.int32(lo), shared, tuple(part))
        if chunk == n:  # one chunk, nothing to cut
            if n_dev == 1:
                return list(out)
            # plain (uncommitted) arrays rather than arrays sharded over the devices
            return [jnp.asarray(np.asarray(x)) for x in out]
        keep = min(chunk, n - lo)
        outs.append([np.asarray(x)[:keep] for x in out])
    return [jnp.asarray(np.concatenate(parts)) for parts in zip(*outs, strict=True)]


def check_trial_inputs(
    model: ResponseModel, trials: Trials, config: PlannerConfig, filter: str, n_steps: int | None
) -> int:
    """Check a trial runner's inputs (filter, masks, model grid, starts); return the number of steps.

    ``n_steps`` ``None`` means one step per azimuth; it must lie between 1 and the candidate views of
    ``config.mode``.
    """
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; expected one of {FILTERS}")
    grid_shape = tuple(trials.responses.shape[1:])
    check_mask_shape(
        trials.available, trials.responses.shape, name="trials.available", where="trials.responses"
    )
    check_response_model(model, grid_shape)
    n_a, n_e, n_s = grid_shape
    max_steps = n_a if config.mode == "azimuth" else n_a * n_e * n_s
    n_steps = n_a if n_steps is None else int(n_steps)
    if not 1 <= n_steps <= max_steps:
        raise ValueError(
            f"n_steps must lie in 1..{max_steps} for mode {config.mode!r}, got {n_steps}"
        )
    check_starts(trials.available, trials.pose, trials.start)
    return n_steps


def run_trials(
    key: jax.Array,
    model: ResponseModel,
    trials: Trials,
    config: PlannerConfig = DEFAULT_PLANNER,
    *,
    filter: str = "naive_bayes",
    n_steps: int | None = None,
    chunk_size: int = 1024,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
    draws_per_trial: int | None = None,
) -> TrialRecord:
    """Run every trial with one filter and one planner configuration.

    Parameters
    ----------
    key
        JAX PRNG key (trial ``i`` uses ``fold_in(key, i)``; use the same key for every planner).
    model
        The response model, on the same view grid as the trials.
    trials
        The trials (:func:`scrppl.sim.make_trials`).
    config
        How each view is chosen (:class:`scrppl.planning.PlannerConfig`): the planner (``"random"``,
        ``"sampled"``, the paper's eq. 5, ``"quadrature"`` or ``"plug_in"``), its objective, the
        candidate views (``mode``: ``"azimuth"``, the paper, or ``"all"``), ``M``, the quadrature order
        and the motion cost in nats per azimuth bin travelled.
    filter
        The belief filter: ``"naive_bayes"`` (the paper) or ``"instance"`` (instance-aware).
    n_steps
        Views per trial (default ``A``; at most the number of candidate views).
    chunk_size
        Trials per call of the compiled runner (the last chunk is padded).
    batch_size
        Trials vectorised together inside a chunk. The default, one trial at a time, keeps the
        planner's working set in the first-level cache; it was the fastest on a 2-core CPU.
    devices
        CPU devices to split each chunk over (default: all local devices; results do not depend on it).
    progress
        Show a progress bar over chunks.
    draws_per_trial
        Each trial reads its own ``draws_per_trial`` posterior draws of ``model``, drawn by its key
        (:func:`trial_draws`); ``None`` (default): every trial reads all of them.

    Returns
    -------
    TrialRecord
        Arrays with leading axes ``(T, K)``.
    """
    config = check_planner_config(config)
    draws_per_trial = check_draws_per_trial(draws_per_trial)
    n_steps = check_trial_inputs(model, trials, config, filter, n_steps)
    n = trials.n_trials
    static = (
        ("filter", filter),
        ("config", config._replace(motion_cost=0.0)),  # the cost is passed as a value
        ("n_steps", n_steps),
        # the random planner scores no candidates: phases would only multiply its compilation time
        ("phases", _PHASES if n >= _MANY_TRIALS and config.planner != "random" else 1),
    )
    if draws_per_trial is not None and int(draws_per_trial) < model.mu.shape[0]:
        static += (("draws_per_trial", int(draws_per_trial)),)
    out = run_chunked(
        _trial,
        static,
        key,
        (model, np.float32(config.motion_cost)),
        (trials.responses, trials.available, trials.pose, trials.start),
        chunk_size=chunk_size,
        batch_size=batch_size,
        devices=devices,
        progress=progress,
        desc=f"{filter}/{config.planner}",
    )
    return TrialRecord(*out)
