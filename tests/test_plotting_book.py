"""Figures added for the book chapters (scrppl.plotting)."""

import numpy as np
import pytest

# --- chapters 7-8: repeated views, expected entropy per candidate, sampling error -------------------


def test_plot_repeated_view_panels_and_axes():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_repeated_view

    rng = np.random.default_rng(0)
    label = rng.integers(0, 2, size=20)
    p = {"naive Bayes": rng.uniform(size=(20, 6)), "instance-aware": rng.uniform(size=(20, 6))}
    fig = plot_repeated_view(p, label, example=3)
    assert len(fig.axes) == 2
    assert len(fig.axes[1].lines) == 4  # confidence and accuracy per filter
    plt.close(fig)
    fig, ax = plt.subplots()
    assert plot_repeated_view(p, label, axes=[ax]) is fig
    plt.close(fig)
    with pytest.raises(ValueError, match="same shape"):
        plot_repeated_view({"a": np.zeros((2, 3)), "b": np.zeros((2, 4))}, [0, 1])


def test_plot_expected_entropies_skips_invalid_and_marks_choice():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_expected_entropies

    h = {"quadrature": np.array([1.0, 0.5, 0.7, np.inf]), "plug_in": np.array([1.2, 0.9, 0.6, 2.0])}
    valid = np.array([False, True, True, True])
    fig = plot_expected_entropies(np.arange(4), h, n_azimuths=4, current=1.5, valid=valid)
    ax = fig.axes[0]
    quad_line, quad_star = ax.lines[0], ax.lines[1]
    np.testing.assert_allclose(quad_line.get_xdata(), [90.0, 180.0])  # invalid and inf dropped
    np.testing.assert_allclose(quad_star.get_xdata(), [90.0])  # argmin among valid
    np.testing.assert_allclose(ax.lines[3].get_xdata(), [180.0])
    plt.close(fig)
    with pytest.raises(ValueError, match="shape"):
        plot_expected_entropies(np.arange(4), {"x": np.zeros(3)}, n_azimuths=4)


def test_plot_sampling_error_reference_slope():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_sampling_error

    m = np.array([16, 64, 256, 1024])
    errors = np.abs(np.random.default_rng(1).normal(size=(30, 4))) / np.sqrt(m)
    fig = plot_sampling_error(m, errors)
    ax = fig.axes[0]
    ref = ax.lines[2].get_ydata()
    np.testing.assert_allclose(ref[:-1] / ref[1:], 2.0)  # c / sqrt(M), M growing fourfold
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    plt.close(fig)
    with pytest.raises(ValueError, match="shape"):
        plot_sampling_error(m, errors[:, :3])


# --- chapters 9-10: per-step comparisons (paired differences, policies) ----------------------------


def test_plot_step_comparison_panels_bands_and_colours():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_step_comparison

    k = 5
    mean = np.linspace(-0.1, 0.0, k)
    panels = {
        "160 trials": {"a": (mean, mean - 0.05, mean + 0.05), "b": np.zeros(k)},
        "10,000 trials": {"b": np.ones(k), "a": (mean, mean - 0.01, mean + 0.01)},
    }
    fig = plot_step_comparison(panels, ylabel="difference", zero_line=True)
    assert len(fig.axes) == 2
    left, right = fig.axes
    np.testing.assert_allclose(left.lines[0].get_xdata(), np.arange(1, k + 1))
    assert len(left.collections) == 1  # one band: curve "b" has none
    # a label keeps its colour across panels, whatever the order of the curves
    assert left.lines[0].get_color() == right.lines[1].get_color()
    assert left.lines[1].get_color() == right.lines[0].get_color()
    assert fig.get_facecolor()[:3] == (1.0, 1.0, 1.0)
    plt.close(fig)
    fig, ax = plt.subplots()
    assert plot_step_comparison({"one": {"a": mean}}, ylabel="y", ax=ax) is fig
    with pytest.raises(ValueError, match="one panel"):
        plot_step_comparison(panels, ylabel="y", ax=ax)
    plt.close(fig)
    with pytest.raises(ValueError, match="shape"):
        plot_step_comparison({"p": {"a": (mean, mean[:2], mean)}}, ylabel="y")


# --- chapter 4: the paper's Figs. 2-3 ----------------------------------------------------------------


def test_plot_viewpoint_functions_angle_labels_do_not_collide():
    import jax.numpy as jnp
    import matplotlib.pyplot as plt

    from scrppl.models import ResponseModel
    from scrppl.plotting import plot_viewpoint_functions

    mu = jnp.asarray(np.linspace(-1.0, 1.0, 2 * 8).reshape(1, 2, 8, 1, 1))
    model = ResponseModel(mu, 0.1 + 0 * mu, jnp.zeros((1, 2)))
    fig = plot_viewpoint_functions([("a", model, None), ("b", model, model)])
    assert len(fig.axes) == 4
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    # the 0-degree label of a left panel must not overlap the 180-degree label of the right panel
    for row in range(2):
        left, right = fig.axes[2 * row], fig.axes[2 * row + 1]
        zero = left.get_xticklabels()[0].get_window_extent(renderer)
        back = right.get_xticklabels()[4].get_window_extent(renderer)
        assert zero.x1 < back.x0
    plt.close(fig)


# --- chapters 5-6: instance effects, prior/posterior predictive checks, rank plots --------------------


def _small_view_data(rng, n_pos=3, n_neg=4, n_az=8):
    from scrppl.models.data import make_view_data

    o = np.r_[np.ones(n_pos, int), np.zeros(n_neg, int)]
    y = (
        rng.normal(size=(len(o), n_az, 1, 1))
        + o[:, None, None, None]
        + rng.normal(size=len(o))[:, None, None, None]
    )
    return make_view_data(y, o, np.zeros(len(o), int))


def _small_response_model(rng, n_draws=5, n_az=8):
    import jax.numpy as jnp

    from scrppl.models import ResponseModel

    mu = rng.normal(size=(n_draws, 2, n_az, 1, 1)) + np.array([0.0, 2.0])[None, :, None, None, None]
    sigma = rng.uniform(0.3, 0.8, size=mu.shape)
    tau = rng.uniform(0.1, 0.5, size=(n_draws, 2))
    return ResponseModel(jnp.asarray(mu), jnp.asarray(sigma), jnp.asarray(tau))


def test_plot_instance_effects_lines_and_columns(rng):
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_instance_effects

    data = _small_view_data(rng)
    n_inst = len(data.o)
    fig = plot_instance_effects(data)
    left, right = fig.axes
    assert len(left.lines) == n_inst + 2  # one per instance, one class mean per class
    assert len(right.lines) == 2 * n_inst + 1  # residual dots, their mean, and the zero line
    # a residual column's black bar sits at the mean of its dots
    dots, bar = right.lines[0], right.lines[1]
    np.testing.assert_allclose(bar.get_ydata()[0], np.mean(dots.get_ydata()))
    assert fig.get_facecolor()[:3] == (1.0, 1.0, 1.0)
    plt.close(fig)
    fig, axes = plt.subplots(1, 2)
    assert plot_instance_effects(data, axes=axes) is fig
    with pytest.raises(ValueError, match="need 2 axes"):
        plot_instance_effects(data, axes=axes[:1])
    plt.close(fig)


def test_plot_prior_predictive_draws_and_mismatch(rng):
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_prior_predictive

    data = _small_view_data(rng)
    n = 12
    draws = {
        "mu": rng.normal(size=(n, 2, 8, 1, 1)),
        "y": rng.normal(size=(n,) + data.y.shape),
    }
    fig = plot_prior_predictive(draws, data, n_lines=5)
    left, right = fig.axes
    assert len(left.lines) == 2 * 5 + 2  # 5 prior profiles per class + observed means
    assert len(right.patches) > 0
    plt.close(fig)
    with pytest.raises(ValueError, match="do not match"):
        plot_prior_predictive({"mu": draws["mu"], "y": draws["y"][:, :2]}, data)


def test_plot_predictive_densities_are_normalised(rng):
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_predictive_densities

    model = _small_response_model(rng)
    views = {"a": (0, 0, 0), "b": (3, 0, 0)}
    marks = {"a": {0: np.array([0.1, -0.2]), 1: np.array([2.0])}}
    fig = plot_predictive_densities({"m": model, "twice": model}, views, responses=marks)
    assert len(fig.axes) == 2
    first = fig.axes[0]
    curves = [ln for ln in first.lines if ln.get_linestyle() != "None"]
    assert len(curves) == 4  # two models x two classes
    for ln in curves:  # each curve is a density: it integrates to one over the grid drawn
        x, y = ln.get_xdata(), ln.get_ydata()
        np.testing.assert_allclose(np.sum((y[1:] + y[:-1]) / 2 * np.diff(x)), 1.0, atol=2e-3)
    assert len(first.lines) == 4 + 2  # and the held-out marks of both classes
    plt.close(fig)
    with pytest.raises(ValueError, match="at least one"):
        plot_predictive_densities({}, views)


def test_plot_predictive_sample_check_draws_log_prob(key, rng):
    import matplotlib.pyplot as plt

    from scrppl.models import log_prob, sample
    from scrppl.plotting import plot_predictive_sample_check

    model = _small_response_model(rng)
    x = sample(key, model, 1, 2, 0, 0, shape=(2000,))
    fig, ax = plt.subplots()
    assert plot_predictive_sample_check(x, model, 1, 2, ax=ax) is fig
    (curve,) = ax.lines
    want = np.exp(np.asarray(log_prob(model, curve.get_xdata(), 1, 2, 0, 0)))
    np.testing.assert_allclose(curve.get_ydata(), want, rtol=1e-5)
    plt.close(fig)


def test_plot_fit_rank_panels(rng):
    import arviz as az
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_fit_rank

    tree = az.from_dict(
        {"posterior": {"x": rng.normal(size=(4, 200, 2)), "y": rng.normal(size=(4, 200))}},
        dims={"x": ["class"]},
        coords={"class": ["absent", "present"]},
    )
    pc = plot_fit_rank(tree, var_names=["x", "y"], col_wrap=2)
    fig = pc.viz["figure"].item()
    assert len([ax for ax in fig.axes if ax.has_data()]) == 3  # x[absent], x[present], y
    plt.close("all")
    with pytest.raises(ValueError, match="no posterior variables"):
        plot_fit_rank(tree, var_names=["z"])


# --- plotting takes the objects the library returns -----------------------------------------------


def _loaded(kind, transform="identity"):
    import jax.numpy as jnp

    from scrppl.models.io import ViewpointModel
    from scrppl.models.response import ResponseModel

    profile = np.array([0.5, 1.0, 2.0, 1.0, 0.5, 1.0, 2.0, 1.0])
    rm = ResponseModel.from_profile(profile, absent=0.1, sigma=0.5, tau=0.2 if kind == "h" else 0.0)
    assert isinstance(rm.mu, jnp.ndarray)
    return ViewpointModel(rm, "hierarchical" if kind == "h" else "gaussian", "sift", "car", transform, None)


def test_plot_viewpoint_functions_takes_loaded_models():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_viewpoint_functions

    h, g = _loaded("h", "anscombe"), _loaded("g", "anscombe")
    fig = plot_viewpoint_functions(h, gaussian=g)
    assert len(fig.axes) == 2
    ax = fig.axes[0]
    assert ax.get_title().startswith("sift / car")  # the title comes from the loaded model
    assert ax.get_ylabel() == "response (anscombe scale)"  # and the radial label from its transform
    # the predictive mean drawn is the model's: mu of the present class, closed around the circle
    mean_line = next(line for line in ax.lines if line.get_color() == "tab:red")
    np.testing.assert_allclose(mean_line.get_ydata()[:8], [0.5, 1.0, 2.0, 1.0, 0.5, 1.0, 2.0, 1.0])
    assert len(ax.lines) == 4  # predictive mean, Gaussian mean and its two band edges
    plt.close(fig)
    # a list of models: one row each, no overlay; a ResponseModel works as well as a loaded model
    fig = plot_viewpoint_functions([h, g.response_model], titles=["a", "b"])
    assert len(fig.axes) == 4 and fig.axes[2].get_title().startswith("b")
    plt.close(fig)
    with pytest.raises(ValueError, match="2 models but 1 gaussian overlays and 2 titles"):
        plot_viewpoint_functions([h, g], gaussian=[g])
    with pytest.raises(ValueError, match="at least one model"):
        plot_viewpoint_functions([])


def test_plot_calibration_draws_into_given_axes():
    import matplotlib.pyplot as plt

    from scrppl.plotting import plot_calibration

    cal = {
        "naive_bayes": {"ece": 0.1, "mean_p": [0.1, None, 0.9], "frac": [0.2, None, 0.8], "count": [5, 0, 5]},
        "instance": {"ece": 0.05, "mean_p": [0.2, 0.5, 0.8], "frac": [0.2, 0.5, 0.8], "count": [3, 3, 3]},
    }
    fig, (left, right) = plt.subplots(1, 2)
    assert plot_calibration(cal, "pooled", ax=right) is fig
    assert len(left.lines) == 0 and right.get_title() == "pooled"
    # the diagonal, then one line per filter with its empty bins left out
    assert len(right.lines) == 3
    np.testing.assert_allclose(right.lines[1].get_xdata(), [0.1, 0.9])
    assert right.get_xlabel() == "predicted p(o = present | F)"
    # another event (the K-way filter's top label being right) gets its own axis labels
    plot_calibration(cal, ax=left, xlabel="predicted max p(c | F)", ylabel="fraction right")
    assert (left.get_xlabel(), left.get_ylabel()) == ("predicted max p(c | F)", "fraction right")
    plt.close(fig)


def test_save_figure_is_atomic_and_the_only_one(tmp_path):
    import matplotlib.pyplot as plt

    import scrppl.plotting as plotting
    from scrppl.plotting import dataset, models

    # one definition: wherever the name is reachable, it is the same function
    assert getattr(dataset, "save_figure", plotting.save_figure) is plotting.save_figure
    assert getattr(models, "save_figure", plotting.save_figure) is plotting.save_figure
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    path = plotting.save_figure(fig, tmp_path / "sub" / "f.png", close=True)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.fignum_exists(fig.number)
    assert [p.name for p in path.parent.iterdir()] == ["f.png"]  # no temporary file left behind
    bad = plt.figure()
    bad.savefig = lambda *a, **k: (_ for _ in ()).throw(RuntimeError("disk full"))
    with pytest.raises(RuntimeError, match="disk full"):
        plotting.save_figure(bad, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the old file survives a failed save
    assert [p.name for p in path.parent.iterdir()] == ["f.png"]
    plt.close(bad)


def test_animate_posterior_evolution_is_offline_html_with_one_frame_per_belief():
    import re

    import matplotlib.pyplot as plt

    from scrppl.plotting import animate_posterior_evolution, animation_html

    b = np.random.default_rng(3).dirichlet(np.ones(8), size=3).reshape(3, 2, 4)
    before = plt.get_fignums()
    anim = animate_posterior_evolution(b, 1, [None, 0, 2], label="car", dpi=30, size=2.0)
    assert plt.get_fignums() == before  # released from pyplot: no static copy in a notebook
    html = animation_html(anim)
    assert html.count("data:image/png;base64") == 3  # the prior and two views, embedded
    assert not re.search(r"(?:src|href)=[\"']https?://", html)  # nothing loaded from the network
    assert 'class="fa' not in html and "&#x25B6;" in html  # the play button drawn as a character
    with pytest.raises(ValueError, match="one robot azimuth per frame"):
        animate_posterior_evolution(b, 1, [None, 0])
