"""The response table's DPM scoring: every target's model on one window, before and after batching.

For a sample of a run's windows (evenly spaced over the dataset's rows) this prepares each window's HOG
pyramid once and scores it with every target's DPM of the run two ways, in this process with BLAS
single-threaded:

* ``per_model``: the maximum of :func:`scrppl.detectors.dpm.model.pyramid_scores`, model by model (how the
  table was scored before :func:`~scrppl.detectors.dpm.model.best_scores`; training still scores this way);
* ``batched``: :meth:`DeformablePartModel.score_prepared_many`, what the table uses now.

It records the CPU milliseconds per window of each (median of ``--repeats`` passes over the sample), the
speed-up, the projected CPU seconds for the whole table (windows x the measured rate) and the largest
absolute and relative difference between the two (float32 rounding: they sum in different orders).

Usage::

    python benchmarks/bench_dpm_scoring.py RESULTS --profile full --preset paper [--windows 200]

``RESULTS`` is a run folder with ``detectors/dpm-*.npz``; the dataset is the one the profile names (as
``scrppl reproduce`` finds it). Writes the key ``<profile>`` of ``benchmarks/results/dpm-scoring.json``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "dpm-scoring.json"


def main() -> None:
    from _record import alternating_cpu_ms, record_windows, sampled_windows, window_fields

    from scrppl.detectors.dpm import DeformablePartModel
    from scrppl.detectors.dpm._blas import single_threaded_blas
    from scrppl.detectors.dpm.model import pyramid_best

    args, dets, windows, n_rows = sampled_windows(__doc__.splitlines()[0], "dpm")

    def per_model() -> np.ndarray:
        out = np.full((len(windows), len(dets)), -np.inf)
        with single_threaded_blas():
            for w, prep in enumerate(windows):
                for d, det in enumerate(dets):
                    out[w, d] = max(pyramid_best(det.model_, pyr) for pyr in prep.pyramids)
        return out

    def batched() -> np.ndarray:
        return np.array([DeformablePartModel.score_prepared_many(dets, prep) for prep in windows])

    fns = {"per_model": per_model, "batched": batched}
    ms, values = alternating_cpu_ms(fns, args.repeats, len(windows))
    diff = np.abs(values["batched"] - values["per_model"])
    n_windows = n_rows
    entry = {
        **window_fields(args, dets, windows, n_rows),
        "cpu_ms_per_window_all_targets": {k: round(v, 2) for k, v in ms.items()},
        "speed_up": round(ms["per_model"] / ms["batched"], 2),
        "projected_table_cpu_s": {k: round(v * n_windows / 1000, 1) for k, v in ms.items()},
        "max_abs_difference": float(diff.max()),
        "max_rel_difference": float((diff / np.maximum(np.abs(values["per_model"]), 1e-12)).max()),
        "note": "CPU seconds of this process (time.process_time), BLAS single-threaded, one core; the "
        "HOG pyramids are prepared once beforehand and not counted (the table shares them too)",
    }
    record_windows(RESULTS, args, entry)


if __name__ == "__main__":
    main()
