"""The response table's SIFT ratio test: padded layout against the packed one, on a run's windows.

For a sample of a run's windows (evenly spaced over the dataset's rows) this extracts each window's SIFT
features once and matches them against every target's SIFT model two ways, in this process with BLAS
single-threaded:

* ``padded``: distances to every slot of the ``(V, K)`` padded model layout, the padding set to infinity
  after the product, nearest and second-nearest over the last axis (how the table was matched before
  :func:`scrppl.detectors.sift.pack_model`; kept here as the reference);
* ``packed``: :func:`scrppl.detectors.sift.ratio_test_matches` with the packed model, what the table
  uses now (one product over the real descriptors with their squared norms appended, the reductions
  over contiguous rows).

It records the CPU milliseconds per window of each (median of ``--repeats`` passes over the sample), the
speed-up, the projected CPU seconds for the whole table (windows x the measured rate; BoF shares these
matches with SIFT) and how many (keypoint, view) matches and nearest indices differ between the two.

Usage::

    python benchmarks/bench_sift_matching.py RESULTS --profile full --preset paper [--windows 200]

``RESULTS`` is a run folder with ``detectors/sift-*.npz``; the dataset is the one the profile names (as
``scrppl reproduce`` finds it). Writes the key ``<profile>/<preset>`` of
``benchmarks/results/sift-matching.json``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "sift-matching.json"


def padded_norms(model, valid):
    """``(V * K,)`` squared norms of the padded layout, ``inf`` for padding (computed once a model)."""
    flat = np.asarray(model, dtype=np.float32).reshape(-1, model.shape[-1])
    sq = np.einsum("md,md->m", flat, flat)
    return np.where(np.asarray(valid).ravel(), sq, np.float32(np.inf)).astype(np.float32)


def padded_ratio_test(query, model, valid, ratio, sq):
    """The padded-layout ratio test (before packing), without the one-to-one step."""
    q = np.asarray(query, dtype=np.float32)
    n_views, k, d = model.shape
    flat = model.reshape(n_views * k, d)
    d2 = q @ flat.T
    d2 *= -2.0
    d2 += np.einsum("qd,qd->q", q, q)[:, None]
    d2 += sq[None, :]
    np.maximum(d2, 0.0, out=d2)
    d2 = d2.reshape(q.shape[0], n_views, k)
    nearest = np.argmin(d2, axis=2)
    best = np.take_along_axis(d2, nearest[:, :, None], axis=2)[:, :, 0]
    np.put_along_axis(d2, nearest[:, :, None], np.inf, axis=2)
    second = d2.min(axis=2)
    return np.isfinite(best) & (best < (ratio * ratio) * second), nearest


def main() -> None:
    from _record import alternating_cpu_ms, record_windows, sampled_windows, window_fields

    from scrppl.detectors.dpm._blas import single_threaded_blas
    from scrppl.detectors.sift import pack_model, ratio_test_matches

    args, dets, windows, n_rows = sampled_windows(__doc__.splitlines()[0], "sift")
    models = [(det._descriptors, det._valid, float(det.hyperparameters["ratio"])) for det in dets]
    packs = [pack_model(m, v) for m, v, _ in models]
    norms = [padded_norms(m, v) for m, v, _ in models]

    def padded() -> list:
        with single_threaded_blas():
            return [
                padded_ratio_test(w.descriptors, *m, sq)
                for w in windows
                for m, sq in zip(models, norms, strict=True)
            ]

    def packed() -> list:
        with single_threaded_blas():
            return [
                ratio_test_matches(w.descriptors, m, v, r, p, unique=False)
                for w in windows
                for (m, v, r), p in zip(models, packs, strict=True)
            ]

    fns = {"padded": padded, "packed": packed}
    ms, values = alternating_cpu_ms(fns, args.repeats, len(windows))
    pairs = list(zip(values["padded"], values["packed"], strict=True))
    n_slots = sum(a.size for (a, _), _ in pairs)
    # a view with no descriptor has no nearest one: only views with descriptors are compared
    has = [v.any(1)[None, :] for _, v, _ in models] * len(windows)
    n_windows = n_rows
    entry = {
        **window_fields(args, dets, windows, n_rows),
        "padding_share": round(1 - float(np.mean([v.mean() for _, v, _ in models])), 3),
        "cpu_ms_per_window_all_targets": {k: round(v, 2) for k, v in ms.items()},
        "speed_up": round(ms["padded"] / ms["packed"], 2),
        "projected_table_cpu_s": {k: round(v * n_windows / 1000, 1) for k, v in ms.items()},
        "keypoint_view_pairs_compared": n_slots,
        "accepted_differ": int(sum((a0 != a1).sum() for (a0, _), (a1, _) in pairs)),
        "nearest_differ": int(
            sum(((n0 != n1) & h).sum() for ((_, n0), (_, n1)), h in zip(pairs, has, strict=True))
        ),
        "note": "CPU seconds of this process (time.process_time), BLAS single-threaded, one core; the "
        "SIFT features are extracted once beforehand and not counted (the table shares them too); "
        "both without the one-to-one step, which is the same code after either",
    }
    record_windows(RESULTS, args, entry)


if __name__ == "__main__":
    main()
