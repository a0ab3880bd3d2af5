"""The figures a user reads first: every panel says what its axes and colours measure."""

import numpy as np

from uqdrive.plots import safety_hexbin_grid, save_figure


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
