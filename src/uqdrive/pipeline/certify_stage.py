"""`uqdrive certify`: a user's policy certified "η1 ≥ target" in a world, or refused — a gate a CI job can call.

The sequential threshold test (`uqdrive.uq.threshold`, unforced) looks after every ``look_size`` rollouts and stops
as soon as it decides: certified (η1 ≥ η wrongly said with probability ≤ γ), refuted (η1 < η, likewise) or, after
``budget`` rollouts, undecided. θ > 0 stops sooner but then certifies only η1 > η − θ (refutes only η1 < η + θ).
The interval printed beside the verdict is Clopper–Pearson at γ / L for the test's L looks: by the union bound it
covers η1 with probability ≥ 1 − γ at whichever look the test stopped.

The policy is built and run on the first frame before any rollout, so a missing, corrupt or mismatched file fails
in one line; rollouts are kept in a log under the cell's key (the policy's bytes or source among it) and replayed
by a rerun of the same policy, world and test. Exit status: 0 certified, 1 refuted, 3 undecided, 2 bad input.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Literal

import mlflow
from omegaconf import DictConfig

from uqdrive.policy.policy_files import UserPolicySpec, load_policy
from uqdrive.records import write_record
from uqdrive.safety.cells import rates
from uqdrive.safety.executors import RolloutJob, job_world, probe_policy
from uqdrive.safety.runner import CellRunner, cell_key
from uqdrive.schema import ConfigError, Count, OpenUnit, Seed, Str, Unit, invalid, schema, validate
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import SimConfig, find_conf
from uqdrive.stage_schemas import ExecutorSettings, Stage
from uqdrive.tracking import numeric_metrics, register_certified, stage_run
from uqdrive.uq import ThresholdTest, clopper_pearson_interval

CertifyVerdict = Literal["certified", "refuted", "undecided"]
EXIT = {"certified": 0, "refuted": 1, "undecided": 3}
BAD_INPUT = 2
DESCRIPTION = (
    'Tests "eta1 >= ETA" for a policy file in a world by the sequential threshold test, stopping once decided; prints '
    "the verdict, an interval and the rollouts used, writes a JSON record and an MLflow run, and exits 0 certified, "
    "1 refuted, 3 undecided within the budget, 2 for a bad policy file or flag (one line)."
)
SUMMARIES = ("collision_rate", "off_road_rate", "left_corridor_rate", "mean_eta2", "mean_mutual_information")
VERDICTS: dict[str | None, CertifyVerdict] = {"above": "certified", "below": "refuted", None: "undecided"}


@schema(frozen=True)
class CertifySection:
    """conf/certify.yaml's `certify`: the policy file, the target η and the test's (θ, γ), looks and budget, the
    first rollout seed and the record's path."""

    policy: Str
    eta: OpenUnit = 0.9
    theta: Unit = 0.0
    gamma: OpenUnit = 0.05
    look_size: Count = 4
    budget: Count = 400
    base_seed: Seed = 0
    out: Str = "certify.json"

    def __post_init__(self) -> None:
        if self.budget < self.look_size:
            raise invalid("budget", self.budget, f"must be >= look_size ({self.look_size})")
        if not self.theta < min(self.eta, 1 - self.eta):
            raise invalid("theta", self.theta, f"must be < min(eta, 1 - eta) = {min(self.eta, 1 - self.eta):g}")

    def test(self) -> ThresholdTest:
        """The sequential test (unforced: undecided at the budget rather than a guess)."""
        looks = tuple(sorted({*range(self.look_size, self.budget + 1, self.look_size), self.budget}))
        return ThresholdTest(self.eta, self.gamma, looks, theta=self.theta, forced=False)


@schema(root=True)
class CertifyStage(WorldChoice, SimConfig, Stage):
    """`stages/certify.py` and `uqdrive certify`: a policy in a pybullet location and weather, or in a Gymnasium
    world (`WorldChoice`: then its own horizon and control rate), the car, camera and horizon (`SimConfig`), the
    workers, the test."""

    executor: ExecutorSettings
    certify: CertifySection


@dataclasses.dataclass(frozen=True)
class CertifyRecord:
    """The verdict with what it rests on (written as JSON, logged to MLflow)."""

    verdict: CertifyVerdict
    policy: str
    policy_kind: str
    policy_digest: str
    world: str
    weather: str
    noise: float
    eta: float
    theta: float
    gamma: float
    rollouts: int
    safe: int
    eta1_hat: float
    eta1_low: float
    eta1_high: float
    interval_gamma: float
    budget: int
    base_seed: int
    cell_key: str
    reused: bool
    seconds: float
    outcomes: str
    collision_rate: float | None = None  # how the rollouts read failed, and (with draws) the policy's confidence
    off_road_rate: float | None = None
    left_corridor_rate: float | None = None
    mean_eta2: float | None = None
    mean_mutual_information: float | None = None
    warning_share: float | None = None  # of the steps, those that raised a warning (a policy YAML's `warnings`)


def plan(stage: CertifyStage) -> tuple[UserPolicySpec, RolloutJob]:
    """The policy's spec and the rollout job, checked: the policy built and run on rollout 0's first frame."""
    spec = load_policy(stage.certify.policy)
    world = job_world(stage.gym_world, stage.camera, stage.vehicle, float(stage.control_hz), float(stage.horizon_s))
    job = RolloutJob(spec, stage.condition(), stage.certify.base_seed, **world)
    probe_policy(job)
    return spec, job


def run_certify(cfg: DictConfig) -> CertifyRecord:
    """Validate, plan, test (rollouts until decided), write the record, log it."""
    stage = validate(CertifyStage, cfg)
    section, test = stage.certify, stage.certify.test()
    spec, job = plan(stage)
    consumer = {"test": "threshold", "eta": section.eta, "theta": section.theta, "gamma": section.gamma}
    key = cell_key(job, {**consumer, "looks": test.looks}, None, __name__)
    log = Path(stage.paths.root) / "cache" / "rollouts" / "certify" / f"{key}.jsonl"
    log.parent.mkdir(parents=True, exist_ok=True)
    with CellRunner.of(stage.executor, stage.progress) as runner:
        run = runner.run("certify", job, key, log, section.base_seed, test.run, section.budget, ahead=runner.batch)
    decision, where = run.outcome, job.where
    read = run.results[: decision.n]
    interval_gamma = section.gamma / len(test.looks)
    low, high = clopper_pearson_interval(decision.k, decision.n, interval_gamma)
    record = CertifyRecord(
        VERDICTS[decision.decision], spec.name, spec.kind, spec.digest, where.location, where.weather_name,
        where.noise, section.eta, section.theta, section.gamma, decision.n, decision.k,
        decision.k / decision.n, float(low), float(high), interval_gamma, section.budget, section.base_seed,
        key, run.reused, run.seconds, "".join("1" if r.verdict.safe else "0" for r in read),
        **{k: v for k, v in rates(read).items() if k in SUMMARIES}, warning_share=_warning_share(spec, read),
    )  # fmt: skip
    write_record(section.out, record)  # before logging: a tracking failure never loses the verdict
    log_certify(cfg, stage, record)
    return record


def _warning_share(spec: UserPolicySpec, results: list) -> float | None:
    """The share of steps that raised a warning; None without warnings configured."""
    steps = sum(r.steps for r in results)
    if spec.warnings is None or not steps:
        return None
    return float(sum(int((r.warning >= 0).sum()) for r in results) / steps)


def log_certify(cfg: DictConfig, stage: CertifyStage, record: CertifyRecord) -> None:
    """One MLflow run in `<prefix>/certify`: the `certify` section and the world (location, weather, noise) as params,
    the verdict as a tag and metrics."""
    tags = {"verdict": record.verdict, "policy_digest": record.policy_digest, "cell_key": record.cell_key}
    tags["guarantee"] = describe(record)  # what the verdict proves, at which γ (θ)
    name = f"{Path(record.policy).name} · {record.world} · {record.verdict}"
    with stage_run(stage.paths.root, "certify", cfg, run_name=name, tags=tags):
        summaries = {k: getattr(record, k) for k in (*SUMMARIES, "warning_share")}
        mlflow.log_metrics({
            "certified": float(record.verdict == "certified"), "rollouts": record.rollouts,
            "eta1_hat": record.eta1_hat, "eta1_low": record.eta1_low, "eta1_high": record.eta1_high,
            **numeric_metrics(summaries),
        })  # fmt: skip
        mlflow.log_artifact(stage.certify.out)
        register_certified(stage.certify.policy, tags, certified=record.verdict == "certified")  # a model version


def describe(record: CertifyRecord) -> str:
    """The verdict as the command prints it."""
    claim = {
        "certified": f"eta1 >= {record.eta:g} certified",
        "refuted": f"eta1 < {record.eta:g} (refuted)",
        "undecided": f"undecided whether eta1 >= {record.eta:g} within {record.budget} rollouts",
    }[record.verdict]
    zone = f", theta={record.theta:g}" if record.theta else ""
    return (
        f"{record.verdict.upper()}: {claim} (gamma={record.gamma:g}{zone}) for {record.policy} in {record.world}"
        f" ({record.weather}, noise {record.noise:g}); {record.safe}/{record.rollouts} rollouts safe, "
        f"eta1 in [{record.eta1_low:.3f}, {record.eta1_high:.3f}] "
        f"(Clopper-Pearson at gamma/{round(record.gamma / record.interval_gamma)} looks)"
        f"{' (replayed)' if record.reused else ''}"
    )


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="uqdrive certify", description=DESCRIPTION)
    kinds = "a TorchScript (.pt), ONNX (.onnx), stable-baselines3 (.zip) or policy YAML file"
    p.add_argument("--policy", required=True, help=kinds)
    p.add_argument(
        "--world",
        default="roundabout",
        help="a location in conf/scenario/, a Gymnasium world in conf/gym_world/, or a file DIR/gym_world/NAME.yaml",
    )
    p.add_argument(
        "--weather", default="clear_noon", help="weather in conf/weather/, pybullet only (default: clear_noon)"
    )
    p.add_argument("--noise", type=float, default=0.0, help="sensor noise sigma (default: 0)")
    p.add_argument("--eta", type=float, default=0.9, help="target: certify eta1 >= this (default: 0.9)")
    p.add_argument("--theta", type=float, default=0.0, help="indifference half-width (default: 0)")
    p.add_argument("--gamma", type=float, default=0.05, help="error probability of a verdict (default: 0.05)")
    p.add_argument("--look-size", type=int, default=4, help="rollouts between the test's looks (default: 4)")
    p.add_argument("--budget", type=int, default=400, help="most rollouts run; undecided after (default: 400)")
    p.add_argument("--seed", type=int, default=0, help="rollout i uses seed SEED + i (default: 0)")
    p.add_argument("--horizon", type=float, default=20.0, help="episode length T in seconds (default: 20)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (default: 1)")
    p.add_argument("--out", default="certify.json", help="the JSON record written (default: certify.json)")
    p.add_argument("--root", default=".", help="project folder: rollout cache, MLflow store (default: .)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("overrides", nargs="*", help="more Hydra overrides of conf/certify.yaml, e.g. vehicle.max_speed=9")
    return p.parse_args(argv)


def _quoted(value: object) -> str:
    return json.dumps(str(value))  # a Hydra quoted string: paths with '=', ',' or spaces stay one value


def compose_certify(a: argparse.Namespace) -> DictConfig:
    """conf/certify.yaml with the flags as overrides (a world or weather that is not there: one line)."""
    from hydra import compose, initialize_config_dir

    from uqdrive.resolvers import register_resolvers
    from uqdrive.sim.config import register_schemas

    conf = find_conf()
    place = _world_overrides(a, conf)
    register_schemas()
    register_resolvers()
    root = Path(a.root).resolve()
    overrides = [
        f"certify.policy={_quoted(Path(a.policy).resolve())}", f"certify.out={_quoted(Path(a.out).resolve())}",
        f"certify.eta={a.eta}", f"certify.theta={a.theta}", f"certify.gamma={a.gamma}",
        f"certify.look_size={a.look_size}", f"certify.budget={a.budget}", f"certify.base_seed={a.seed}",
        *place, f"noise={a.noise}", f"horizon_s={a.horizon}",
        f"executor.workers={a.workers}", f"paths.root={_quoted(root)}", f"progress={str(not a.no_progress).lower()}",
        *a.overrides,
    ]  # fmt: skip
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        return compose("certify", overrides=overrides)


def _world_overrides(a: argparse.Namespace, conf: Path) -> list[str]:
    """Where ``--world`` and ``--weather`` put the policy, as overrides: a location of conf/scenario/ in a weather
    of conf/weather/, a Gymnasium world of conf/gym_world/, or a world file of the user's own in a folder named
    ``gym_world`` (its parent joins Hydra's search path). Anything else: one line saying what there is."""
    if a.world.endswith(".yaml"):
        path = Path(a.world).resolve()
        if not path.is_file() or path.parent.name != "gym_world":
            raise ConfigError(
                f"--world={a.world!r}: a world file must exist in a folder named gym_world/ (its config group), "
                "e.g. myconf/gym_world/drift.yaml"
            )
        return [f"hydra.searchpath=[{_quoted(path.parent.parent.as_uri())}]", f"gym_world={path.stem}"]
    worlds = {p.stem: "scenario" for p in (conf / "scenario").glob("*.yaml")}
    worlds |= {p.stem: "gym_world" for p in (conf / "gym_world").glob("*.yaml")}  # the env is the world: no weather
    if a.world not in worlds:
        raise ConfigError(
            f"--world={a.world!r} is not known; choose one of {sorted(worlds)} (conf/scenario/, conf/gym_world/) "
            "or give a world file, e.g. myconf/gym_world/drift.yaml"
        )
    if not (conf / "weather" / f"{a.weather}.yaml").is_file():
        names = sorted(p.stem for p in (conf / "weather").glob("*.yaml"))
        raise ConfigError(f"--weather={a.weather!r} is not known; choose one of {names}")
    if worlds[a.world] == "gym_world":
        return [f"gym_world={a.world}"]
    return [f"scenario={a.world}", f"weather={a.weather}"]


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    try:
        cfg = compose_certify(a)
        record = run_certify(cfg)
    except Exception as err:  # a bad flag, config value or policy: one line, exit 2
        from uqdrive.stage import one_line

        if not isinstance(err, ConfigError) and type(err).__module__.split(".")[0] not in ("hydra", "omegaconf"):
            raise
        print(f"uqdrive certify: {one_line(err) if not isinstance(err, ConfigError) else err}", file=sys.stderr)
        return BAD_INPUT
    print(f"{describe(record)} -> {cfg.certify.out}")
    return EXIT[record.verdict]
