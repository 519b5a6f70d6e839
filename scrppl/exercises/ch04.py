"""Checks for the exercises of chapter 4 (the paper's viewpoint functions).

The Anscombe transform, a per-view Student-t fitted by maximum likelihood (against the paper's
Gaussian), the evidence of one view, and held-out criticism of the fit.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats
from scipy.stats import norm

from scrppl.exercises._core import (
    Case,
    Mistake,
    _difference,
    call,
    check_function,
    describe,
    exercise,
    fail,
    require,
)
from scrppl.exercises.inputs import CATEGORIES, response_table, small_grid

__all__ = [
    "check_4_1",
    "check_4_2",
    "check_4_3",
    "check_4_4",
    "student_t_per_view",
    "t_cell_loglik",
    "view_data_cases",
]


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
    # copies: an answer that changes its inputs in place must not change the next check's inputs
    return [
        Case(tuple(np.array(x, copy=True) for x in c.args), c.label)
        for c in _view_data_cases(split)
    ]


@functools.cache
def _view_data_cases(split: str) -> tuple[Case, ...]:
    """:func:`view_data_cases`, simulated once per split (the simulation compiles JAX code)."""
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
    return tuple(cases)


def _fit_ref(y, observed, o):
    from scrppl.models.data import make_view_data
    from scrppl.models.gaussian import fit_gaussian

    model, _ = fit_gaussian(make_view_data(y, o, observed=observed), min_sigma=1e-9)
    return np.asarray(model.mu[0, :, :, 0, 0], float), np.asarray(model.sigma[0, :, :, 0, 0], float)


#: Degrees of freedom of the Student-t of exercise 4.2 when none are given.
T_DF = 4.0


def _cells(y, observed, o):
    """Responses of each (class, azimuth) cell: ``values`` ``(2, A, m)`` and ``mask`` (NaN-free)."""
    A = y.shape[1]
    values, masks = [], []
    for c in (0, 1):
        v = np.moveaxis(np.asarray(y, float)[o == c], 1, 0).reshape(A, -1)
        m = np.moveaxis(np.asarray(observed, bool)[o == c], 1, 0).reshape(A, -1)
        values.append(np.where(m, v, 0.0))
        masks.append(m)
    width = max(v.shape[1] for v in values)
    pad = [(0, 0), (0, 0)]
    values = np.stack([np.pad(v, [pad[0], (0, width - v.shape[1])]) for v in values])
    masks = np.stack([np.pad(m, [pad[0], (0, width - m.shape[1])]) for m in masks])
    return values, masks


def t_cell_loglik(loc, scale, y, observed, o, df=T_DF) -> np.ndarray:
    """Log-likelihood of every (class, azimuth) cell under a Student-t, shape ``(2, A)``.

    ``sum_j log t_df(f_j; loc[o, a], scale[o, a])`` over the cell's observed responses ``f_j``.
    """
    values, masks = _cells(y, observed, o)
    loc, scale = np.asarray(loc, float), np.asarray(scale, float)
    with np.errstate(all="ignore"):
        lp = stats.t.logpdf(values, df, loc[..., None], scale[..., None])
    return np.where(masks, lp, 0.0).sum(axis=-1)


def student_t_per_view(y, observed, o, df=T_DF, tol=1e-11, max_iter=5_000):
    """Maximum-likelihood Student-t per (class, azimuth): ``loc, scale`` of shape ``(2, A)``.

    The reference of exercise 4.2 (the library has no Student-t model). ``df`` is fixed. The EM
    iteration of the t as a scale mixture of normals,
    ``w_j = (df + 1) / (df + ((f_j - m) / s)^2)``, ``m <- sum w_j f_j / sum w_j``,
    ``s^2 <- sum w_j (f_j - m)^2 / n``, raises the likelihood at every step. Here the scale update
    divides by ``sum w_j`` instead of ``n`` (the parameter-expanded EM of Kent, Tyler and Vardi 1994):
    the fixed points are the same (at a maximum ``sum w_j = n``), and it converges in far fewer steps.
    It runs for all cells at once from four starts (the mean, the median and the quartiles, with the
    ML normal's sd), and each cell keeps its best end point, so that a cell with two local maxima
    gets the higher one.
    """
    values, masks = _cells(y, observed, o)
    n = masks.sum(axis=-1)
    if (n == 0).any():
        raise ValueError("every (class, azimuth) cell needs an observed response")
    with np.errstate(invalid="ignore"):
        filled = np.where(masks, values, np.nan)
        mean = np.nanmean(filled, axis=-1)
        sd = np.sqrt(np.nanmean((filled - mean[..., None]) ** 2, axis=-1))
        quartiles = np.nanquantile(filled, [0.5, 0.25, 0.75], axis=-1)
    sd = np.maximum(sd, 1e-9)
    best_loc, best_scale, best_ll = mean, sd, np.full(mean.shape, -np.inf)
    for start in (mean, *quartiles):
        m, s = start.copy(), sd.copy()
        for _ in range(max_iter):
            w = np.where(
                masks, (df + 1.0) / (df + ((values - m[..., None]) / s[..., None]) ** 2), 0.0
            )
            m_new = (w * values).sum(-1) / w.sum(-1)
            s_new = np.sqrt((w * (values - m_new[..., None]) ** 2).sum(-1) / w.sum(-1))
            s_new = np.maximum(s_new, 1e-12)
            done = np.max(np.abs(m_new - m) + np.abs(s_new - s) / s) < tol
            m, s = m_new, s_new
            if done:
                break
        ll = t_cell_loglik(m, s, y, observed, o, df)
        better = ll > best_ll
        best_loc = np.where(better, m, best_loc)
        best_scale = np.where(better, s, best_scale)
        best_ll = np.where(better, ll, best_ll)
    return best_loc, best_scale


def _t_as_normal(y, observed, o, df=T_DF):
    return _fit_ref(y, observed, o)


def _t_sd_not_scale(y, observed, o, df=T_DF):
    loc, scale = student_t_per_view(y, observed, o, df)
    return loc, scale * np.sqrt(df / (df - 2.0))


def _t_default_df(y, observed, o, df=T_DF):
    return student_t_per_view(y, observed, o)


def _t_missing_as_zero(y, observed, o, df=T_DF):
    return student_t_per_view(np.nan_to_num(y), np.ones_like(observed, bool), o, df)


_T_MISTAKES = [
    Mistake(
        "these are the normal's maximum-likelihood mean and sd. The Student-t's maximum is elsewhere: "
        "it weighs each response by w = (df + 1) / (df + ((f - loc) / scale)^2), so that responses far "
        "from the others pull less; iterate the updates of the statement until they stop changing.",
        _t_as_normal,
    ),
    Mistake(
        "you returned the standard deviation of the fitted t, scale * sqrt(df / (df - 2)); return its "
        "scale parameter (scipy's `scale`), which is smaller.",
        _t_sd_not_scale,
    ),
    Mistake(
        "use the degrees of freedom `df` you are given (here not 4).",
        _t_default_df,
    ),
    Mistake(
        "leave out the missing views (observed == False); they are NaN in y and must not count "
        "as responses of 0.",
        _t_missing_as_zero,
    ),
]


def _t_cases() -> list[Case]:
    cases = view_data_cases()
    y, obs, o = cases[1].args
    return [
        *cases,
        Case((y, obs, o), cases[1].label + "; df = 10", {"df": 10.0}),
        Case((y, obs, o), cases[1].label + "; df = 2.5", {"df": 2.5}),
    ]


def _t_convert(x):
    if isinstance(x, list | tuple) and len(x) == 2:
        return tuple(np.asarray(v, float) for v in x)
    return x


@exercise(
    "4.2",
    "A per-view Student-t",
    "medium",
    reference=lambda: (student_t_per_view,),
    wrong=lambda: [(_t_as_normal,), (_t_sd_not_scale,), (_t_default_df,), (_t_missing_as_zero,)],
)
def check_4_2(fit_per_view_t) -> str:
    """Check exercise 4.2.

    ``fit_per_view_t(y, observed, o, df=4)`` must return ``(loc, scale)`` of shape ``(2, A)`` at which
    the Student-t log-likelihood of every (class, azimuth) cell is within ``1e-4`` of its maximum
    (:func:`student_t_per_view`, EM from several starts). A property check rather than a comparison of
    numbers: an optimiser stopped close to the maximum passes, one stopped far from it does not.
    """
    name = "fit_per_view_t(y, observed, o, df)"
    require(fit_per_view_t, name)
    cases = _t_cases()
    arg_names = ["y", "observed", "o"]
    for i, case in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        got = call(fit_per_view_t, name, case, where=where, arg_names=arg_names)
        if got is None:
            fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
        got = _t_convert(got)
        y, obs, o = case.args
        df = case.kwargs.get("df", T_DF)
        shape = (2, y.shape[1])
        if not isinstance(got, tuple) or any(np.shape(v) != shape for v in got):
            fail(
                f"`{name}` should return a tuple (loc, scale) of two arrays of shape {shape} on input "
                f"{where} ({case.label}); it returned {describe(got)}."
            )
        loc, scale = got
        ref_loc, ref_scale = student_t_per_view(y, obs, o, df)
        ll = t_cell_loglik(loc, scale, y, obs, o, df)
        ll_max = t_cell_loglik(ref_loc, ref_scale, y, obs, o, df)
        bad = ~(np.isfinite(ll) & (scale > 0) & (ll >= ll_max - 1e-4))
        if not bad.any():
            continue
        c, a = (int(k) for k in np.argwhere(bad)[0])
        lines = [
            f"`{name}` does not reach the maximum of the likelihood on input {where} ({case.label}), "
            f"df = {df}:",
            case.describe(arg_names),
            f"  {int(bad.sum())} of {bad.size} cells fall short; the first is class o = {c}, azimuth "
            f"a = {a}: your loc = {loc[c, a]:.6g}, scale = {scale[c, a]:.6g} give a log-likelihood of "
            f"{ll[c, a]:.6g}, but loc = {ref_loc[c, a]:.6g}, scale = {ref_scale[c, a]:.6g} give "
            f"{ll_max[c, a]:.6g}.",
        ]
        for m in _T_MISTAKES:
            if _difference(got, _t_convert(m.fn(*case.args, **case.kwargs)), 1e-6, 1e-9) is None:
                lines.append(f"Hint: {m.hint}")
                break
        else:
            lines.append(
                "Hint: start from the cell's mean and sd and repeat w_j = (df + 1) / (df + ((f_j - loc) "
                "/ scale)^2), loc = sum w_j f_j / sum w_j, scale^2 = sum w_j (f_j - loc)^2 / n until loc "
                "and scale stop changing (scipy.stats.t.fit's optimiser can stop early)."
            )
        fail("\n".join(lines))
    return f"reaches the Student-t's maximum likelihood in every cell of {len(cases)} data sets"


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
