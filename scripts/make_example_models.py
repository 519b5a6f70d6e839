"""Make the example viewpoint models shipped in ``scrppl/data/`` (``scrppl.example_model``).

Fits the paper's Gaussian and the hierarchical model (8 draws kept) of the ``dpm`` detector for three
targets, and their K-way model, on a response table simulated with the given seed
(:func:`scrppl.examples.make_example_models`), and records the seed and this command in
``examples.json`` beside them. ``tests/test_examples.py`` runs it into a temporary folder and compares.

Usage::

    .venv/bin/python scripts/make_example_models.py [--seed 0] [--out scrppl/data]
"""

from __future__ import annotations

import os

# Before JAX starts: the chains run on two host devices, whatever this machine has (the fits'
# numbers depend on how chains are split over devices), on the CPU.
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "scrppl" / "data")
    args = parser.parse_args(argv)
    import scrppl  # noqa: F401  (portable numerics before NumPy)
    from scrppl.examples import make_example_models

    command = f"python scripts/make_example_models.py --seed {args.seed}"
    record = make_example_models(args.out, args.seed, command=command)
    sizes = {f: (args.out / f).stat().st_size for f in record["files"]}
    for name, size in sizes.items():
        print(f"make_example_models: {args.out / name} ({size / 1024:.0f} kB)")
    print(
        f"make_example_models: {sum(sizes.values()) / 1024:.0f} kB in all; diagnostics ok: "
        f"{record['diagnostics_ok']}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
