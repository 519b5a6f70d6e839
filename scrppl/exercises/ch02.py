"""Checks for the exercises of chapter 2 (the dataset): views, the view grid, the index and its splits."""

from __future__ import annotations

import numpy as np

from scrppl.datasets.core import DEFAULT_SPLIT_PROPORTIONS, MultiviewDataset, assign_splits
from scrppl.exercises._core import Case, Mistake, check_function, exercise, fail, require
from scrppl.exercises.inputs import dataset_index, small_grid
from scrppl.views import object_azimuth, relative_azimuth


# -- 2.1 relative azimuth ---------------------------------------------------------------------------
def _azimuth_cases() -> list[Case]:
    rng = np.random.default_rng(21)
    return [
        Case((3, 1, 8), "one robot azimuth and one pose"),
        Case((1, 6, 8), "the robot's bin is below the object's"),
        Case((rng.integers(-20, 20, 12), rng.integers(0, 8, 12), 8), "negative robot azimuths"),
        Case((rng.integers(0, 16, 10), rng.integers(0, 16, 10), 16), "A = 16 azimuth bins"),
        Case((np.arange(4)[:, None], np.arange(4)[None, :], 4), "broadcasting, A = 4"),
    ]


def _relative_view_ref(robot, pose, n_azimuth=8):
    return relative_azimuth(robot, pose, n_azimuth)


def _object_pose_ref(robot, relative, n_azimuth=8):
    return object_azimuth(robot, relative, n_azimuth)


_RELATIVE_MISTAKES = [
    Mistake(
        "you computed (pose - robot); the relative azimuth is the robot's azimuth minus the "
        "object's pose, a = (phi - theta) mod A.",
        lambda robot, pose, n_azimuth=8: (pose - robot) % n_azimuth,
    ),
    Mistake(
        "the result must be a bin in 0..A-1: wrap the difference with `% n_azimuth` (Python's and "
        "NumPy's % return a non-negative result for a positive modulus).",
        lambda robot, pose, n_azimuth=8: robot - pose,
    ),
    Mistake(
        "the number of bins is the argument n_azimuth, not always 8.",
        lambda robot, pose, n_azimuth=8: (robot - pose) % 8,
    ),
]
_POSE_MISTAKES = [
    Mistake(
        "solve a = (phi - theta) mod A for theta: theta = (phi - a) mod A, not phi + a.",
        lambda robot, relative, n_azimuth=8: (robot + relative) % n_azimuth,
    ),
    Mistake(
        "wrap the pose into 0..A-1 with `% n_azimuth`.",
        lambda robot, relative, n_azimuth=8: robot - relative,
    ),
]


@exercise(
    "2.1",
    "Relative azimuth",
    "easy",
    reference=lambda: (_relative_view_ref, _object_pose_ref),
    wrong=lambda: [
        (_RELATIVE_MISTAKES[0].fn, _object_pose_ref),
        (_RELATIVE_MISTAKES[1].fn, _object_pose_ref),
        (_relative_view_ref, _POSE_MISTAKES[0].fn),
    ],
)
def check_2_1(relative_view, object_pose) -> str:
    """Check exercise 2.1.

    Compares ``relative_view(robot, pose, n_azimuth)`` and ``object_pose(robot, relative,
    n_azimuth)`` against :func:`scrppl.views.relative_azimuth` and
    :func:`scrppl.views.object_azimuth`.
    """
    cases = _azimuth_cases()
    n = check_function(
        relative_view,
        _relative_view_ref,
        cases,
        name="relative_view(robot, pose, n_azimuth)",
        mistakes=_RELATIVE_MISTAKES,
    )
    check_function(
        object_pose,
        _object_pose_ref,
        cases,
        name="object_pose(robot, relative, n_azimuth)",
        mistakes=_POSE_MISTAKES,
    )
    return f"both functions agree with scrppl.views on {n} inputs"


# -- 2.2 flat view index ----------------------------------------------------------------------------
def _grid_cases() -> list[Case]:
    out = []
    for shape in ((8, 3, 3), (8, 2, 3), (4, 3, 2), (12, 1, 4)):
        grid = small_grid(*shape)
        views = grid.all_views()
        rng = np.random.default_rng(sum(shape))
        pick = views[rng.permutation(len(views))[:10]]
        out.append(
            Case(
                (pick[:, 0], pick[:, 1], pick[:, 2], grid),
                f"A, E, S = {shape}",
            )
        )
    return out


def _view_index_ref(a, e, s, grid):
    return grid.view_index(a, e, s)


def _view_of_ref(index, grid):
    return tuple(np.asarray(x) for x in grid.view_from_index(index))


_INDEX_MISTAKES = [
    Mistake(
        "in scrppl the scale varies fastest, then the elevation, then the azimuth: "
        "index = (a * E + e) * S + s (azimuth-major, the order of the response table's axes).",
        lambda a, e, s, grid: (a * grid.n_scale + s) * grid.n_elevation + e,
    ),
    Mistake(
        "the elevation step is S (the number of scales), not E: index = a*E*S + e*S + s.",
        lambda a, e, s, grid: a * grid.n_elevation * grid.n_scale + e * grid.n_elevation + s,
    ),
]


def _view_of_cases() -> list[Case]:
    out = []
    for shape in ((8, 3, 3), (8, 2, 3), (4, 3, 2), (12, 1, 4)):
        grid = small_grid(*shape)
        out.append(Case((np.arange(grid.n_views), grid), f"every view of A, E, S = {shape}"))
    return out


_VIEW_OF_MISTAKES = [
    Mistake(
        "peel the indices off from the fastest-varying one: s = index % S, then rest = index // S, "
        "e = rest % E, a = rest // E.",
        lambda index, grid: (
            index // (grid.n_elevation * grid.n_scale),
            index % grid.n_elevation,
            (index // grid.n_elevation) % grid.n_scale,
        ),
    ),
]


@exercise(
    "2.2",
    "The flat view index",
    "easy",
    reference=lambda: (_view_index_ref, _view_of_ref),
    wrong=lambda: [
        (_INDEX_MISTAKES[0].fn, _view_of_ref),
        (_view_index_ref, _VIEW_OF_MISTAKES[0].fn),
    ],
)
def check_2_2(view_index, view_of) -> str:
    """Check exercise 2.2.

    Compares ``view_index(a, e, s, grid)`` and ``view_of(index, grid)`` against
    :meth:`ViewGrid.view_index <scrppl.views.ViewGrid.view_index>` and ``view_from_index``.
    """
    n = check_function(
        view_index,
        _view_index_ref,
        _grid_cases(),
        name="view_index(a, e, s, grid)",
        mistakes=_INDEX_MISTAKES,
    )
    m = check_function(
        view_of,
        _view_of_ref,
        _view_of_cases(),
        name="view_of(index, grid)",
        mistakes=_VIEW_OF_MISTAKES,
        convert=lambda x: tuple(x) if isinstance(x, list) else x,
    )
    return f"{n} sets of views and {m} grids"


# -- 2.3 split bookkeeping --------------------------------------------------------------------------
def _index_cases() -> list[Case]:
    cases = []
    for seed, grid, counts, missing in (
        (1, small_grid(8, 1, 1), (5, 3, 6, 4), 0.0),
        (2, small_grid(8, 2, 3), (5, 3, 6, 4), 0.1),
        (3, small_grid(8, 3, 3), (10, 10, 10, 10), 0.2),
        (4, small_grid(4, 2, 2), (2, 7, 3, 1), 0.3),
    ):
        index = dataset_index(seed, grid, n_instances=counts, missing=missing)
        cases.append(
            Case(
                (index, grid),
                f"{len(index)} images of {sum(counts)} instances, grid {grid.shape}, "
                f"{missing:.0%} of views missing",
            )
        )
    return cases


def _split_summary_ref(index, grid):
    summary = MultiviewDataset(".", index, grid).summary()
    return {"instances": summary["split_counts"], "missing_views": summary["missing_views"]}


def _count_rows(index, grid):
    return {
        "instances": {s: int((index["split"] == s).sum()) for s in ("train", "fit", "test")},
        "missing_views": _split_summary_ref(index, grid)["missing_views"],
    }


def _ids_only(index, grid):
    per = index.drop_duplicates(["instance"])
    return {
        "instances": {s: int((per["split"] == s).sum()) for s in ("train", "fit", "test")},
        "missing_views": int(index["instance"].nunique() * grid.n_views - len(index)),
    }


_SPLIT_MISTAKES = [
    Mistake(
        "you counted images (rows of the index); count instances: each (category, instance) pair "
        "once, e.g. index.drop_duplicates(['category', 'instance']).",
        _count_rows,
    ),
    Mistake(
        "instance numbers restart at 0 in every category: an instance is a (category, instance) "
        "pair, not an instance number.",
        _ids_only,
    ),
]


@exercise(
    "2.3",
    "Split bookkeeping",
    "medium",
    reference=lambda: (_split_summary_ref,),
    wrong=lambda: [(_count_rows,), (_ids_only,)],
)
def check_2_3(split_summary) -> str:
    """Check exercise 2.3.

    Compares ``split_summary(index, grid)`` against ``MultiviewDataset.summary()``.
    """
    n = check_function(
        split_summary,
        _split_summary_ref,
        _index_cases(),
        name="split_summary(index, grid)",
        mistakes=_SPLIT_MISTAKES,
        hint="missing_views is the number of (instance, view) pairs of the full grid with no image: "
        "(number of instances) * A * E * S - (number of images).",
    )
    return f"agrees with MultiviewDataset.summary() on {n} indexes"


# -- 2.4 stratified, stable splits ------------------------------------------------------------------
def _split_inputs(seed: int) -> dict[str, list[int]]:
    rng = np.random.default_rng([seed, 24])
    names = ["bicycle", "car", "cellphone", "head", "iron", "monitor", "mouse", "shoe"]
    return {c: list(range(int(rng.integers(1, 13)))) for c in names}


def _global_shuffle(seed, instances, proportions=DEFAULT_SPLIT_PROPORTIONS):
    rng = np.random.default_rng(seed)
    out = {}
    for cat, ids in instances.items():
        ids = list(ids)
        order = [ids[i] for i in rng.permutation(len(ids))]
        n = len(ids)
        n_test = max(1, round(proportions[2] * n)) if n >= 3 else min(n, 1)
        n_train = max(1, round(proportions[0] * n)) if n >= 3 else n - n_test
        labels = ["test"] * n_test + ["train"] * n_train + ["fit"] * (n - n_test - n_train)
        out.update({(cat, i): lab for i, lab in zip(order, labels, strict=False)})
    return out


def _iid_labels(seed, instances, proportions=DEFAULT_SPLIT_PROPORTIONS):
    out = {}
    for cat, ids in instances.items():
        rng = np.random.default_rng([seed, len(cat), sum(map(ord, cat))])
        for i in ids:
            out[(cat, i)] = str(rng.choice(["train", "fit", "test"], p=list(proportions)))
    return out


def _unseeded(seed, instances, proportions=DEFAULT_SPLIT_PROPORTIONS):
    rng = np.random.default_rng()  # a fresh seed every call
    return assign_splits(int(rng.integers(2**31)), instances, proportions)


def _check_splits(make_splits, seed, instances, proportions, label) -> dict:
    from scrppl.exercises._core import call

    case = Case((seed, instances, proportions), label)
    got = call(make_splits, "make_splits(seed, instances, proportions)", case, where=label)
    if not isinstance(got, dict):
        fail(f"make_splits should return a dict {{(category, instance): split}}, got {type(got)}")
    expected_keys = {(c, i) for c, ids in instances.items() for i in ids}
    missing = expected_keys - set(got)
    if missing:
        fail(
            f"on input {label}, these instances got no split: {sorted(missing)[:5]}"
            f"{' ...' if len(missing) > 5 else ''}. Every (category, instance) pair needs one."
        )
    extra = set(got) - expected_keys
    if extra:
        fail(
            f"on input {label}, unknown keys {sorted(extra, key=str)[:5]}: keys are (category, instance)."
        )
    bad = {k: v for k, v in got.items() if v not in ("train", "fit", "test")}
    if bad:
        fail(f"on input {label}, split labels must be 'train', 'fit' or 'test'; got {bad}")
    for cat, ids in instances.items():
        n = len(ids)
        if n < 3:
            continue
        counts = {s: sum(got[(cat, i)] == s for i in ids) for s in ("train", "fit", "test")}
        for s, p in zip(("train", "fit", "test"), proportions, strict=True):
            if p > 0 and counts[s] == 0:
                fail(
                    f"on input {label}: category {cat!r} has {n} instances but none in split {s!r} "
                    f"(counts {counts}). With 3 or more instances every split must get at least one; "
                    "shuffle and cut the instances of each category separately (stratify)."
                )
            if abs(counts[s] - p * n) > 1:
                fail(
                    f"on input {label}: category {cat!r} has {n} instances and proportions "
                    f"{tuple(proportions)}, so split {s!r} should get about {p * n:.1f} of them; "
                    f"it got {counts[s]} (counts {counts}). Cut each category's shuffled "
                    "instances by rounded shares, not by independent coin flips."
                )
    return got


@exercise(
    "2.4",
    "Stratified, stable splits",
    "hard",
    reference=lambda: (assign_splits,),
    wrong=lambda: [(_global_shuffle,), (_iid_labels,), (_unseeded,)],
)
def check_2_4(make_splits) -> str:
    """Check exercise 2.4.

    Compares ``make_splits(seed, instances, proportions)``, tested for the properties of
    :func:`scrppl.datasets.core.assign_splits` (deterministic, stratified, stable, seed-
    driven).
    """
    require(make_splits, "make_splits")
    n_inputs = 0
    for seed in range(6):
        instances = _split_inputs(seed)
        for proportions in ((0.4, 0.3, 0.3), (0.5, 0.25, 0.25)):
            label = f"seed={seed}, proportions={proportions}, categories " + ", ".join(
                f"{c}: {len(v)}" for c, v in instances.items()
            )
            first = _check_splits(make_splits, seed, instances, proportions, label)
            n_inputs += 1
            again = _check_splits(make_splits, seed, instances, proportions, label)
            if again != first:
                changed = [k for k in first if first[k] != again.get(k)]
                fail(
                    f"make_splits is not deterministic: called twice with seed={seed} it gave "
                    f"different splits (e.g. for {changed[0]}). Draw every random number from a "
                    "generator seeded by `seed` (and never from an unseeded one)."
                )
            # stability: removing a category (or adding one) leaves the others alone
            for drop in list(instances)[:3]:
                fewer = {c: v for c, v in instances.items() if c != drop}
                sub = _check_splits(
                    make_splits, seed, fewer, proportions, label + f", without {drop!r}"
                )
                changed = [k for k in sub if sub[k] != first[k]]
                if changed:
                    fail(
                        f"the splits are not stable: removing category {drop!r} changed the split "
                        f"of {changed[0]} (seed={seed}, proportions={proportions}). Give each "
                        "category a generator of its own, seeded by `seed` and the category's "
                        "name (e.g. with zlib.crc32 of the name; Python's hash() of a string "
                        "changes from one process to the next)."
                    )
    # different seeds give different splits
    instances = {"car": list(range(10)), "shoe": list(range(8))}
    seen = {
        tuple(
            sorted(_check_splits(make_splits, s, instances, (0.4, 0.3, 0.3), f"seed={s}").items())
        )
        for s in range(8)
    }
    if len(seen) < 2:
        fail(
            "make_splits gives the same split for 8 different seeds: the seed must drive the "
            "shuffle."
        )
    return f"deterministic, stratified and stable on {n_inputs} inputs; the seed matters"


__all__ = ["check_2_1", "check_2_2", "check_2_3", "check_2_4"]
