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
from scrppl.planning import MODES, PLANNERS, choose_view
from scrppl.sim.simulator import Trials, check_starts, robot_frame
from scrppl.views import check_mask_shape

__all__ = ["TrialRecord", "run_trials", "run_trial"]

#: Phases of a trial: steps are split into this many scans, each evaluating only the candidate views
#: that can still be unvisited at its first step (more phases: less work, about twice the compilation
#: time). Batches of at least ``_MANY_TRIALS`` trials use ``_PHASES``, smaller ones a single phase.
_PHASES = 3
_MANY_TRIALS = 2048


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


def run_trial(
    key: jax.Array,
    model: ResponseModel,
    responses,
    available,
    pose,
    start,
    *,
    filter: str = "naive_bayes",
    planner: str = "sampled",
    objective: str = "joint",
    mode: str = "azimuth",
    n_steps: int = 8,
    n_samples: int = 256,
    order: int = 32,
    motion_cost=0.0,
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
    filter, planner, objective, mode, n_steps, n_samples, order, motion_cost
        See :func:`run_trials`.
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

    def observe_update(belief, visited, current, view, found):
        f = resp_r[view[0], view[1], view[2]]
        new = update(model, belief, f, view[0], view[1], view[2])
        belief = jax.tree.map(lambda n, o: jnp.where(found, n, o), new, belief)
        visited = visited.at[view[0], view[1], view[2]].set(
            visited[view[0], view[1], view[2]] | found
        )
        view = jnp.where(found, view, current)
        f = resp_r[view[0], view[1], view[2]]
        return belief, visited, view, f

    belief0 = init_belief(filter, model)
    visited0 = jnp.zeros(avail_r.shape, bool)
    belief, visited, current, f0 = observe_update(
        belief0, visited0, start, start, jnp.asarray(True)
    )
    first = (current, f0, jnp.asarray(True), joint_log_belief(belief))

    def step(carry, t, max_candidates=None):
        belief, visited, current = carry
        view, found, _ = choose_view(
            jax.random.fold_in(key, t),
            model,
            belief,
            current,
            visited,
            avail_r,
            planner=planner,
            objective=objective,
            mode=mode,
            n_samples=n_samples,
            order=order,
            motion_cost=motion_cost,
            max_candidates=max_candidates,
        )
        belief, visited, current, f = observe_update(
            belief, visited, current, view.astype(jnp.int32), found
        )
        return (belief, visited, current), (current, f, found, joint_log_belief(belief))

    # After k views at most C - k candidates are left. The steps are split into a few phases, each a
    # scan that evaluates only as many candidates as can be left at its first step.
    n_a, n_e, n_s = avail_r.shape
    n_cand = n_a if mode == "azimuth" else n_a * n_e * n_s
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


@functools.lru_cache(maxsize=64)
def _chunk_runner(n_devices: int, batch_size: int, static: tuple):
    """A compiled function that runs a chunk of trials.

    It takes the experiment's key and the chunk's first trial index and folds the per-trial keys in
    itself (no eager work per chunk). ``lax.map`` over small ``vmap`` batches (or single trials) keeps
    the intermediates in cache; the chunk is split across ``n_devices`` CPU devices with ``shard_map``.
    """
    options = dict(static)

    def local(keys, model, responses, available, pose, start, motion_cost):
        def one(args):
            k, r, a, p, st = args
            return run_trial(k, model, r, a, p, st, motion_cost=motion_cost, **options)

        return jax.lax.map(one, (keys, responses, available, pose, start), batch_size=batch_size)

    if n_devices == 1:
        run = local
    else:
        mesh = jax.sharding.Mesh(np.asarray(jax.local_devices()[:n_devices]), ("trials",))
        spec = jax.sharding.PartitionSpec("trials")
        rep = jax.sharding.PartitionSpec()
        run = jax.shard_map(
            local,
            mesh=mesh,
            in_specs=(spec, rep, spec, spec, spec, spec, rep),
            out_specs=spec,
            check_vma=False,
        )

    def chunk(key, first, model, responses, available, pose, start, motion_cost):
        index = first + jnp.arange(responses.shape[0])
        keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(index)
        return run(keys, model, responses, available, pose, start, motion_cost)

    return jax.jit(chunk)


def run_trials(
    key: jax.Array,
    model: ResponseModel,
    trials: Trials,
    *,
    filter: str = "naive_bayes",
    planner: str = "sampled",
    objective: str = "joint",
    mode: str = "azimuth",
    n_steps: int | None = None,
    n_samples: int = 256,
    order: int = 32,
    motion_cost: float = 0.0,
    chunk_size: int = 1024,
    batch_size: int = 1,
    devices: int | None = None,
    progress: bool = False,
) -> TrialRecord:
    """Run every trial with one filter and one planner.

    Parameters
    ----------
    key
        JAX PRNG key (trial ``i`` uses ``fold_in(key, i)``; use the same key for every planner).
    model
        The response model, on the same view grid as the trials.
    trials
        The trials (:func:`scrppl.sim.make_trials`).
    filter
        ``"naive_bayes"`` (the paper) or ``"instance"`` (instance-aware).
    planner
        ``"random"``, ``"sampled"`` (the paper's eq. 5), ``"quadrature"`` or ``"plug_in"``.
    objective
        Entropy objective of the entropy planners: ``"joint"``, ``"class"`` or ``"pose"``.
    mode
        Candidate views: ``"azimuth"`` (the paper) or ``"all"``.
    n_steps
        Views per trial (default ``A``; at most the number of candidate views).
    n_samples, order
        ``M`` of the sampled planner; Gauss-Hermite order of the quadrature planner.
    motion_cost
        Nats per azimuth bin travelled.
    chunk_size
        Trials per call of the compiled runner (the last chunk is padded).
    batch_size
        Trials vectorised together inside a chunk. The default, one trial at a time, keeps the
        planner's working set in the first-level cache; it was the fastest on a 2-core CPU.
    devices
        CPU devices to split each chunk over (default: all local devices; results do not depend on it).
    progress
        Show a progress bar over chunks.

    Returns
    -------
    TrialRecord
        Arrays with leading axes ``(T, K)``.
    """
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; expected one of {FILTERS}")
    if planner not in PLANNERS:
        raise ValueError(f"unknown planner {planner!r}; expected one of {PLANNERS}")
    if mode not in MODES:
        raise ValueError(f"unknown candidate mode {mode!r}; expected one of {MODES}")
    grid_shape = tuple(trials.responses.shape[1:])
    check_mask_shape(
        trials.available, trials.responses.shape, name="trials.available", where="trials.responses"
    )
    check_response_model(model, grid_shape)
    n_a, n_e, n_s = grid_shape
    max_steps = n_a if mode == "azimuth" else n_a * n_e * n_s
    n_steps = n_a if n_steps is None else int(n_steps)
    if not 1 <= n_steps <= max_steps:
        raise ValueError(f"n_steps must lie in 1..{max_steps} for mode {mode!r}, got {n_steps}")
    n = trials.n_trials
    check_starts(trials.available, trials.pose, trials.start)
    n_dev = len(jax.local_devices()) if devices is None else int(devices)
    if not 1 <= n_dev <= len(jax.local_devices()):
        raise ValueError(f"devices must lie in 1..{len(jax.local_devices())}, got {devices}")
    batch = max(1, int(batch_size))
    n_dev = max(1, min(n_dev, -(-n // batch)))  # no device without a full batch of work
    unit = n_dev * batch
    chunk = max(unit, -(-min(int(chunk_size), n) // unit) * unit)
    static = (
        ("filter", filter),
        ("planner", planner),
        ("objective", objective),
        ("mode", mode),
        ("n_steps", n_steps),
        ("n_samples", int(n_samples)),
        ("order", int(order)),
        ("phases", _PHASES if n >= _MANY_TRIALS else 1),
    )
    runner = _chunk_runner(n_dev, batch, static)
    # chunks are cut and padded on the host: indexing device arrays from Python costs a dispatch each
    host = [np.asarray(x) for x in (trials.responses, trials.available, trials.pose, trials.start)]
    outs = []
    for lo in tqdm(
        range(0, n, chunk), desc=f"{filter}/{planner}", disable=not progress, leave=False
    ):
        if lo == 0 and chunk == n:
            part = host
        else:
            sel = np.minimum(np.arange(lo, lo + chunk), n - 1)  # pad the last chunk with repeats
            part = [x[sel] for x in host]
        out = runner(key, np.int32(lo), model, *part, np.float32(motion_cost))
        if chunk == n:  # one chunk, nothing to cut
            if n_dev == 1:
                return TrialRecord(*out)
            # plain (uncommitted) arrays rather than arrays sharded over the devices
            return TrialRecord(*(jnp.asarray(np.asarray(x)) for x in out))
        keep = min(chunk, n - lo)
        outs.append([np.asarray(x)[:keep] for x in out])
    return TrialRecord(*(jnp.asarray(np.concatenate(parts)) for parts in zip(*outs, strict=True)))
