"""The trial simulator over held-out instances of a response table (Meger et al. 2010, Sec. IV-A).

Each trial picks a held-out (``test`` split) instance that is either a positive (its category is the
target) or a negative for the target, a hidden object pose ``theta*`` and a random start robot azimuth
``phi0`` at an elevation and scale where the instance has every azimuth. Observing robot view
``(phi, e, s)`` returns the pre-collected response at relative azimuth ``(phi - theta*) mod A``
(:func:`observe`). Responses are passed through the viewpoint model's transform before filtering.

Missing views (NaN in the table) are never used as numbers: :class:`Trials` carries an ``available``
mask, the runner never offers unavailable views as candidates, and :func:`observe` refuses them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from scrppl.responses import table_grid, validate_response_table
from scrppl.views import check_view_array

__all__ = [
    "Trials",
    "make_trials",
    "draw_trials",
    "transformed_scores",
    "robot_frame",
    "observe",
    "select_trials",
    "check_starts",
]


class Trials(NamedTuple):
    """A batch of simulated trials (a pytree; leading axis ``T`` = number of trials).

    Attributes
    ----------
    responses
        Transformed responses of each trial's instance in the *object* frame, ``(T, A, E, S)``
        (``responses[t, a, e, s]`` is the response at relative azimuth ``a``); missing views hold 0.
    available
        ``(T, A, E, S)`` boolean: ``False`` where the table is NaN (the image does not exist).
    label
        True class ``o*`` (1 = the target is present), ``(T,)``.
    pose
        Hidden object pose ``theta*`` in azimuth bins, ``(T,)``.
    start
        Start robot view ``(phi0, e0, s0)``, ``(T, 3)``.
    category
        Index of the instance's category in the table's ``category`` coordinate, ``(T,)``.
    instance
        Index of the instance in the table's ``instance`` coordinate, ``(T,)``.
    """

    responses: jax.Array
    available: jax.Array
    label: jax.Array
    pose: jax.Array
    start: jax.Array
    category: jax.Array
    instance: jax.Array

    @property
    def n_trials(self) -> int:
        """Number of trials ``T``."""
        return self.label.shape[0]


def make_trials(
    key: jax.Array,
    table: xr.Dataset,
    detector: str,
    target: str,
    n_trials: int,
    *,
    positive_fraction: float = 0.5,
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
    split: str = "test",
) -> Trials:
    """Draw ``n_trials`` trials from the held-out instances of a response table.

    Exactly ``round(positive_fraction * n_trials)`` trials show a positive instance (category ==
    target), the rest a negative one (any other category); their order is random. Instances are drawn
    uniformly with replacement within each group; the pose ``theta*`` and the start azimuth ``phi0`` are
    uniform over the ``A`` bins; the start elevation and scale are uniform over the ``(e, s)`` rings on
    which the instance has all ``A`` azimuths (instances with no complete ring are not used).

    Parameters
    ----------
    key
        JAX PRNG key: the same key gives the same trials.
    table
        A response table (:mod:`scrppl.responses`).
    detector, target
        Which detector and target category to simulate.
    n_trials
        Number of trials ``T``.
    positive_fraction
        Fraction of trials with a positive instance.
    transform
        Callable applied to the raw scores (e.g. ``lambda raw: transforms.apply(name, raw)``); ``None``
        when the table is already transformed. NaN must stay NaN.
    split
        Which split to draw instances from (``"test"``: held out from detector training and fitting).

    Returns
    -------
    Trials
    """
    validate_response_table(table)
    for name, value in (("detector", detector), ("target", target)):
        if value not in table[name].values.tolist():
            raise ValueError(
                f"{name} {value!r} is not in the response table ({table[name].values.tolist()})"
            )
    if n_trials < 1:
        raise ValueError(f"n_trials must be positive, got {n_trials}")
    if not 0.0 <= positive_fraction <= 1.0:
        raise ValueError(f"positive_fraction must lie in [0, 1], got {positive_fraction}")
    score = transformed_scores(table, detector, target, transform)
    present = ~np.isnan(score)
    labels, cat, inst, pose, start = draw_trials(
        key, table, present, target, n_trials, positive_fraction, split, f"detector {detector!r}"
    )
    resp = score[cat, inst]  # (T, A, E, S)
    avail = ~np.isnan(resp)
    return Trials(
        responses=jnp.asarray(np.where(avail, resp, 0.0), jnp.float32),
        available=jnp.asarray(avail),
        label=jnp.asarray(labels),
        pose=jnp.asarray(pose),
        start=jnp.asarray(start),
        category=jnp.asarray(cat),
        instance=jnp.asarray(inst),
    )


def transformed_scores(
    table: xr.Dataset,
    detector: str,
    target: str,
    transform: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """One detector's scores for ``target``, shape ``(C, I, A, E, S)``, through ``transform``.

    Raises ``ValueError`` if the transform changes the shape or turns a finite score into a non-finite
    one (NaN, a missing view, must stay NaN).
    """
    raw = table["score"].sel(detector=detector, target=target).values  # (C, I, A, E, S)
    score = np.asarray(transform(raw) if transform is not None else raw, dtype=np.float64)
    if score.shape != raw.shape:
        raise ValueError(
            f"transform of {detector!r} changed the shape of the scores: {raw.shape} -> {score.shape}"
        )
    if np.isinf(score).any() or (np.isnan(score) & ~np.isnan(raw)).any():
        raise ValueError(
            f"transform of {detector!r} produced non-finite responses from finite scores"
        )
    return score


def draw_trials(
    key: jax.Array,
    table: xr.Dataset,
    present: np.ndarray,
    target: str,
    n_trials: int,
    positive_fraction: float,
    split: str,
    what: str = "",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The random part of :func:`make_trials`: instances, poses and start views of ``n_trials`` trials.

    Parameters
    ----------
    key
        JAX PRNG key.
    table
        The response table (its ``split`` and ``category`` coordinates).
    present
        ``(C, I, A, E, S)``: views with a response. An instance is usable on an ``(e, s)`` ring where every
        azimuth is present.
    target, n_trials, positive_fraction, split
        As for :func:`make_trials`.
    what
        Named in the error raised when a group has no usable instance.

    Returns
    -------
    ``label (T,)``, ``category (T,)``, ``instance (T,)``, ``pose (T,)``, ``start (T, 3)`` (azimuth,
    elevation, scale), as int32 NumPy arrays.
    """
    n_a = table_grid(table).n_azimuth
    complete = present.all(axis=2)  # (C, I, E, S): every azimuth present on that ring
    usable = (table["split"].values.astype(str) == split) & complete.any(axis=(2, 3))
    is_target = table["category"].values == target
    pools = {
        1: np.argwhere(usable & is_target[:, None]),
        0: np.argwhere(usable & ~is_target[:, None]),
    }
    n_pos = int(round(positive_fraction * n_trials))
    counts = {1: n_pos, 0: n_trials - n_pos}
    for o, pool in pools.items():
        if counts[o] and len(pool) == 0:
            kind = "positive" if o else "negative"
            raise ValueError(
                f"no {kind} instances for target {target!r} in split {split!r} with a complete azimuth "
                f"ring ({what})"
            )
    k_order, k_inst, k_pose, k_phi, k_ring = jax.random.split(key, 5)
    labels = np.asarray(
        jax.random.permutation(k_order, np.r_[np.ones(n_pos), np.zeros(n_trials - n_pos)])
    ).astype(np.int32)
    u_inst = np.asarray(jax.random.uniform(k_inst, (n_trials,)))
    u_ring = np.asarray(jax.random.uniform(k_ring, (n_trials,)))
    cat = np.empty(n_trials, np.int32)
    inst = np.empty(n_trials, np.int32)
    ring = np.empty((n_trials, 2), np.int32)
    for t in range(n_trials):
        pool = pools[int(labels[t])]
        c, i = pool[min(int(u_inst[t] * len(pool)), len(pool) - 1)]
        rings = np.argwhere(complete[c, i])
        cat[t], inst[t] = c, i
        ring[t] = rings[min(int(u_ring[t] * len(rings)), len(rings) - 1)]
    pose = np.asarray(jax.random.randint(k_pose, (n_trials,), 0, n_a), np.int32)
    phi0 = np.asarray(jax.random.randint(k_phi, (n_trials,), 0, n_a), np.int32)
    return labels, cat, inst, pose, np.c_[phi0, ring].astype(np.int32)


def check_starts(available, pose, start) -> None:
    """Raise ``ValueError`` unless every trial's pose is an azimuth bin and its start an existing view.

    Parameters
    ----------
    available
        ``(T, A, E, S)`` object-frame availability of each trial.
    pose
        ``(T,)`` hidden poses, in ``0 .. A-1``.
    start
        ``(T, 3)`` start robot views ``(phi0, e0, s0)``, inside the grid and available at relative
        azimuth ``(phi0 - pose) mod A``.
    """
    avail = np.asarray(available)
    pose = np.asarray(pose)
    start = np.asarray(start)
    n = avail.shape[0]
    if avail.ndim != 4 or pose.shape != (n,) or start.shape != (n, 3):
        raise ValueError(
            f"trials must have available (T, A, E, S), pose (T,) and start (T, 3); got "
            f"{avail.shape}, {pose.shape} and {start.shape}"
        )
    n_a = avail.shape[1]
    if pose.dtype.kind not in "iu" or (n and (pose.min() < 0 or pose.max() >= n_a)):
        raise ValueError(
            f"trial poses must be integer azimuth bins 0..{n_a - 1}, got values in "
            f"[{pose.min()}, {pose.max()}] of dtype {pose.dtype}"
        )
    check_view_array(
        avail.shape[1:],
        start,
        name="trial start views",
        names=("start azimuth", "start elevation", "start scale"),
        where="the trials' grid",
    )
    ok = avail[np.arange(n), (start[:, 0] - pose) % n_a, start[:, 1], start[:, 2]]
    if not ok.all():
        bad = int(np.flatnonzero(~ok)[0])
        raise ValueError(
            f"trial {bad} starts at a missing view {tuple(start[bad].tolist())} (no image there)"
        )


def select_trials(trials: Trials, index) -> Trials:
    """A subset of trials (any NumPy index along the trial axis)."""
    return Trials(*(x[index] for x in trials))


def robot_frame(responses, available, pose) -> tuple[jax.Array, jax.Array]:
    """One trial's responses and availability indexed by *robot* view ``(phi, e, s)``.

    ``out[phi] = responses[(phi - theta*) mod A]``.

    Parameters
    ----------
    responses, available
        Object-frame arrays ``(A, E, S)``.
    pose
        Hidden pose ``theta*``.
    """
    n_a = responses.shape[0]
    rel = (jnp.arange(n_a) - pose) % n_a
    return responses[rel], available[rel]


def observe(trials: Trials, t: int, view) -> float:
    """The response trial ``t`` returns at robot view ``(phi, e, s)``; ``ValueError`` if it is missing."""
    phi, e, s = (int(v) for v in view)
    n_a, n_e, n_s = trials.responses.shape[1:]
    if not (0 <= phi < n_a and 0 <= e < n_e and 0 <= s < n_s):
        raise ValueError(f"view {(phi, e, s)} is outside the view grid {(n_a, n_e, n_s)}")
    a = (phi - int(trials.pose[t])) % n_a
    if not bool(trials.available[t, a, e, s]):
        raise ValueError(
            f"trial {t} has no image at robot view {(phi, e, s)} (relative view {(a, e, s)})"
        )
    return float(trials.responses[t, a, e, s])
