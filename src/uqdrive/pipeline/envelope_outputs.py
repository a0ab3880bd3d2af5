"""What the `envelope` stage writes and logs: its result record (metrics/envelope/<method>-<replicate>.json), the map
with its tables (plots/envelope/<method>-<replicate>/), and one MLflow run."""

from __future__ import annotations

from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.envelope.certify import VERDICTS, RegionResult, grid_cost
from uqdrive.envelope.figure import envelope_figure
from uqdrive.envelope.search import SearchResult
from uqdrive.envelope.space import ConditionSpace
from uqdrive.files import write_csv
from uqdrive.pipeline.envelope_config import Envelope
from uqdrive.pipeline.envelope_records import EnvelopeAxis, EnvelopeRegion, EnvelopeResult, EnvelopeSearch, GridCost
from uqdrive.pipeline.records import write_record
from uqdrive.plots import save_figure
from uqdrive.tracking import numeric_metrics, stage_run


def guarantee(theta: float) -> str:
    """What the map's verdicts say, together (each region's test at its share of γ, the union bound over them)."""
    safe, unsafe = ("eta1 >= threshold", "eta1 < threshold")
    if theta > 0:
        safe, unsafe = ("eta1 > threshold - theta", "eta1 < threshold + theta")
    return (
        f"family-wise: with probability >= 1 - gamma, at once, every region marked safe has {safe} and every region "
        f"marked unsafe has {unsafe}, where a region's eta1 is the probability that a rollout at a condition drawn "
        "uniformly in the region, on a fresh seed, stays in the safe set"
    )


def _values(space: ConditionSpace, unit: np.ndarray) -> list[float]:
    """A point of the unit box as the axes' values (unrounded)."""
    return [a.low + float(u) * (a.high - a.low) for a, u in zip(space.axes, unit)]


def _region(space: ConditionSpace, r: RegionResult, order: int, region_budget: int) -> EnvelopeRegion:
    low, high = _values(space, np.asarray(r.region.low)), _values(space, np.asarray(r.region.high))
    undecided_by = None
    if r.verdict == "undecided":
        undecided_by = "region_budget" if r.rollouts >= region_budget else "certify_budget"
    return EnvelopeRegion(
        name=r.region.name,
        order=order,
        bounds={a.key: [lo, hi] for a, lo, hi in zip(space.axes, low, high)},
        depth=r.region.depth,
        volume=r.region.volume,
        gamma=r.gamma,
        verdict=r.verdict,
        rollouts=r.rollouts,
        safe_rollouts=r.safe,
        eta1_hat=r.safe / r.rollouts if r.rollouts else None,
        undecided_by=undecided_by,
    )


def envelope_result(
    envelope: Envelope,
    found: SearchResult,
    results: list[RegionResult],
    order: list[int],
    seconds: float,
    unread: int,
) -> EnvelopeResult:
    """The stage's record: ``results`` in depth-first order, ``order`` the order phase two took them in;
    ``unread``: rollouts the regions' cells ran ahead of their tests, which the tests never read."""
    env, space, stage = envelope.settings, envelope.space, envelope.stage
    regions = [_region(space, r, order.index(i), env.region_budget) for i, r in enumerate(results)]
    searched, certified = len(found.outcomes), sum(r.rollouts for r in results)
    return EnvelopeResult(
        method=envelope.method,
        replicate=stage.seed,
        experiment=stage.experiment.name,
        location=stage.scenario.name,
        weather=stage.weather.name,
        noise=stage.noise,
        axes=[EnvelopeAxis(a.key, [a.low, a.high]) for a in space.axes],
        blend={"from": space.blend[0].name, "to": space.blend[1].name} if space.blend else None,
        threshold=env.threshold,
        gamma=env.gamma,
        theta=env.theta,
        guarantee=guarantee(env.theta),
        base_seed=env.base_seed,
        regions=regions,
        verdicts={v: sum(r.verdict == v for r in regions) for v in VERDICTS},
        volume={v: sum(r.volume for r in regions if r.verdict == v) for v in VERDICTS},
        search=EnvelopeSearch(
            rollouts=searched,
            failures=int(searched - found.outcomes.sum()),
            rounds=list(found.rounds),
            points=[_values(space, p) for p in found.points],
            outcomes="".join(str(int(y)) for y in found.outcomes),
        ),
        rollouts={"search": searched, "certify": certified, "unread": unread, "total": searched + certified + unread},
        grid=GridCost(theta=env.grid_theta, **grid_cost(space.dim, env.partition.max_depth, env.grid_theta, env.gamma)),
        seconds=seconds,
    )


def write_outputs(
    envelope: Envelope, result: EnvelopeResult, found: SearchResult, results: list[RegionResult]
) -> list[Path]:
    """The record first, then the map (regions by verdict, phase one's rollouts), the regions' table and phase
    one's rollouts under envelope.plots_dir."""
    env = envelope.settings
    write_record(env.out, result)
    plots = Path(env.plots_dir)
    v, n = result.verdicts, result.rollouts
    title = (
        f"{envelope.method} {envelope.stage.replicate}: η1 ≥ {env.threshold:g} certified in {v['safe']} regions, "
        f"< {env.threshold:g} in {v['unsafe']}, undecided in {v['undecided']} (all at once w.p. ≥ {1 - env.gamma:g}); "
        f"{n['total']} rollouts"
    )
    figure = envelope_figure(envelope.space.axes, results, found.points, found.outcomes, title)
    map_png = save_figure(figure, plots / "map.png")
    rows = [
        {
            "region": r.name,
            **{f"{key}_{end}": b[i] for key, b in r.bounds.items() for i, end in enumerate(("low", "high"))},
            "verdict": r.verdict,
            "rollouts": r.rollouts,
            "safe_rollouts": r.safe_rollouts,
            "gamma": r.gamma,
            "order": r.order,
        }
        for r in result.regions
    ]
    regions = write_csv(plots / "regions.csv", rows)
    keys = [a.key for a in result.axes]
    conditions = [{**dict(zip(keys, p)), "safe": int(y)} for p, y in zip(result.search.points, result.search.outcomes)]
    search = write_csv(plots / "search.csv", conditions)
    return [Path(env.out), map_png, regions, search]


def log_envelope(cfg: DictConfig, result: EnvelopeResult, files: list[Path]) -> None:
    """One MLflow run in experiment `envelope`: the stage's section as params, counts and volumes as metrics,
    the map and the tables as artefacts."""
    metrics = {
        **{f"{v}_regions": n for v, n in result.verdicts.items()},
        **{f"{v}_volume": x for v, x in result.volume.items()},
        **{f"{phase}_rollouts": n for phase, n in result.rollouts.items()},
        "grid_rollouts": result.grid.rollouts,
        "search_failures": result.search.failures,
        "seconds": result.seconds,
    }
    with stage_run(cfg.paths.root, "envelope", cfg, run_name=f"{result.method}-seed{result.replicate}"):
        mlflow.log_metrics(numeric_metrics(metrics))
        for path in files:
            mlflow.log_artifact(str(path))


def describe(result: dict) -> str:
    """The line the stage prints for `run_envelope`'s result."""
    v, x, n = result["verdicts"], result["volume"], result["rollouts"]
    return (
        f"envelope {result['method']} seed{result['replicate']}: {len(result['regions'])} regions, safe {v['safe']} "
        f"({x['safe']:.0%} of the box), unsafe {v['unsafe']} ({x['unsafe']:.0%}), undecided {v['undecided']} "
        f"({x['undecided']:.0%}); {n['total']} rollouts ({n['search']} search, {n['certify']} certify, "
        f"{n['unread']} run ahead unread; a grid of "
        f"the finest regions with per-cell intervals needs {result['grid']['rollouts']}) in {result['seconds']:.0f} s"
        f"{' (reused: every rollout replayed)' if result['reused'] else ''}"
    )
