"""What issue 11 found unreadable in the plots, checked on the figures themselves (the drawn
artists in display coordinates), not by eye."""

from __future__ import annotations

import numpy as np
import pytest

from carfeel.io import plots
from carfeel.io.presets import load_hpattern, load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.steering import simulate_steering
from tests.conftest import shift_run


@pytest.fixture
def figures(monkeypatch):
    """The figures the plot functions draw, kept open (drawn) instead of saved."""
    kept = []

    def keep(fig, plt, path):
        fig.canvas.draw()
        kept.append(fig)
        return path

    monkeypatch.setattr(plots, "_save", keep)
    yield kept
    import matplotlib.pyplot as plt

    for fig in kept:
        plt.close(fig)


def inside(box, points) -> np.ndarray:
    """Which display points (n x 2) lie inside a Bbox."""
    x, y = points[:, 0], points[:, 1]
    return np.asarray((x >= box.x0) & (x <= box.x1) & (y >= box.y0) & (y <= box.y1))


def line_points(ax, line) -> np.ndarray:
    xy = np.asarray(line.get_xydata(), dtype=float)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    return np.asarray(ax.transData.transform(xy))


@pytest.mark.parametrize("seed", range(4))
def test_the_peak_labels_stand_clear_of_the_force_trace(figures, tmp_path, seed):
    """Issue 11: the shift plot's "engagement peak" label lay over the trace."""
    plots.plot_shift(shift_run(seed), tmp_path / "s.png")
    (fig,) = figures
    ax = fig.axes[0]
    trace = line_points(ax, ax.get_lines()[0])
    renderer = fig.canvas.get_renderer()
    labels = [t for t in ax.texts if "\n" in t.get_text()]
    assert {t.get_text().split("\n")[0] for t in labels} >= {"engagement peak", "stop impact"}
    for label in labels:
        box = label.get_bbox_patch().get_window_extent(renderer)
        assert not inside(box, trace).any(), label.get_text()


def test_the_hpattern_legend_tells_up_and_down_shifts_apart(figures, tmp_path):
    """Issue 11: hpattern.png's legend repeated "into 3", "into 2" for up and down shifts."""
    from carfeel.runs import HPatternRunConfig, run_hpattern

    config = HPatternRunConfig(sequence=("N", "1", "2", "3", "2", "N"))
    run_hpattern(config, tmp_path / "hp.csv", tmp_path / "hp.png")
    (fig,) = figures
    legend = fig.axes[1].get_legend()
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["N \u2192 1", "1 \u2192 2", "2 \u2192 3", "3 \u2192 2"]
    assert load_hpattern("5r").name == "5r"  # the layout the labels' gears come from


def test_the_step_plots_legend_leaves_the_torque_visible_and_its_path_is_not_squashed(
    figures, tmp_path
):
    """Issue 11: the ISO 7401 step plot's legend covered the torque and its path panel was a
    flat line (equal scales on a 170 m by 5 m path)."""
    car = load_steering().params
    result = simulate_steering(car, manoeuvres.build("iso7401-step", car.vehicle))
    plots.plot_steering(result, tmp_path / "step.png")
    (fig,) = figures
    ax_t, ax_path = fig.axes[0], fig.axes[3]
    renderer = fig.canvas.get_renderer()
    legend = ax_t.get_legend().get_window_extent(renderer)
    total = next(line for line in ax_t.get_lines() if line.get_label() == "total")
    covered = inside(legend, line_points(ax_t, total)).mean()
    assert covered < 0.02, covered  # the total torque shows (a few samples may pass under)
    box = ax_path.get_window_extent(renderer)
    path = line_points(ax_path, ax_path.get_lines()[0])
    # The path fills its panel's height, not a line in the middle of it.
    assert np.ptp(path[:, 1]) > 0.5 * box.height


@pytest.mark.parametrize("model", ["paper", "physical"])
def test_a_parked_run_plots_the_terms_its_model_has(figures, tmp_path, model):
    """A steer cycle at standstill plots the terms against the wheel angle; the paper's run
    has no physical-model term (it raised KeyError on torque_jacking_Nm)."""
    from carfeel.runs import SteeringRun, run_steering

    run_steering(SteeringRun("steer-cycle", steering_model=model), tmp_path / "p.csv",
                 tmp_path / "p.png")  # fmt: skip
    (fig,) = figures
    labels = {line.get_label() for line in fig.axes[3].get_lines()}
    assert "friction (tau2)" in labels if model == "paper" else "jacking" in labels


def test_the_fit_reports_figure_shows_both_lines_labels_both_and_clips_outliers(figures, tmp_path):
    """Issue 11: the model line hid the measured one, the scatter had no legend and a few
    outliers stretched the residual histogram into one bar."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 20.0, 4000)
    ay = 3.0 * np.sin(0.5 * t)
    measured = 2.0 * ay + rng.normal(0.0, 0.05, t.size)
    model = 2.0 * ay
    measured[[100, 2000]] += 40.0  # two spikes in the log
    plots.plot_torque_validation(t, ay, measured, model, tmp_path / "v.png", "v")
    (fig,) = figures
    ax_t, ax_a, ax_r = fig.axes
    for ax in (ax_t, ax_a):
        labels = [text.get_text() for text in ax.get_legend().get_texts()]
        assert labels == ["model", "measured"]
        model_line, measured_line = ax.get_lines()[:2]
        # The measured line on top and thinner, the model broad beneath: both show.
        assert measured_line.get_zorder() > model_line.get_zorder()
    low, high = ax_r.get_xlim()
    assert low > -1.0 and high < 1.0  # the bulk's range (0.05 Nm noise), not the 40 Nm spikes
    assert "2 of 4000 samples beyond the range shown" in ax_r.get_title()
