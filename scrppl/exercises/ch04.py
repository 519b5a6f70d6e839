"""Checks for the exercises of chapter 4 (the paper's viewpoint functions).

The Anscombe transform, the per-view Gaussian fitted by hand, the evidence of one view, and held-out
criticism of the fit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from scrppl.exercises._core import Case, Mistake, check_function, exercise
from scrppl.exercises.inputs import CATEGORIES, response_table, small_grid

__all__ = ["check_4_1", "check_4_2", "check_4_3", "check_4_4", "view_data_cases"]


# -- 4.1 the Anscombe transform ---------------------------------------------------------------------
def _anscombe_ref(x):
    from scrppl.models import transforms

    return transforms.apply("anscombe", x)


def _inverse_ref(f):
    from scrppl.models import transforms

    return transforms.inverse("anscombe", f)


def _count_cases() -> list[Case]:
    rng = np.random.default_rng(41)
    counts = rng.poisson(3.0, 20).astype(float)
    with_nan = rng.poisson(1.0, (3, 5)).astype(float)
    with_nan[0, 1] = with_nan[2, 4] = np.nan
    return [
        Case((np.arange(6.0),), "the counts 0..5"),
        Case((counts,), "20 Poisson counts"),
        Case((with_nan,), "a (3, 5) table of counts with missing views (NaN)"),
        Case((np.array([0.0, 1.0, 250.0]),), "a large count"),
    ]


def _f_cases() -> list[Case]:
    return [
        Case((_anscombe_ref(np.arange(6.0)),), "the images of the counts 0..5"),
        Case((np.linspace(0.0, 6.0, 13),), "values from 0 to 6, some below 2 sqrt(3/8)"),
        Case((np.array([[1.3, np.nan], [4.0, 2.5]]),), "a (2, 2) array with a NaN"),
    ]


_ANSCOMBE_MISTAKES = [
    Mistake(
        "the transform is 2 sqrt(x + 3/8): you left out the factor 2.", lambda x: np.sqrt(x + 0.375)
    ),
    Mistake("the transform is 2 sqrt(x + 3/8): you left out the + 3/8.", lambda x: 2 * np.sqrt(x)),
]
_INVERSE_MISTAKES = [
    Mistake(
        "values below 2 sqrt(3/8) (the image of 0 counts) would give negative counts: clip the "
        "inverse at 0 (np.maximum(..., 0)).",
        lambda f: (np.asarray(f) / 2) ** 2 - 0.375,
    ),
    Mistake(
        "invert f = 2 sqrt(x + 3/8): x = (f / 2)^2 - 3/8.",
        lambda f: np.maximum(np.asarray(f) ** 2 - 0.375, 0.0),
    ),
]


@exercise(
    "4.1",
    "The Anscombe transform",
    "easy",
    reference=lambda: (_anscombe_ref, _inverse_ref),
    wrong=lambda: [
        (_ANSCOMBE_MISTAKES[0].fn, _inverse_ref),
        (_anscombe_ref, _INVERSE_MISTAKES[0].fn),
    ],
)
def check_4_1(anscombe, inverse_anscombe) -> str:
    """Check exercise 4.1.

    Compares ``anscombe(x)`` and ``inverse_anscombe(f)`` against
    :mod:`scrppl.models.transforms` (``"anscombe"``).
    """
    n = check_function(
        anscombe, _anscombe_ref, _count_cases(), name="anscombe(x)", mistakes=_ANSCOMBE_MISTAKES
    )
    m = check_function(
        inverse_anscombe,
        _inverse_ref,
        _f_cases(),
        name="inverse_anscombe(f)",
        mistakes=_INVERSE_MISTAKES,
    )
    return f"agrees with scrppl.models.transforms on {n + m} inputs"


# -- shared inputs: fitting data --------------------------------------------------------------------
def view_data_cases(split: str = "fit") -> list[Case]:
    """Inputs ``(y, observed, o)`` (of :class:`~scrppl.models.ViewData`) from simulated tables."""
    from scrppl.models.data import extract_view_data

    cases = []
    for seed, grid, n_inst, missing, target in (
        (41, small_grid(8, 1, 1), 6, 0.0, "car"),
        (42, small_grid(8, 1, 1), 6, 0.1, "bicycle"),
        (43, small_grid(8, 2, 3), 4, 0.15, "mouse"),
        (44, small_grid(6, 3, 1), 5, 0.2, "monitor"),
    ):
        table = response_table(
            seed,
            grid,
            CATEGORIES[:4],
            2 * n_inst,
            missing=missing,
            splits={"fit": n_inst, "test": n_inst},
        )
        data, _ = extract_view_data(table, "dpm", target, split)
        y = np.where(data.observed, data.y, np.nan)
        cases.append(
            Case(
                (y, np.asarray(data.observed), np.asarray(data.o)),
                f"{len(data.o)} instances ({int(data.o.sum())} positive), grid {grid.shape}, "
                f"{int((~data.observed).sum())} missing views",
            )
        )
    return cases


def _fit_ref(y, observed, o):
    from scrppl.models.data import make_view_data
    from scrppl.models.gaussian import fit_gaussian

    model, _ = fit_gaussian(make_view_data(y, o, observed=observed), min_sigma=1e-9)
    return np.asarray(model.mu[0, :, :, 0, 0], float), np.asarray(model.sigma[0, :, :, 0, 0], float)


def _fit_manual(y, observed, o, ddof=0, use_mask=True):
    A = y.shape[1]
    mu, sd = np.zeros((2, A)), np.zeros((2, A))
    yy = np.where(observed, y, np.nan) if use_mask else np.nan_to_num(y)
    for c in (0, 1):
        v = np.moveaxis(yy[o == c], 1, 0).reshape(A, -1)
        mu[c] = np.nanmean(v, axis=1)
        sd[c] = np.nanstd(v, axis=1, ddof=ddof)
    return mu, sd


def _fit_per_instance(y, observed, o):
    A = y.shape[1]
    mu, sd = np.zeros((2, A)), np.zeros((2, A))
    for c in (0, 1):
        v = np.where(observed, y, np.nan)[o == c]  # (I, A, E, S)
        inst_mean = np.nanmean(v.reshape(*v.shape[:2], -1), axis=2)  # (I, A)
        mu[c] = np.nanmean(inst_mean, axis=0)
        sd[c] = np.nanstd(inst_mean, axis=0)
    return mu, sd


_FIT_MISTAKES = [
    Mistake(
        "the paper's fit is maximum likelihood: the variance divides by n (np.std's default ddof=0), "
        "not by n - 1.",
        lambda y, obs, o: _fit_manual(y, obs, o, ddof=1),
    ),
    Mistake(
        "leave out the missing views (observed == False); they are NaN in y and must not count "
        "as responses of 0.",
        lambda y, obs, o: _fit_manual(y, obs, o, use_mask=False),
    ),
    Mistake(
        "every response is one observation: pool the responses of all instances, elevations and "
        "scales of a (class, azimuth) cell; do not average each instance first.",
        _fit_per_instance,
    ),
]


@exercise(
    "4.2",
    "The per-view Gaussian by hand",
    "medium",
    reference=lambda: (_fit_ref,),
    wrong=lambda: [(m.fn,) for m in _FIT_MISTAKES],
)
def check_4_2(fit_per_view) -> str:
    """Check exercise 4.2.

    Compares ``fit_per_view(y, observed, o) -> (mu, sigma)`` against
    :func:`scrppl.models.fit_gaussian`.
    """
    n = check_function(
        fit_per_view,
        _fit_ref,
        view_data_cases(),
        name="fit_per_view(y, observed, o)",
        rtol=1e-5,
        atol=1e-6,
        mistakes=_FIT_MISTAKES,
        hint="for each class o and azimuth a, take every observed response y[i, a, e, s] of the "
        "instances i of class o (all elevations and scales): mu is their mean, sigma the square root "
        "of their mean squared deviation from mu.",
        convert=lambda x: (
            tuple(np.asarray(v, float) for v in x) if isinstance(x, list | tuple) else x
        ),
    )
    return f"agrees with scrppl.models.fit_gaussian on {n} data sets"


# -- 4.3 the evidence of one view -------------------------------------------------------------------
@jax.jit
def _llr_jit(mu, sigma, f, a):
    from scrppl.models.response import ResponseModel, log_prob

    model = ResponseModel(
        mu[None, :, :, None, None], sigma[None, :, :, None, None], jnp.zeros((1, 2))
    )
    return log_prob(model, f, 1, a) - log_prob(model, f, 0, a)


def _llr_ref(mu, sigma, f, a):
    # one compiled call per input shape (eager JAX would compile every small operation)
    return np.asarray(
        _llr_jit(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(f), jnp.asarray(a)), float
    )


def _llr_cases() -> list[Case]:
    out = []
    for case in view_data_cases()[:3]:
        y, obs, o = case.args
        mu, sigma = _fit_ref(y, obs, o)
        A = mu.shape[1]
        rng = np.random.default_rng(A + len(o))
        f = rng.normal(mu.mean(), 2 * sigma.mean(), 10)
        a = rng.integers(0, A, 10)
        out.append(Case((mu, sigma, f, a), "fitted on " + case.label + "; 10 responses"))
    mu = np.array([[0.0, 0.0, 0.2, 0.0], [1.5, 1.0, 2.5, 1.2]])
    sigma = np.array([[0.5, 0.5, 0.6, 0.5], [0.4, 1.2, 0.5, 0.8]])
    out.append(
        Case(
            (mu, sigma, np.array([[0.0], [1.0], [3.0]]), np.arange(4)), "broadcasting (3, 1) x (4,)"
        )
    )
    return out


_LLR_MISTAKES = [
    Mistake(
        "sigma is the standard deviation: the normal density is N(f; mu, sigma), not a variance of "
        "sigma (scipy's `scale` argument is the sd).",
        lambda mu, sigma, f, a: (
            norm.logpdf(f, mu[1][a], sigma[1][a] ** 2) - norm.logpdf(f, mu[0][a], sigma[0][a] ** 2)
        ),
    ),
    Mistake(
        "the two classes have different sigmas, so the normalising term -log(sigma) does not cancel "
        "in the ratio.",
        lambda mu, sigma, f, a: (
            -0.5 * ((f - mu[1][a]) / sigma[1][a]) ** 2 + 0.5 * ((f - mu[0][a]) / sigma[0][a]) ** 2
        ),
    ),
    Mistake(
        "the ratio is present over absent: log p(f | o=1, a) - log p(f | o=0, a).",
        lambda mu, sigma, f, a: (
            norm.logpdf(f, mu[0][a], sigma[0][a]) - norm.logpdf(f, mu[1][a], sigma[1][a])
        ),
    ),
]


@exercise(
    "4.3",
    "The evidence of one view",
    "medium",
    reference=lambda: (_llr_ref,),
    wrong=lambda: [(m.fn,) for m in _LLR_MISTAKES],
)
def check_4_3(log_likelihood_ratio) -> str:
    """Check exercise 4.3.

    Compares ``log_likelihood_ratio(mu, sigma, f, a)`` against :func:`scrppl.models.log_prob`.
    """
    n = check_function(
        log_likelihood_ratio,
        _llr_ref,
        _llr_cases(),
        name="log_likelihood_ratio(mu, sigma, f, a)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_LLR_MISTAKES,
    )
    return f"agrees with scrppl.models.log_prob on {n} inputs"


# -- 4.4 held-out criticism -------------------------------------------------------------------------
def _lpd_cases() -> list[Case]:
    out = []
    # three data sets of two shapes: each new shape costs a compilation of the library's evaluation
    pairs = zip(view_data_cases("fit")[:3], view_data_cases("test")[:3], strict=True)
    for fit_case, test_case in pairs:
        mu, sigma = _fit_ref(*fit_case.args)
        out.append(Case((mu, sigma, *test_case.args), "held-out " + test_case.label))
    return out


def _lpd_ref(mu, sigma, y, observed, o):
    from scrppl.models.data import make_view_data
    from scrppl.models.evaluate import heldout_scores
    from scrppl.models.response import ResponseModel

    A, E, S = y.shape[1:]
    shape = (1, 2, A, E, S)
    model = ResponseModel(
        jnp.broadcast_to(jnp.asarray(mu)[None, :, :, None, None], shape),
        jnp.broadcast_to(jnp.asarray(sigma)[None, :, :, None, None], shape),
        jnp.zeros((1, 2)),
    )
    return float(
        np.mean(heldout_scores(model, make_view_data(y, o, observed=observed))["lpd_single"])
    )


def _lpd_terms(mu, sigma, y, observed, o):
    a = np.arange(y.shape[1])[None, :, None, None]
    oo = np.asarray(o)[:, None, None, None]
    return norm.logpdf(y, mu[oo, a], sigma[oo, a])  # (I, A, E, S), NaN where missing


def _lpd_pooled(mu, sigma, y, observed, o):
    return float(np.mean(_lpd_terms(mu, sigma, y, observed, o)[observed]))


def _lpd_sum(mu, sigma, y, observed, o):
    lp = np.where(observed, _lpd_terms(mu, sigma, y, observed, o), 0.0)
    return float(np.mean(lp.reshape(len(o), -1).sum(1)))


def _lpd_wrong_class(mu, sigma, y, observed, o):
    return _lpd_ref(mu, sigma, y, observed, np.zeros_like(o))


_LPD_MISTAKES = [
    Mistake(
        "instances are the unit: first average the log densities of each instance's observed "
        "responses, then average over instances (instances with missing views weigh as much as "
        "the others).",
        _lpd_pooled,
    ),
    Mistake(
        "report the mean log density *per response* of an instance (divide its sum by its number of "
        "observed views), then average over instances.",
        _lpd_sum,
    ),
    Mistake(
        "each instance is scored under the normal of its own class o_i.",
        _lpd_wrong_class,
    ),
]


@exercise(
    "4.4",
    "How many instances does the Gaussian need?",
    "hard",
    reference=lambda: (_lpd_ref,),
    wrong=lambda: [(m.fn,) for m in _LPD_MISTAKES],
)
def check_4_4(heldout_lpd) -> str:
    """Check exercise 4.4.

    Compares ``heldout_lpd(mu, sigma, y, observed, o)`` against the mean ``lpd_single`` of
    :func:`scrppl.models.heldout_scores`.
    """
    n = check_function(
        heldout_lpd,
        _lpd_ref,
        _lpd_cases(),
        name="heldout_lpd(mu, sigma, y, observed, o)",
        rtol=1e-4,
        atol=1e-4,
        mistakes=_LPD_MISTAKES,
        convert=lambda x: float(np.asarray(x)),
    )
    return f"agrees with scrppl.models.heldout_scores on {n} held-out sets"
