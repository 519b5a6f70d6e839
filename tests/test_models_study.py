"""The choices ``scrppl fit`` makes, as library functions (:mod:`scrppl.models.study`)."""

import pytest

from scrppl.models.study import PAPER_TARGETS, failed_fits, figure_targets, select_names


def test_select_names_defaults_to_all_and_names_what_is_missing():
    assert select_names(None, ["dpm", "sift"], "detector") == ["dpm", "sift"]
    assert select_names(["sift"], ["dpm", "sift"], "detector") == ["sift"]
    with pytest.raises(ValueError, match=r"targets \['boat'\] are not in the response table"):
        select_names(["car", "boat"], ["car", "shoe"], "target")


def test_figure_targets_prefers_the_papers_targets():
    assert figure_targets(["shoe", "monitor", "car", "iron"]) == ["car", "monitor"]
    assert figure_targets(["a", "b", "c", "d"]) == ["a", "b", "c"]
    assert set(PAPER_TARGETS) == {"bicycle", "car", "monitor"}


def test_failed_fits_only_of_the_pairs_asked_for():
    diag = {
        "dpm/car": {"ok": False, "failures": ["R-hat"]},
        "dpm/shoe": {"ok": True, "failures": []},
        "sift/car": {"ok": False, "failures": ["ESS"]},
    }
    assert failed_fits(diag, ["dpm"], ["car", "shoe"]) == {"dpm/car": ["R-hat"]}
