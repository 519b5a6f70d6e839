"""The machinery behind :func:`scrppl.exercises.check`: the registry, the failures and the comparisons.

An exercise is registered with :func:`exercise` on its *check function*: a function that receives the
student's answers (the arguments given to ``check`` after the exercise id), runs them on inputs of its own
(fixed seeds, several cases, including the awkward ones) against the library's reference, and raises
:class:`ExerciseFailed` with a hint when an answer differs. The helpers here do the common work:

* :func:`require` -- an answer that is still a stub (``None``, ``...``) is "not answered yet";
* :func:`call` -- calls the student's function on one :class:`Case`; a ``NotImplementedError`` means "not
  answered yet", any other exception becomes a failure that names the input;
* :func:`compare` -- compares an answer with the expected value (shape, missing values, numbers) and,
  when they differ, says on which input, where, what was expected and what came back, and whether the
  answer matches one of the exercise's known :class:`Mistake` s (then it gives that mistake's hint);
* :func:`check_function` -- all of the above over a list of cases.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "ExerciseFailed",
    "ExerciseNotAnswered",
    "Exercise",
    "Case",
    "Mistake",
    "DIFFICULTIES",
    "exercise",
    "get_exercise",
    "list_exercises",
    "require",
    "call",
    "compare",
    "check_function",
    "fail",
    "describe",
]

#: The difficulty grades, in order.
DIFFICULTIES = ("easy", "medium", "hard")

_ID = re.compile(r"^(\d+)\.(\d+)$")


class ExerciseFailed(AssertionError):
    """An answer to an exercise is not correct yet; the message says on which input and what differs."""

    def _render_traceback_(self) -> list[str]:
        """What IPython shows instead of a traceback: the message (after the student's own error).

        The frames of the check itself tell a student nothing; when the student's code raised, its
        traceback (the ``__cause__``) comes first.
        """
        lines: list[str] = []
        if self.__cause__ is not None:
            cause, tb = self.__cause__, self.__cause__.__traceback__
            while tb is not None and tb.tb_frame.f_code.co_filename == __file__:
                tb = tb.tb_next  # the frames of the check's own call of the student's function
            lines += traceback.format_exception(type(cause), cause, tb)
            lines.append("\nThe check stopped there:\n")
        lines.append(f"\x1b[0;31m{type(self).__name__}\x1b[0m: {self}")
        return lines


class ExerciseNotAnswered(ExerciseFailed):
    """An answer is still the stub of the student copy (``None``, ``...`` or ``NotImplementedError``)."""


@dataclass(frozen=True)
class Exercise:
    """One registered exercise.

    Attributes
    ----------
    id
        ``"<chapter>.<number>"``, e.g. ``"2.1"``.
    title
        Short title, without the difficulty (the book shows ``"<title> (<difficulty>)"``).
    difficulty
        One of :data:`DIFFICULTIES`.
    run
        The check function: takes the answers, raises :class:`ExerciseFailed` or returns a short
        description of what was checked (e.g. ``"6 inputs"``).
    reference
        Returns correct answers (a tuple, in the order ``check`` takes them); used by the unit tests.
    wrong
        Returns a list of wrong answer tuples, each of which the check must reject with a hint.
    answers
        Names of the answers, in order (for messages and documentation).
    """

    id: str
    title: str
    difficulty: str
    run: Callable[..., str | None]
    reference: Callable[[], tuple]
    wrong: Callable[[], list[tuple]]
    answers: tuple[str, ...] = field(default=())

    @property
    def chapter(self) -> int:
        """The chapter number (the part of the id before the dot)."""
        return int(self.id.split(".")[0])

    @property
    def heading(self) -> str:
        """``"Exercise 2.1: Relative azimuth (easy)"``."""
        return f"Exercise {self.id}: {self.title} ({self.difficulty})"


_REGISTRY: dict[str, Exercise] = {}


def exercise(
    id: str,
    title: str,
    difficulty: str,
    *,
    reference: Callable[[], tuple],
    wrong: Callable[[], list[tuple]],
) -> Callable[[Callable[..., str | None]], Callable[..., str | None]]:
    """Register the decorated check function as exercise ``id``.

    Parameters
    ----------
    id
        ``"<chapter>.<number>"``; the chapter's module is ``scrppl.exercises.ch<NN>``.
    title, difficulty
        See :class:`Exercise`.
    reference
        Zero-argument function returning a tuple of correct answers.
    wrong
        Zero-argument function returning a list of tuples of wrong answers.
    """
    if not _ID.match(id):
        raise ValueError(f"exercise id must look like '2.1', got {id!r}")
    if difficulty not in DIFFICULTIES:
        raise ValueError(f"difficulty must be one of {DIFFICULTIES}, got {difficulty!r}")

    def register(run: Callable[..., str | None]) -> Callable[..., str | None]:
        if id in _REGISTRY and _REGISTRY[id].run.__qualname__ != run.__qualname__:
            raise ValueError(f"exercise {id} is registered twice")
        names = tuple(run.__code__.co_varnames[: run.__code__.co_argcount])
        _REGISTRY[id] = Exercise(id, title, difficulty, run, reference, wrong, names)
        return run

    return register


def _chapter_modules() -> list[str]:
    import scrppl.exercises as pkg

    return sorted(
        m.name for m in pkgutil.iter_modules(pkg.__path__) if re.fullmatch(r"ch\d\d", m.name)
    )


def get_exercise(id: str) -> Exercise:
    """The registered :class:`Exercise` with this id (its chapter module is imported on first use)."""
    id = str(id).strip()
    m = _ID.match(id)
    if not m:
        raise ValueError(f"an exercise id looks like '2.1' (chapter.number), got {id!r}")
    if id not in _REGISTRY:
        name = f"ch{int(m.group(1)):02d}"
        if name in _chapter_modules():
            importlib.import_module(f"scrppl.exercises.{name}")
    if id not in _REGISTRY:
        known = ", ".join(e.id for e in list_exercises()) or "none"
        raise ValueError(f"there is no exercise {id!r}; known exercises: {known}")
    return _REGISTRY[id]


def list_exercises(chapter: int | None = None) -> list[Exercise]:
    """Every registered exercise (of one chapter, if given), in id order."""
    for name in _chapter_modules():
        importlib.import_module(f"scrppl.exercises.{name}")
    out = [e for e in _REGISTRY.values() if chapter is None or e.chapter == chapter]
    return sorted(out, key=lambda e: tuple(int(p) for p in e.id.split(".")))


# -- failures ---------------------------------------------------------------------------------------
def fail(message: str, *, not_answered: bool = False) -> None:
    """Raise :class:`ExerciseFailed` (or :class:`ExerciseNotAnswered`) with ``message``."""
    raise (ExerciseNotAnswered if not_answered else ExerciseFailed)(message)


def _is_stub(value: Any) -> bool:
    return value is None or value is Ellipsis


def require(answer: Any, name: str) -> None:
    """Fail as "not answered yet" if ``answer`` is a stub (``None`` or ``...``)."""
    if _is_stub(answer):
        fail(
            f"`{name}` is not answered yet (it is still {answer!r}): write your answer in the "
            "cell above this check and run both cells again.",
            not_answered=True,
        )


# -- inputs -----------------------------------------------------------------------------------------
@dataclass
class Case:
    """One input on which an answer is checked.

    Attributes
    ----------
    args
        Positional arguments for the student's function (and the reference).
    label
        A short description shown in messages (e.g. ``"negative robot azimuths, A = 8"``).
    kwargs
        Keyword arguments.
    """

    args: tuple
    label: str = ""
    kwargs: dict[str, Any] = field(default_factory=dict)

    def describe(self, names: Sequence[str] = ()) -> str:
        """The inputs, one per line, with argument names when known."""
        lines = []
        for i, value in enumerate(self.args):
            name = names[i] if i < len(names) else f"argument {i + 1}"
            lines.append(f"    {name} = {describe(value)}")
        for name, value in self.kwargs.items():
            lines.append(f"    {name} = {describe(value)}")
        return "\n".join(lines)


def describe(value: Any, width: int = 300) -> str:
    """A short, readable description of an input or output value (arrays abbreviated)."""
    try:
        import xarray as xr
    except ImportError:  # pragma: no cover - xarray is a dependency
        xr = None
    try:
        import pandas as pd
    except ImportError:  # pragma: no cover - pandas is a dependency
        pd = None
    if xr is not None and isinstance(value, xr.Dataset):
        sizes = ", ".join(f"{k}: {v}" for k, v in value.sizes.items())
        extra = ""
        if "score" in value:
            extra = f", {int(np.isnan(value['score'].values).sum())} missing scores (NaN)"
        return f"<xarray.Dataset ({sizes}){extra}>"
    if xr is not None and isinstance(value, xr.DataArray):
        body = np.array2string(value.values, precision=4, threshold=24, edgeitems=3)
        return f"<xarray.DataArray dims {value.dims}> {body}"
    if pd is not None and isinstance(value, pd.DataFrame):
        return f"<DataFrame with {len(value)} rows, columns {list(value.columns)}>"
    if type(value).__module__.startswith("jax") and _is_prng_key(value):
        # a typed PRNG key (jax.random.key) cannot become a NumPy array: show its key data
        import jax

        data = np.asarray(jax.random.key_data(value))
        return f"<JAX PRNG key, data {np.array2string(data, threshold=12)}>"
    if isinstance(value, np.ndarray) or type(value).__module__.startswith("jax"):
        arr = np.asarray(value)
        if arr.ndim == 0:
            return repr(arr.item())
        if arr.ndim <= 2 and arr.size <= 40:
            body = np.array2string(arr, precision=4, threshold=40, max_line_width=100)
            return f"{body} (shape {arr.shape})"
        return _summary(arr)
    if isinstance(value, tuple) and hasattr(value, "_fields"):  # NamedTuple: ResponseModel, ...
        parts = ",\n      ".join(
            f"{k}={describe(v, width)}" for k, v in zip(value._fields, value, strict=True)
        )
        return f"{type(value).__name__}(\n      {parts})"
    text = repr(value)
    return text if len(text) <= width else text[: width - 5] + " ...>"


def _is_prng_key(value: Any) -> bool:
    """Whether ``value`` is a typed JAX PRNG key array (made by ``jax.random.key``)."""
    import jax

    dtype = getattr(value, "dtype", None)
    return dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)


def _summary(arr: np.ndarray) -> str:
    """One line about a large array: shape, dtype, missing values, range and first values."""
    flat = arr.ravel()
    text = f"<array of shape {arr.shape}, dtype {arr.dtype}"
    if arr.dtype.kind == "f":
        n_nan = int(np.isnan(flat).sum())
        finite = flat[np.isfinite(flat)]
        if n_nan:
            text += f", {n_nan} NaN"
        if finite.size:
            text += f", values in [{finite.min():.4g}, {finite.max():.4g}]"
    elif arr.dtype.kind == "b":
        text += f", {int(flat.sum())} True"
    elif arr.dtype.kind in "iu" and flat.size:
        text += f", values in [{flat.min()}, {flat.max()}]"
    head = np.array2string(flat[:6], precision=4, separator=", ")
    return text + f"; first values {head[:-1]}, ...]>"


# -- calling and comparing --------------------------------------------------------------------------
def call(
    fn: Any, name: str, case: Case, *, where: str = "", arg_names: Sequence[str] | None = None
) -> Any:
    """Call the student's ``fn`` on ``case``; turn a stub or an exception into a helpful failure."""
    require(fn, name)
    if not callable(fn):
        fail(f"`{name}` should be a function, but it is {describe(fn)}.")
    try:
        return fn(*case.args, **case.kwargs)
    except NotImplementedError as err:
        raise ExerciseNotAnswered(
            f"`{name}` is not answered yet: it raises NotImplementedError ({err}). Replace the "
            "`raise NotImplementedError(...)` line with your code and run the cell again."
        ) from None
    except Exception as err:  # the student's code failed: say on which input
        raise ExerciseFailed(
            f"`{name}` raised {type(err).__name__}: {err}\n  on input {where}"
            f"{' (' + case.label + ')' if case.label else ''}:\n"
            f"{case.describe(_arg_names(fn) if arg_names is None else arg_names)}"
        ) from err


def _arg_names(fn: Any) -> list[str]:
    code = getattr(fn, "__code__", None)
    if code is None:
        return []
    return list(code.co_varnames[: code.co_argcount])


@dataclass(frozen=True)
class Mistake:
    """A known wrong way to answer, and the hint to give when an answer matches it.

    Attributes
    ----------
    hint
        What to say (what the mistake is and how to fix it).
    fn
        A function with the reference's signature that makes this mistake; when the student's output
        equals ``fn``'s on a failing input, ``hint`` is shown.
    """

    hint: str
    fn: Callable[..., Any]


def _as_array(value: Any) -> np.ndarray | None:
    try:
        import xarray as xr

        if isinstance(value, xr.DataArray):
            return np.asarray(value.values, dtype=float)
    except ImportError:  # pragma: no cover
        pass
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr


def _close(got: np.ndarray, expected: np.ndarray, rtol: float, atol: float) -> np.ndarray:
    both_nan = np.isnan(got) & np.isnan(expected)
    with np.errstate(invalid="ignore"):
        near = np.abs(got - expected) <= atol + rtol * np.abs(expected)
    return both_nan | (near & ~np.isnan(got) & ~np.isnan(expected)) | (got == expected)


def _difference(got: Any, expected: Any, rtol: float, atol: float) -> str | None:
    """``None`` if equal (within tolerance), else a sentence saying where and how they differ."""
    if isinstance(expected, dict):
        if not isinstance(got, dict):
            return f"expected a dict with keys {sorted(expected)}, got {describe(got)}"
        missing = sorted(set(expected) - set(got), key=str)
        extra = sorted(set(got) - set(expected), key=str)
        if missing or extra:
            return (
                f"keys differ: expected {sorted(expected, key=str)}, got {sorted(got, key=str)}"
                + (f" (missing {missing})" if missing else "")
                + (f" (unexpected {extra})" if extra else "")
            )
        for k in expected:
            d = _difference(got[k], expected[k], rtol, atol)
            if d:
                return f"at key {k!r}: {d}"
        return None
    if isinstance(expected, tuple):
        if not isinstance(got, tuple | list) or len(got) != len(expected):
            return f"expected a tuple of {len(expected)} values, got {describe(got)}"
        for i, (g, e) in enumerate(zip(got, expected, strict=True)):
            d = _difference(g, e, rtol, atol)
            if d:
                return f"in item {i} of the tuple: {d}"
        return None
    if isinstance(expected, str):
        return None if got == expected else f"expected {expected!r}, got {describe(got)}"
    e = _as_array(expected)
    g = _as_array(got)
    if g is None or g.dtype == object:
        return f"expected a number or an array like {describe(expected)}, got {describe(got)}"
    if g.shape != e.shape:
        return f"expected shape {e.shape}, got shape {g.shape} ({describe(got)})"
    ok = _close(g, e, rtol, atol)
    if ok.all():
        return None
    where = tuple(int(i) for i in np.argwhere(~ok)[0])
    n_bad = int((~ok).sum())
    e_show, g_show = _display(expected), _display(got)
    if e.ndim == 0:
        return f"expected {describe(e_show)}, got {describe(g_show)}"
    return (
        f"{n_bad} of {e.size} values differ; the first at index {where}: expected "
        f"{e_show[where].item()!r}, got {g_show[where].item()!r}\n  expected: {describe(e_show)}\n"
        f"  got:      {describe(g_show)}"
    )


def _display(value: Any) -> np.ndarray:
    """``value`` as a NumPy array of its own dtype (integers stay integers), for messages."""
    values = getattr(value, "values", value)  # xarray
    arr = np.asarray(values)
    if arr.dtype.kind not in "biuf":
        arr = arr.astype(float)
    if arr.dtype.kind == "f":
        arr = np.round(arr, 6)
    return arr


def _inputs_at(case: Case, names: Sequence[str], index: tuple[int, ...], shape) -> str:
    """The elementwise inputs behind output ``index`` (for functions that broadcast their inputs)."""
    parts = []
    for i, value in enumerate(case.args):
        if isinstance(value, int | float | np.integer | np.floating) or (
            isinstance(value, np.ndarray) and value.dtype.kind in "iuf"
        ):
            arr = np.asarray(value)
            try:
                item = np.broadcast_to(arr, shape)[index]
            except ValueError:
                return ""
            name = names[i] if i < len(names) else f"argument {i + 1}"
            parts.append(f"{name}={item.item()!r}")
    return ", ".join(parts)


def compare(
    got: Any,
    expected: Any,
    *,
    name: str,
    case: Case,
    where: str = "",
    rtol: float = 1e-6,
    atol: float = 1e-9,
    mistakes: Sequence[Mistake] = (),
    hint: str = "",
    arg_names: Sequence[str] = (),
) -> None:
    """Fail with a message naming the input if ``got`` differs from ``expected``.

    Parameters
    ----------
    got, expected
        The student's and the reference's output: numbers, arrays (NumPy, JAX, xarray), strings, or
        dicts/tuples of those (compared item by item). NaN equals NaN.
    name
        How the answer is called in the message (e.g. ``"relative_view(robot, pose, n_azimuth)"``).
    case
        The input (shown in the message).
    where
        e.g. ``"2 of 6"``.
    rtol, atol
        Tolerances, as in :func:`numpy.isclose`.
    mistakes
        Known mistakes: if ``got`` equals a mistake's output on this input, its hint is shown.
    hint
        A general hint shown when no known mistake matches.
    arg_names
        Names of the inputs, for the message.
    """
    diff = _difference(got, expected, rtol, atol)
    if diff is None:
        return
    lines = [
        f"`{name}` gives a different result on input {where}"
        + (f" ({case.label})" if case.label else "")
        + ":",
        case.describe(arg_names),
        f"  {diff}",
    ]
    e, g = _as_array(expected), _as_array(got)
    if e is not None and g is not None and e.ndim > 0 and g.shape == e.shape and g.dtype != object:
        bad = np.argwhere(~_close(g, e, rtol, atol))
        if len(bad):
            at = _inputs_at(case, arg_names, tuple(int(i) for i in bad[0]), e.shape)
            if at:
                lines.append(f"  (that value comes from {at})")
    for m in mistakes:
        try:
            alt = m.fn(*case.args, **case.kwargs)
        except Exception:  # noqa: BLE001 - a mistake that cannot run on this input just does not match
            continue
        if _difference(got, alt, rtol, atol) is None:
            lines.append(f"Hint: {m.hint}")
            break
    else:
        if hint:
            lines.append(f"Hint: {hint}")
    fail("\n".join(lines))


def check_function(
    fn: Any,
    reference: Callable[..., Any],
    cases: Sequence[Case],
    *,
    name: str,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    mistakes: Sequence[Mistake] = (),
    hint: str = "",
    convert: Callable[[Any], Any] | None = None,
) -> int:
    """Check ``fn`` against ``reference`` on every case; return the number of cases.

    ``convert`` (optional) is applied to the student's output before comparing (e.g. to accept a list
    where an array is expected).
    """
    require(fn, name)
    names = _arg_names(reference)
    for i, case in enumerate(cases):
        where = f"{i + 1} of {len(cases)}"
        got = call(fn, name, case, where=where, arg_names=names)
        if got is None:
            fail(f"`{name}` returned None on input {where}: did you forget the `return` statement?")
        if convert is not None:
            got = convert(got)
        expected = reference(*case.args, **case.kwargs)
        compare(
            got,
            expected,
            name=name,
            case=case,
            where=where,
            rtol=rtol,
            atol=atol,
            mistakes=mistakes,
            hint=hint,
            arg_names=names,
        )
    return len(cases)
