"""Multiview object-category datasets: the index, the Savarese loader and the synthetic dataset.

The index is `MultiviewDataset`; `open_dataset(root)` opens the dataset in a folder, whether it is a
saved index (the synthetic cache) or a copy of the Savarese dataset (`dataset_layout` tells which);
`describe` and `format_summary` summarise it (`scrppl dataset info`). With ``errors="report"`` a
Savarese tree's bad files are skipped and listed as `Problem` records (`format_problems`,
`write_problems`).

The loaders and generators are imported lazily by their submodules (``scrppl.datasets.savarese``,
``scrppl.datasets.synthetic``) because they pull in OpenCV and the renderer.
"""

from scrppl.datasets.core import (
    DEFAULT_SPLIT_PROPORTIONS,
    INDEX_COLUMNS,
    SPLITS,
    MultiviewDataset,
    assign_splits,
    bbox_from_mask,
    read_ascii_mask,
    write_ascii_mask,
)
from scrppl.datasets.folders import dataset_layout, open_dataset
from scrppl.datasets.problems import Problem, format_problems, read_problems, write_problems
from scrppl.datasets.summary import check_generation_root, describe, format_summary

__all__ = [
    "DEFAULT_SPLIT_PROPORTIONS",
    "INDEX_COLUMNS",
    "SPLITS",
    "MultiviewDataset",
    "assign_splits",
    "bbox_from_mask",
    "check_generation_root",
    "describe",
    "format_summary",
    "dataset_layout",
    "open_dataset",
    "Problem",
    "format_problems",
    "read_problems",
    "write_problems",
    "read_ascii_mask",
    "write_ascii_mask",
]
