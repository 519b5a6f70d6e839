"""What the benchmark scripts share: one key of a JSON record under ``benchmarks/results/`` updated."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from scrppl._io import atomic_path


def update_record(path: Path, key: str, entry: dict[str, Any], run: dict[str, Any]) -> None:
    """Set ``record[key] = entry`` (with the run's profile, seed and preset and this machine), keeping
    the other keys; written atomically, so an interrupted script leaves the old record whole."""
    from scrppl.pipeline import machine_description

    record = json.loads(path.read_text()) if path.exists() else {}
    record[key] = {
        **entry,
        "run": {k: run.get(k) for k in ("profile", "seed", "preset")},
        "machine": machine_description(),
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {path} [{key}]")
