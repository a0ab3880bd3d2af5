"""The figures a user reads first: every panel says what its axes and colours measure."""

from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np

from uqdrive.avoid.figure import avoid_signals_figure, avoid_tradeoff_figure, avoid_trajectories_figure
from uqdrive.data.figure import class_histogram_figure
from uqdrive.figures import save_figure
from uqdrive.models.figure import condition_lines_figure, reliability_grid
from uqdrive.report.figure import eta1_intervals_figure
from uqdrive.safety.figure import safety_hexbin_grid


def ring_panel(rng: np.random.Generator, eta1: float) -> dict[str, np.ndarray]:
    angle = rng.uniform(0, 2 * np.pi, 400)
    radius = rng.normal(10, 0.5, 400)
    ring = np.linspace(0, 2 * np.pi, 50)
    return {
        "x": radius * np.cos(angle),
        "y": radius * np.sin(angle),
        "route": np.stack([10 * np.cos(ring), 10 * np.sin(ring)], 1),
        "left": np.stack([12 * np.cos(ring), 12 * np.sin(ring)], 1),
        "right": np.stack([8 * np.cos(ring), 8 * np.sin(ring)], 1),
        "extent": np.array([-15.0, 15.0, -15.0, 15.0]),
        "eta1": np.array(eta1),
    }


def test_hexbin_panels_have_axes_in_metres_and_one_log_colour_bar_of_visits(tmp_path):
    rng = np.random.default_rng(0)
    panels = {("mcd", "clear_noon"): ring_panel(rng, 0.9), ("vi", "rain"): ring_panel(rng, 0.5)}  # two cells blank
    fig = safety_hexbin_grid(panels, ["mcd", "vi"], ["clear_noon", "rain"], "paths")
    drawn = [ax for ax in fig.axes if ax.collections and ax.get_title()]
    assert len(drawn) == 2
    assert {(ax.get_xlabel(), ax.get_ylabel()) for ax in drawn} == {("x (m)", "y (m)")}
    bars = [ax for ax in fig.axes if "visits" in ax.get_ylabel()]
    assert len(bars) == 1 and bars[0].get_yscale() == "log" and "log" in bars[0].get_ylabel()
    hexagons = [ax.collections[0] for ax in drawn]
    assert hexagons[0].norm is hexagons[1].norm  # one scale: colours compare across panels
    busiest = max(float(h.get_array().max()) for h in hexagons)
    assert bars[0].get_ylim()[0] == 1 and bars[0].get_ylim()[1] >= busiest
    assert save_figure(fig, tmp_path / "hexbin.png").stat().st_size > 5000


LABEL_CHARS = 80  # an axis label a person reads at a glance: one line, no longer than this


def unreadable_labels(fig) -> list[str]:
    """Every axis label or panel title of ``fig`` that runs over `LABEL_CHARS` or over a line."""
    texts = [
        (ax, what, text)
        for ax in fig.axes
        for what, text in (("xlabel", ax.get_xlabel()), ("ylabel", ax.get_ylabel()), ("title", ax.get_title()))
    ]
    return [f"{what} {text[:120]!r}" for ax, what, text in texts if len(text) > LABEL_CHARS or "\n" in text]


def avoid_panel(rng: np.random.Generator) -> dict:
    paths = [
        {"x": np.linspace(0, 30, 20), "y": rng.normal(0, 0.3, 20), "mi": rng.uniform(0, 0.5, 20), "termination": t}
        for t in ("collision", "handover", "timeout")
    ]
    return {
        "paths": paths,
        "obstacle": np.array([25.0, 0.0, 4.0, 2.0]),
        "road": np.array([0, 40, -3, 0, 3]),
        "title": "η̂1 0.7",
    }


def every_figure(rng: np.random.Generator) -> dict[str, object]:
    """Each figure-building function (the `figure` modules), on small inputs shaped as the stages pass them."""
    thresholds = SimpleNamespace(delta1=0.8, delta2=0.6, tau=0.3)
    bins = np.linspace(0, 1, 6)
    reliability = {
        "low": bins[:-1], "high": bins[1:], "frames": np.array([0, 3, 5, 9, 20]),
        "confidence": bins[:-1] + 0.1, "accuracy": bins[:-1] + 0.05, "ece": 0.04,
    }  # fmt: skip
    candidates = {
        "autonomy": rng.uniform(0, 1, 8), "eta1_unknown": rng.uniform(0, 1, 8), "certified": np.arange(8) % 2,
        "pareto": np.arange(8) < 3, "delta1": np.full(8, 0.8), "delta2": np.full(8, 0.6), "tau": np.full(8, 0.3),
    }  # fmt: skip
    signals = [(np.linspace(30, 0, 40), rng.uniform(0, 1, 40), rng.uniform(0, 0.4, 40), "collision") for _ in range(3)]
    return {
        "class_histogram": class_histogram_figure(np.linspace(-0.5, 0.5, 11), {"train": np.arange(1, 12)}, "classes"),
        "safety_hexbin_grid": safety_hexbin_grid({("mcd", "rain"): ring_panel(rng, 0.9)}, ["mcd"], ["rain"], "paths"),
        "reliability_grid": reliability_grid({("mcd", "rain"): reliability}, ["mcd"], ["rain"], "reliability"),
        "condition_lines": condition_lines_figure(
            {"mcd": {"accuracy": [0.9, None]}}, ["clear_noon", "rain"], [("accuracy", "accuracy")], "conditions"
        ),
        "avoid_trajectories": avoid_trajectories_figure({("known", "off"): avoid_panel(rng)}, ["known"], ["off"], "p"),
        "avoid_signals": avoid_signals_figure({"known": signals, "fog": signals}, thresholds, thresholds, "warnings"),
        "avoid_tradeoff": avoid_tradeoff_figure(candidates, 1, 0, 0.9, "trade-off"),
        "eta1_intervals": eta1_intervals_figure(
            [{"method": m, "condition": c, "eta1": 0.5, "eta1_low": 0.1, "eta1_high": 0.9} for m in "ab" for c in "xy"],
            ["a", "b"],
        ),
    }


def test_every_figure_labels_its_axes_in_one_short_line():
    """An axis label is a phrase: the warnings figure once printed a rollout's distances (an array) as its x label."""
    for name, fig in every_figure(np.random.default_rng(0)).items():
        assert not unreadable_labels(fig), f"{name}: {unreadable_labels(fig)}"
        plt.close(fig)
