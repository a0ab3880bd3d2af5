"""The runs table and charts an experiment opens with in the MLflow UI.

MLflow 3.17's runs table shows no metric column until a user picks one (its defaults are Created, Dataset,
Duration, Source, Models), and its chart view leads with whatever metrics sort first. Its UI also reads a *shared
view*: an experiment tag ``mlflow.sharedViewState.<key>`` holding the table's columns, its sort and its chart
sections, applied when a link names the key (``viewStateShareKey=<key>``). Every experiment uqdrive makes carries
one: the stage's key metrics (η1 and its interval for a closed-loop stage) and the keys runs are compared by as
columns, the worst run first, and a chart section of those metrics first in the chart view. `runs_link` is the link
that opens it; `make ui` prints one per experiment.
"""

from __future__ import annotations

import json
import string
from collections.abc import Sequence

VIEW_KEY = "uqdrive"
VIEW_TAG = f"mlflow.sharedViewState.{VIEW_KEY}"
SECTION_ID = "uqdrive-key-metrics"


def metric_names(form: str) -> list[str]:
    """The metrics a run-name form such as ``"η1={eta1:.2f} [{eta1_low:.2f}, …]"`` shows, in its order."""
    return [field for _, field, _, _ in string.Formatter().parse(form) if field]


def column(kind: str, key: str) -> str:
    """The UI's name of a runs-table column (its canonical sort key): ``metrics.`eta1```."""
    return f"{kind}.`{key}`"


def runs_view(metrics: Sequence[str], params: Sequence[str]) -> dict:
    """The shared view: ``metrics`` then ``params`` as columns, sorted by the first metric ascending (the least safe
    cell, the least accurate model first), and one chart section leading with a bar chart per metric."""
    charts = [
        {
            "type": "BAR",
            "uuid": f"{SECTION_ID}-{name}",
            "metricSectionId": SECTION_ID,
            "metricKey": name,
            "deleted": False,
            "isGenerated": False,
        }
        for name in metrics
    ]
    view: dict = {
        "selectedColumns": [column("metrics", m) for m in metrics] + [column("params", p) for p in params],
        "compareRunSections": [{"uuid": SECTION_ID, "name": "Key metrics", "display": True, "isReordered": False}],
        "compareRunCharts": charts,
        "isAccordionReordered": True,
    }
    if metrics:
        view |= {"orderByKey": column("metrics", metrics[0]), "orderByAsc": True}
    return view


def view_tag(metrics: Sequence[str], params: Sequence[str]) -> dict[str, str]:
    """The experiment tag that holds `runs_view`."""
    return {VIEW_TAG: json.dumps(runs_view(metrics, params), ensure_ascii=False)}


def runs_link(experiment_id: str, port: int | str = 5000, host: str = "127.0.0.1") -> str:
    """The link to an experiment's runs in MLflow's model-training view, opening its shared view. The ``/runs``
    tab must be named: the experiment's bare page redirects there and drops the share key."""
    return (
        f"http://{host}:{port}/#/experiments/{experiment_id}/runs"
        f"?viewStateShareKey={VIEW_KEY}&workflowType=machine_learning"
    )
