"""Unit tests of scrppl.exercises: every check accepts the reference, rejects each known wrong answer
with a hint that names the input, and treats stubs as "not answered yet"."""

import numpy as np
import pytest

from scrppl.exercises import (
    DIFFICULTIES,
    ExerciseFailed,
    ExerciseNotAnswered,
    check,
    get_exercise,
    list_exercises,
    reference_answers,
    wrong_answers,
)
from scrppl.exercises._core import Case, Mistake, check_function, compare, describe, exercise

EXERCISES = [e.id for e in list_exercises()]


def test_registry_covers_the_first_chapters():
    for chapter in (2, 3, 4, 5, 6, 7, 8, 9, 10, 11):
        found = list_exercises(chapter)
        assert len(found) >= 3, f"chapter {chapter} has {len(found)} exercises"
        assert {e.difficulty for e in found} <= set(DIFFICULTIES)
        assert "hard" in {e.difficulty for e in found}
        # ids are chapter.1, chapter.2, ... without gaps (the book numbers exercises by position)
        assert [e.id for e in found] == [f"{chapter}.{k}" for k in range(1, len(found) + 1)]


@pytest.mark.parametrize("exercise_id", EXERCISES)
def test_reference_answers_pass(exercise_id, capsys):
    check(exercise_id, *reference_answers(exercise_id))
    out = capsys.readouterr().out
    assert out.startswith(f"✓ Exercise {exercise_id}:") and "correct" in out


@pytest.mark.parametrize("exercise_id", EXERCISES)
def test_wrong_answers_fail_with_a_hint_naming_the_input(exercise_id):
    wrong = wrong_answers(exercise_id)
    assert len(wrong) >= 1, "every exercise needs at least one deliberately wrong answer"
    for answers in wrong:
        with pytest.raises(ExerciseFailed) as info:
            check(exercise_id, *answers)
        assert not isinstance(info.value, ExerciseNotAnswered)
        msg = str(info.value)
        assert msg.startswith(f"Exercise {exercise_id}:") and "not correct yet" in msg
        assert "input" in msg or "seed=" in msg, msg  # says on which input the answer differs
        assert "Traceback" not in msg


@pytest.mark.parametrize("exercise_id", EXERCISES)
def test_stubs_are_not_answered(exercise_id):
    ex = get_exercise(exercise_id)

    def stub(*args, **kwargs):
        raise NotImplementedError(f"Exercise {exercise_id}: write me")

    for answers in ([stub] * len(ex.answers), [...] * len(ex.answers), [None] * len(ex.answers)):
        with pytest.raises(ExerciseNotAnswered, match="not answered yet"):
            check(exercise_id, *answers)


def test_one_stub_among_correct_answers_is_not_answered():
    relative_view, _ = reference_answers("2.1")
    with pytest.raises(ExerciseNotAnswered, match="object_pose"):
        check("2.1", relative_view, ...)


def test_an_exception_in_the_answer_names_the_input_and_keeps_the_cause():
    def relative_view(robot, pose, n_azimuth=8):
        return robot.missing_attribute

    with pytest.raises(ExerciseFailed, match=r"raised AttributeError") as info:
        check("2.1", relative_view, reference_answers("2.1")[1])
    assert "input 1 of" in str(info.value) and "robot = 3" in str(info.value)
    assert isinstance(info.value.__cause__, AttributeError)


def test_an_input_that_is_a_jax_key_is_described():
    # a typed key cannot become a NumPy array; the message of a failing answer still shows it
    import jax

    assert describe(jax.random.key(7)) == "<JAX PRNG key, data [0 7]>"
    assert "PRNG key" in Case((jax.random.key(7), 3)).describe(["key", "n"])


def test_a_function_without_return_is_told_so():
    def relative_view(robot, pose, n_azimuth=8):
        (robot - pose) % n_azimuth  # noqa: B018 - the mistake under test

    with pytest.raises(ExerciseFailed, match="forget the `return`"):
        check("2.1", relative_view, reference_answers("2.1")[1])


def test_known_mistake_gives_its_hint():
    wrong, right = wrong_answers("2.1")[0]
    with pytest.raises(ExerciseFailed, match=r"pose - robot") as info:
        check("2.1", wrong, right)
    msg = str(info.value)
    assert "robot = 3" in msg and "pose = 1" in msg and "expected 2, got 6" in msg


def test_wrong_number_of_answers_and_unknown_ids():
    with pytest.raises(ValueError, match=r"takes 2 answer\(s\)"):
        check("2.1", lambda r, p, n=8: (r - p) % n)
    with pytest.raises(ValueError, match="no exercise '2.99'"):
        check("2.99", None)
    with pytest.raises(ValueError, match="looks like '2.1'"):
        check("two", None)


# -- the helpers chapters 5-10 build on -------------------------------------------------------------
def test_compare_reports_shape_nan_dict_and_first_difference():
    case = Case((np.arange(3),), "three values")
    compare(np.array([0.0, np.nan]), np.array([0.0, np.nan]), name="f(x)", case=case)  # NaN == NaN
    with pytest.raises(ExerciseFailed, match=r"expected shape \(3,\), got shape \(2,\)"):
        compare(np.zeros(2), np.zeros(3), name="f(x)", case=case, where="1 of 1")
    with pytest.raises(ExerciseFailed, match=r"first at index \(1,\): expected 1, got 5"):
        compare(np.array([0, 5, 2]), np.arange(3), name="f(x)", case=case, where="1 of 1")
    with pytest.raises(ExerciseFailed, match=r"that value comes from x=1"):
        compare(np.array([0, 5, 2]), np.arange(3), name="f(x)", case=case, arg_names=["x"])
    with pytest.raises(ExerciseFailed, match=r"keys differ.*missing \['b'\]"):
        compare({"a": 1}, {"a": 1, "b": 2}, name="f(x)", case=case)
    with pytest.raises(ExerciseFailed, match=r"at key 'b': expected 2, got 3"):
        compare({"a": 1, "b": 3}, {"a": 1, "b": 2}, name="f(x)", case=case)
    compare(1.0 + 1e-9, 1.0, name="f(x)", case=case)  # within tolerance


def test_check_function_matches_mistakes_and_general_hints():
    cases = [Case((np.arange(4.0),), "four values")]
    mistakes = [Mistake("you squared instead of doubling", lambda x: x**2)]
    assert check_function(lambda x: 2 * x, lambda x: 2 * x, cases, name="double(x)") == 1
    with pytest.raises(ExerciseFailed, match="Hint: you squared"):
        check_function(lambda x: x**2, lambda x: 2 * x, cases, name="double(x)", mistakes=mistakes)
    with pytest.raises(ExerciseFailed, match="Hint: multiply by two"):
        check_function(
            lambda x: x + 1, lambda x: 2 * x, cases, name="double(x)", hint="multiply by two"
        )
    with pytest.raises(ExerciseNotAnswered):
        check_function(None, lambda x: 2 * x, cases, name="double(x)")
    with pytest.raises(ExerciseFailed, match="should be a function"):
        check_function(3, lambda x: 2 * x, cases, name="double(x)")


def test_a_matching_mistake_shows_its_hint_only():
    """Catches the checker showing several hints when a registered mistake matches and a general hint
    also applies (or when two registered mistakes match): only the first matching mistake's hint shows."""
    cases = [Case((np.arange(4.0),), "four values")]
    mistakes = [
        Mistake("you added instead of doubling", lambda x: x + 1),
        Mistake("you squared instead of doubling", lambda x: x**2),
        Mistake("you squared, then added nothing", lambda x: x**2 + 0),  # matches as well
    ]
    for wrong, only in (
        (lambda x: x**2, "Hint: you squared instead of doubling"),
        (lambda x: x + 1, "Hint: you added instead of doubling"),
    ):
        with pytest.raises(ExerciseFailed) as info:
            check_function(
                wrong, lambda x: 2 * x, cases, name="double(x)", mistakes=mistakes,
                hint="multiply by two",
            )  # fmt: skip
        hints = [line for line in str(info.value).splitlines() if line.startswith("Hint:")]
        assert hints == [only]
    # no mistake matches: the general hint alone
    with pytest.raises(ExerciseFailed) as info:
        compare(np.zeros(4), 2 * np.arange(4.0), name="double(x)", case=cases[0],
                mistakes=mistakes, hint="multiply by two")  # fmt: skip
    hints = [line for line in str(info.value).splitlines() if line.startswith("Hint:")]
    assert hints == ["Hint: multiply by two"]


def test_registration_validates_ids_and_difficulty():
    with pytest.raises(ValueError, match="look like '2.1'"):
        exercise("2", "t", "easy", reference=tuple, wrong=list)
    with pytest.raises(ValueError, match="difficulty"):
        exercise("2.9", "t", "tricky", reference=tuple, wrong=list)


def test_failure_messages_are_readable_for_large_inputs():
    """Big arrays are summarised in one line, not printed in full."""
    (fit,) = reference_answers("4.2")

    def too_wide(y, observed, o):
        mu, sigma = fit(y, observed, o)
        return mu, sigma * 2

    with pytest.raises(ExerciseFailed) as info:
        check("4.2", too_wide)
    msg = str(info.value)
    assert "<array of shape" in msg and len(msg) < 2500


def test_ipython_shows_the_message_and_the_students_own_error_only():
    wrong, right = wrong_answers("2.1")[0]
    with pytest.raises(ExerciseFailed) as info:
        check("2.1", wrong, right)
    (line,) = info.value._render_traceback_()
    assert "ExerciseFailed" in line and "Hint:" in line

    def relative_view(robot, pose, n_azimuth=8):
        return robot.missing_attribute

    with pytest.raises(ExerciseFailed) as info:
        check("2.1", relative_view, right)
    text = "".join(info.value._render_traceback_())
    assert "in relative_view" in text and "AttributeError" in text
    assert "_core.py" not in text and text.rstrip().endswith("n_azimuth = 8")
