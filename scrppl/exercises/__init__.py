"""Feedback for the teaching exercises: one check per exercise, run from the exercise notebooks.

The exercise notebooks (``notebooks/`` in the repository; their student copies come from
``make student``) ask for small functions -- the relative azimuth, the average precision of a ranking, the
paper's per-view Gaussian fitted by hand, ... After writing one, a student runs its check::

    from scrppl.exercises import check

    def relative_view(robot, pose, n_azimuth=8):
        return (robot - pose) % n_azimuth

    def object_pose(robot, relative, n_azimuth=8):
        return (robot - relative) % n_azimuth

    check("2.1", relative_view, object_pose)

The check runs the answer on several inputs of its own (fixed seeds; small and awkward cases: negative
angles, missing views, tied scores, ...) and compares it with the library's reference (here
:func:`scrppl.views.relative_azimuth` and :func:`scrppl.views.object_azimuth`). When the answers agree it
prints one line starting with ``✓``; otherwise it raises :class:`ExerciseFailed` (an ``AssertionError``, so
the notebook stops there) whose message says on which input the answer differs, what was expected, what
came back, and -- when the answer matches a known mistake -- what that mistake is. An answer that is still
a stub (``None``, ``...``, or a function that raises ``NotImplementedError``) raises
:class:`ExerciseNotAnswered`.

:func:`list_exercises` lists every exercise (id, title, difficulty); the checks of chapter ``N`` live in
``scrppl.exercises.ch0N`` and load on first use. ``notebooks/README.md`` explains how to add one.
"""

from __future__ import annotations

from typing import Any

from scrppl.exercises._core import (
    DIFFICULTIES,
    Case,
    Exercise,
    ExerciseFailed,
    ExerciseNotAnswered,
    Mistake,
    get_exercise,
    list_exercises,
)

__all__ = [
    "check",
    "ExerciseFailed",
    "ExerciseNotAnswered",
    "Exercise",
    "Case",
    "Mistake",
    "DIFFICULTIES",
    "get_exercise",
    "list_exercises",
    "reference_answers",
    "wrong_answers",
]


def check(exercise_id: str, *answers: Any) -> None:
    """Check answers to one exercise against the library's reference; print a line if they are right.

    Parameters
    ----------
    exercise_id
        ``"<chapter>.<number>"``, as in the exercise's heading (e.g. ``"2.1"``).
    *answers
        What the exercise asks for, in the order its statement gives (usually functions).

    Raises
    ------
    ExerciseNotAnswered
        If an answer is still a stub.
    ExerciseFailed
        If an answer differs from the reference; the message names the input and gives a hint.
    ValueError
        If there is no such exercise, or the number of answers is wrong.
    """
    __tracebackhide__ = True  # IPython and pytest hide this frame: the message is what matters
    ex = get_exercise(exercise_id)
    if len(answers) != len(ex.answers):
        names = ", ".join(ex.answers)
        raise ValueError(
            f"exercise {ex.id} takes {len(ex.answers)} answer(s) ({names}); got {len(answers)}: "
            f"call check({ex.id!r}, {names})"
        )
    try:
        detail = ex.run(*answers)
    except ExerciseFailed as err:
        # Re-raise from here, so that the traceback is the student's cell and this call, not the
        # check's internals; an exception raised by the student's own code stays attached as the cause.
        header = (
            f"{ex.heading} is not answered yet."
            if isinstance(err, ExerciseNotAnswered)
            else f"{ex.heading}: not correct yet."
        )
        raise type(err)(f"{header}\n{err}") from err.__cause__
    print(f"✓ {ex.heading}: correct" + (f" ({detail})." if detail else "."))


def reference_answers(exercise_id: str) -> tuple:
    """Correct answers to an exercise (what ``check`` accepts); for tests and for the curious."""
    return get_exercise(exercise_id).reference()


def wrong_answers(exercise_id: str) -> list[tuple]:
    """Deliberately wrong answers to an exercise (each one ``check`` must reject with a hint)."""
    return get_exercise(exercise_id).wrong()
