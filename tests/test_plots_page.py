"""`dvc plots show` as a person sees it: every plot of dvc.yaml, on the committed run's plot data, rendered in headless
Chromium, draws data marks under titled axes, and every figure loads (tests/rendered_plots.py reads the page back)."""

import csv
import json
import os
import shutil
import subprocess
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from conftest import dvc
from rendered_plots import INSTALL_HINT, chromium, problems, render
from test_failure_modes import RAIN, cell
from test_plots import ring_panel

from uqdrive.pipeline.safety_summary_stage import write_failure_modes
from uqdrive.safety.figure import safety_hexbin_grid
from uqdrive.tools.plots_page import write_page

ROOT = Path(__file__).resolve().parents[1]
FAILURE_MODES = "plots/safety/failure_modes.csv"
IMAGE_PLOTS = (
    "plots/safety/summary",
    "plots/evaluate/figures",
    "plots/avoid/summary",
    "plots/report/envelope",
)  # no PNG in git


def require_chromium() -> None:
    """Skip where Chromium cannot be had; CI installs it (.ci/run), so there a missing one fails."""
    if chromium() is None:
        if os.environ.get("CI"):
            pytest.fail(INSTALL_HINT)
        pytest.skip(INSTALL_HINT)


def plots_project(tmp_path: Path) -> Path:
    """A DVC project with this checkout's dvc.yaml, plot templates and page, the committed run's plot data (its
    params: every plot it drew) and a figure in each image folder (git keeps no PNG)."""
    project = tmp_path / "project"
    project.mkdir()
    for name in ("dvc.yaml", "params.yaml"):
        shutil.copy(ROOT / name, project / name)
    shutil.copytree(ROOT / "plots", project / "plots", ignore=shutil.ignore_patterns("*.png"))
    if not (project / FAILURE_MODES).exists():  # a committed run from before failure records: constructed failures
        write_failure_modes(project / FAILURE_MODES, [cell("mcd", "rain", RAIN), cell("vi", "rain", RAIN[:2])])
    subprocess.run(["git", "init", "-q"], cwd=project, check=True, timeout=60)
    dvc(project, "init", "-q")
    shutil.copytree(ROOT / ".dvc/plots", project / ".dvc/plots")
    write_page(project / ".dvc/plots_page.html")
    dvc(project, "config", "plots.html_template", "plots_page.html")
    rng = np.random.default_rng(0)
    methods, weathers = ["mcd", "vi", "hmc"], ["clear_noon", "afternoon", "rain", "fog"]  # wider than the window
    panels = {(m, w): ring_panel(rng, 0.9) for m in methods for w in weathers}
    figure = safety_hexbin_grid(panels, methods, weathers, "paths")
    for folder in IMAGE_PLOTS:
        (project / folder).mkdir(parents=True, exist_ok=True)
        figure.savefig(project / folder / "figure.png")
    plt.close(figure)
    return project


@pytest.mark.slow
def test_every_plot_of_plots_show_draws_data_under_titled_axes(tmp_path):
    require_chromium()
    project = plots_project(tmp_path)
    dvc(project, "plots", "show")
    drawn = render(project / "dvc_plots/index.html")
    assert not problems(drawn), "\n".join(problems(drawn))
    by_plot = {d.plot: d for d in drawn}
    assert {"plots_offline_class_histogram_csv", "plots_evaluate_reliability_csv"} <= set(by_plot)
    assert {d.kind for d in drawn} == {"vega", "image"}
    histogram = by_plot["plots_offline_class_histogram_csv"]
    assert histogram.axis_titles == ("frames (square-root scale)", "steering class centre (positive = left)")
    with (project / "plots/evaluate/reliability.csv").open() as f:
        conditions = len({(row["weather"], row["noise"]) for row in csv.DictReader(f)})  # a panel each
    reliability = by_plot["plots_evaluate_reliability_csv"]
    assert reliability.axis_titles.count("mean confidence of the bin") == min(conditions, 3)  # one per column


@pytest.mark.slow
def test_the_check_fails_on_a_plot_with_no_data_marks_or_untitled_axes(tmp_path):
    """Mutants of the templates: bars on a log scale from a zero baseline draw nothing; axes with no title; an axis
    title that runs over a line; a page without our style, whose panels cut a wide figure off (as DVC's own)."""
    require_chromium()
    project = plots_project(tmp_path)
    histogram = project / ".dvc/plots/class_histogram.json"
    histogram.write_text(histogram.read_text().replace('"type": "sqrt"', '"type": "log"'))
    reliability = project / ".dvc/plots/reliability.json"
    reliability.write_text(reliability.read_text().replace('"<DVC_METRIC_X_LABEL>"', "null"))
    conditions = project / "dvc.yaml"
    long_title = "mean mutual information (nats) " * 3
    conditions.write_text(
        conditions.read_text().replace("x_label: mean mutual information (nats)", f"x_label: {long_title}")
    )
    page = project / ".dvc/plots_page.html"
    page.write_text(page.read_text().replace("max-width: 100%", "max-width: none"))  # as DVC's own page
    targets = ["plots/offline/class_histogram.csv", "plots/evaluate/reliability.csv", "plots/evaluate/conditions.csv"]
    dvc(project, "plots", "show", *targets, IMAGE_PLOTS[0])
    found = problems(render(project / "dvc_plots/index.html"))
    assert len(found) == 4, found
    assert found[0].startswith("plots_offline_class_histogram_csv: no data marks")
    assert found[1].startswith("plots_evaluate_reliability_csv: axes without titles")
    assert found[2].startswith("plots_evaluate_conditions_csv: axis titles longer than 80 characters")
    assert found[3].startswith("plots_safety_summary_figure_png: image") and "px wide in a panel of" in found[3]


def test_plots_show_each_learning_curve_once_titled_the_eta1_chart_the_envelope_maps_and_padded_scatters(tmp_path):
    """Learning curves: one plot, a panel titled by experiment · method and a line per replicate, not a plot per CSV
    named by its path and its PNG again; η̂1 with its interval per condition; the envelope maps; the trade-off's and
    the signals' rates of 0 and 1 drawn inside the frame (the scales padded), not on its edge."""
    project = plots_project(tmp_path)
    (project / "plots/offline/train/vi/seed0_curve.png").write_bytes(
        (project / IMAGE_PLOTS[0] / "figure.png").read_bytes()
    )
    shown = json.loads(dvc(project, "plots", "show", "--json"))["data"]
    assert not [plot for plot in shown if "/train/" in plot], [p for p in shown if "/train/" in p]
    curves = shown["plots/report/learning_curves.csv"][0]["content"]
    panels = {row["panel"] for row in curves["data"]["values"]}
    assert "offline · vi" in panels and curves["facet"]["field"] == "panel"
    assert {row["replicate"] for row in curves["data"]["values"]} == {"seed0", "seed1"}
    assert curves["spec"]["encoding"]["y"]["scale"]["zero"] is False  # accuracies near 1, not squashed against 0
    eta1 = shown["plots/report/eta1.csv"][0]["content"]
    assert {"eta1_low", "eta1_high"} <= set(eta1["data"]["values"][0])
    assert any(p.startswith("plots/report/envelope/") for p in shown)
    for name in ("tradeoff.csv", "signals.csv"):
        plot = next(v[0]["content"] for p, v in shown.items() if p.endswith(f"mcd-seed0/{name}"))
        assert all(plot["encoding"][axis]["scale"]["padding"] > 0 for axis in ("x", "y")), name
    # every chart titled in words, not by its file's path; the η̂1 chart fits a 1400-px window, its legend on top
    titles = {p: v[0]["content"].get("title") for p, v in shown.items() if v[0].get("type") == "vega"}
    untitled = [p for p, t in titles.items() if not t or ".csv" in str(t) or str(t) == p]
    assert titles and not untitled, untitled
    assert eta1["width"] <= 1100 and eta1["encoding"]["color"]["legend"]["orient"] == "top"
