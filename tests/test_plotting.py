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
    labels = {t.get_text() for t in axes[0, 0].get_legend().get_texts()}
    assert {"Q-learning", "SARSA"} <= labels
    plt.close(fig)


def test_sensitivity_accepts_csv_strings(grid):
    rows = [{k: str(v) for k, v in r.items()} for r in summarize(grid)]
    plt.close(plotting.sensitivity(rows))


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
    from vdbejax.results import stats

    window = 20
    fig = plotting.figure3(grid, smoothing="authors", window=window)
    line = fig.axes[0].get_lines()[0]
    x, y = line.get_xdata(), line.get_ydata()
    # np.convolve 'full' of the agents' mean, shown from episode 20 to its end.
    full = np.convolve(grid.returns[0].mean(0).astype(np.float64), np.ones(window) / window)
    assert x[0] == window and len(x) == grid.num_episodes
    np.testing.assert_allclose(y, full[window - 1:])
    # Up to the last episode it is the trailing moving average; past it, it falls off.
    trailing = stats.moving_average(grid.returns[0].mean(0), window)
    np.testing.assert_allclose(y[: grid.num_episodes - window + 1], trailing[window - 1:], atol=1e-12)
    assert "np.convolve" in fig._suptitle.get_text()
    plt.close(fig)
    with pytest.raises(ValueError, match="smoothing='median'"):
        plotting.figure3(grid, smoothing="median")
    with pytest.raises(ValueError, match="no bands"):
        plotting.figure3(grid, smoothing="authors", bands=True)
