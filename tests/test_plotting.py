"""Figures: files are written and the axes are what the paper's plots need."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.image
import matplotlib.pyplot as plt
import numpy as np
import pytest
from synthetic_grid import BEST, synthetic_grid

from vdbejax.results import plotting
from vdbejax.results.analysis import summarize


@pytest.fixture(scope="module")
def grid():
    return synthetic_grid()


def _read(path):
    image = matplotlib.image.imread(path)
    assert image.ndim == 3 and image.shape[0] > 200 and image.shape[1] > 200
    return image


def test_figure3_with_bands(grid, tmp_path):
    fig = plotting.figure3(grid, best_return=BEST, bands=True, path=tmp_path / "fig3.png")
    _read(tmp_path / "fig3.png")
    axes = fig.axes
    assert len(axes) == 8  # 2 learners × 4 explorers
    ax = axes[0]
    assert ax.get_title() == "Q-learning — ε-greedy"
    assert ax.get_xlim()[1] >= grid.num_episodes
    # One band (PolyCollection) and one line per parameter, plus the reference line.
    assert len(ax.collections) == len(grid.select("qlearning", "egreedy"))
    assert any(np.allclose(line.get_ydata(), BEST) for line in ax.get_lines())
    plt.close(fig)


def test_figure3_without_bands_has_no_collections(grid):
    fig = plotting.figure3(grid)
    assert all(len(ax.collections) == 0 for ax in fig.axes)
    plt.close(fig)


def test_sensitivity(grid, tmp_path):
    rows = summarize(grid)
    fig = plotting.sensitivity(rows, best_return=BEST, path=tmp_path / "sens.png")
    _read(tmp_path / "sens.png")
    axes = np.array(fig.axes).reshape(2, 4)
    for ax in axes.ravel():
        assert ax.get_xscale() == "log"
    assert [ax.get_title() for ax in axes[0]] == ["ε-greedy", "softmax", "VDBE", "VDBE-Softmax"]
    assert axes[1, 2].get_xlabel().startswith("σ")
    # Final returns live in [−1.5, 1]; convergence episodes in [1, episodes].
    low, high = axes[0, 0].get_ylim()
    assert low > -2 and high < 1.5
    assert axes[1, 0].get_ylim()[1] <= grid.num_episodes * 1.2
    # Each learner's line carries error bars (one line per learner).
    labels = {t.get_text() for t in fig.legends[0].get_texts()}  # one legend, below
    assert {"Q-learning", "SARSA"} <= labels
    plt.close(fig)


def test_sensitivity_accepts_csv_strings(grid):
    rows = summarize(grid)
    as_read = [{k: str(v) for k, v in r.items()} for r in rows]
    fig, want = plotting.sensitivity(as_read), plotting.sensitivity(rows)
    # The same figure as from the rows themselves: columns, lines and their points.
    assert [ax.get_title() for ax in fig.axes] == [ax.get_title() for ax in want.axes]
    for got_ax, want_ax in zip(fig.axes, want.axes, strict=True):
        got_lines, want_lines = got_ax.get_lines(), want_ax.get_lines()
        assert len(got_lines) == len(want_lines) > 0
        for got, line in zip(got_lines, want_lines, strict=True):
            np.testing.assert_allclose(got.get_xdata(), line.get_xdata())
            np.testing.assert_allclose(got.get_ydata(), line.get_ydata(), rtol=1e-6)
    plt.close(fig)
    plt.close(want)


def test_epsilon_heatmap(tmp_path):
    episodes = np.arange(10, 110, 10)
    epsilon = np.linspace(1, 0, 10)[:, None, None] * np.ones((10, 3, 108))
    states = np.arange(0, 108, 2)
    fig = plotting.epsilon_heatmap(epsilon, episodes, states=states, path=tmp_path / "eps.png")
    _read(tmp_path / "eps.png")
    ax = fig.axes[0]
    image = ax.get_images()[0]
    assert image.get_array().shape == (len(states), len(episodes))  # states × episodes
    assert image.get_clim() == (0.0, 1.0)
    assert ax.get_xlabel() == "episode" and ax.get_ylabel() == "state"
    assert [t.get_text() for t in ax.get_xticklabels()][-1] == "100"
    plt.close(fig)


def test_figure3_as_the_authors_plot_it(grid):
    from vdbejax.results import curves

    window = 20
    fig = plotting.figure3(grid, smoothing="authors", window=window)
    line = fig.axes[0].get_lines()[0]
    x, y = line.get_xdata(), line.get_ydata()
    # np.convolve 'full' of the agents' mean, shown from episode 20 to its end.
    full = np.convolve(grid.returns[0].mean(0).astype(np.float64), np.ones(window) / window)
    assert x[0] == window and len(x) == grid.num_episodes
    np.testing.assert_allclose(y, full[window - 1:])
    # Up to the last episode it is the trailing moving average; past it, it falls off.
    trailing = curves.moving_average(grid.returns[0].mean(0), window)
    np.testing.assert_allclose(y[: grid.num_episodes - window + 1], trailing[window - 1:], atol=1e-12)
    assert "np.convolve" in fig._suptitle.get_text()
    plt.close(fig)
    with pytest.raises(ValueError, match="smoothing='median'"):
        plotting.figure3(grid, smoothing="median")
    with pytest.raises(ValueError, match="no bands"):
        plotting.figure3(grid, smoothing="authors", bands=True)


# ------------------------------------------------------------------ layout of any grid
def _grid_of(settings, seeds=3, episodes=60):
    from vdbejax.results.grid_result import GridResult

    rng = np.random.default_rng(1)
    t = np.arange(episodes)
    levels = np.linspace(-0.8, BEST, len(settings))
    returns = (-1.0 + (levels[:, None, None] + 1.0) * (1.0 - np.exp(-t / 15.0))
               + rng.normal(0, 0.05, (len(settings), seeds, episodes))).astype(np.float32)
    lengths = np.full(returns.shape, 20, np.int32)
    meta = {"mdp": "a_user_task_with_a_rather_long_name", "num_seeds": seeds,
            "num_episodes": episodes, "seed": 0, "max_steps": 100, "options": {},
            "best_return": BEST, "random_return": -1.05}
    return GridResult(settings, returns, lengths, np.zeros(returns.shape[:2], bool), meta)


def _grids():
    from vdbejax.methods import Setting, sweep
    from vdbejax.methods.agents import paper_settings

    nine = sweep(["qlearning"], ["vdbe"], {"alpha": [0.1, 0.3, 0.8],
                                          "sigma": [0.01, 1.0, 100.0]}, {"gamma": 0.95})
    four = [Setting(learner, explorer, 0.1) for learner in ("qlearning", "sarsa")
            for explorer in ("egreedy", "softmax")]
    twelve = sweep(["sarsa"], ["softmax"], {"alpha": [0.1, 0.5, 0.8],
                                           "tau": [0.001, 0.01, 0.1, 1.0]})
    return {"1": [Setting("qlearning", "vdbe_softmax", 1.0)], "4": four, "9": nine,
            "12": twelve, "46": paper_settings()}


def _assert_laid_out(fig):
    """No visible text outside the canvas, no legend over any axes' data region."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    # Everything drawn (titles, labels, the ticks in view, legends), in inches.
    drawn = fig.get_tightbbox(renderer)
    width, height = fig.get_size_inches()
    assert drawn.x0 >= -0.01 and drawn.y0 >= -0.01, drawn
    assert drawn.x1 <= width + 0.01 and drawn.y1 <= height + 0.01, (drawn, width, height)
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    legends += fig.legends
    assert legends
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            data = ax.get_window_extent(renderer)
            overlap_x = min(box.x1, data.x1) - max(box.x0, data.x0)
            overlap_y = min(box.y1, data.y1) - max(box.y0, data.y0)
            assert overlap_x <= 1 or overlap_y <= 1, ("legend over the data of", ax.get_title())


@pytest.mark.parametrize("name", ["1", "4", "9", "12", "46"])
def test_figures_of_any_grid_keep_text_on_the_canvas_and_legends_off_the_data(name):
    settings = _grids()[name]
    grid = _grid_of(settings)
    fig = plotting.figure3(grid, best_return=BEST, bands=True)
    _assert_laid_out(fig)
    plt.close(fig)
    fig = plotting.sensitivity(summarize(grid), best_return=BEST)
    _assert_laid_out(fig)
    plt.close(fig)


def test_curves_of_a_panel_are_told_apart_and_labelled_by_what_varies():
    grid = _grid_of(_grids()["12"])
    fig = plotting.figure3(grid)
    ax = fig.axes[0]
    curves = [line for line in ax.get_lines() if line.get_label().startswith("τ=")]
    assert len(curves) == 12
    styles = {(line.get_color(), str(line.get_linestyle())) for line in curves}
    assert len(styles) == 12  # no two curves alike
    assert curves[0].get_label() == "τ=0.001, α=0.1"  # the swept parameter first
    plt.close(fig)
    nine = _grid_of(_grids()["9"])
    fig = plotting.figure3(nine)
    labels = [line.get_label() for line in fig.axes[0].get_lines()]
    assert "σ=1, α=0.3" in labels and not any("γ" in label for label in labels)
    plt.close(fig)
    # The sensitivity plot's legend: readable values, only those that vary (not γ, no JSON).
    fig = plotting.sensitivity(summarize(nine))
    texts = [t.get_text() for t in fig.legends[0].get_texts()
             if plotting.CENSORED_LABEL not in t.get_text()]  # the lines, less their marks
    assert texts == ["Q-learning α=0.1", "Q-learning α=0.3", "Q-learning α=0.8"], texts
    plt.close(fig)


@pytest.mark.parametrize("values", [[20.0, 30.0, 40.0, 60.0],  # less than a decade
                                    [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0],
                                    [0.0001, 0.0003, 0.001, 0.01, 0.1, 1.0, 10.0, 100.0]])
def test_sensitivity_log_ticks_never_overlap_and_panels_share_one_width(values):
    from vdbejax.methods import sweep

    settings = (sweep(["qlearning", "sarsa"], ["softmax", "vdbe"],
                      {"tau": values, "sigma": values})
                + sweep(["qlearning"], ["egreedy"],  # a column with longer labels
                        {"epsilon": [v / 200 for v in values], "alpha": [0.1, 0.35]}))
    fig = plotting.sensitivity(summarize(_grid_of(settings)), best_return=BEST)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        assert ax.get_xscale() == "log"
        labels = [t for t in ax.get_xticklabels(which="both") if t.get_visible()
                  and t.get_text() and ax.get_xlim()[0] <= t.get_position()[0]
                  <= ax.get_xlim()[1]]
        assert len(labels) >= 2 and "×" not in "".join(t.get_text() for t in labels)
        boxes = sorted((t.get_window_extent(renderer) for t in labels), key=lambda b: b.x0)
        for left, right in zip(boxes, boxes[1:]):
            assert left.x1 < right.x0, [t.get_text() for t in labels]
    widths = {round(ax.get_position().width, 6) for ax in fig.axes}
    assert len(widths) == 1, widths  # the legends' text squeezes no panel
    assert widths.pop() * 3 > 0.75  # the panels fill the figure's width
    plt.close(fig)
