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
import sys
from pathlib import Path
from typing import Literal

import mlflow

from uqdrive.records import write_record
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.policy_files import UserPolicySpec, load_policy, probe_policy
from uqdrive.safety.runner import CellRunner, cell_key
from uqdrive.safety.user_policy import PolicyFailure
from uqdrive.schema import ConfigError
from uqdrive.sim import CameraConfig, VehicleConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import ScenarioConfig, WeatherConfig, find_conf
from uqdrive.tracking import stage_run
from uqdrive.uq import ThresholdTest, clopper_pearson_interval

Verdict = Literal["certified", "refuted", "undecided"]
EXIT = {"certified": 0, "refuted": 1, "undecided": 3}
BAD_INPUT = 2
VERDICTS: dict[str | None, Verdict] = {"above": "certified", "below": "refuted", None: "undecided"}


@dataclasses.dataclass(frozen=True)
class CertifyRequest:
    """What to certify: the policy file, where (a conf/scenario location, weather, sensor noise), the target η and
    the test's (θ, γ), looks and budget; the car's horizon and control rate; where records go."""

    policy: str
    world: str = "roundabout"
    weather: str = "clear_noon"
    noise: float = 0.0
    eta: float = 0.9
    theta: float = 0.0
    gamma: float = 0.05
    look_size: int = 4
    budget: int = 400
    base_seed: int = 0
    horizon_s: float = 20.0
    control_hz: float = 15.0
    workers: int = 1
    out: str = "certify.json"
    root: str = "."
    progress: bool = True

    def test(self) -> ThresholdTest:
        """The sequential test (unforced: undecided at the budget rather than a guess)."""
        looks = tuple(sorted({*range(self.look_size, self.budget + 1, self.look_size), self.budget}))
        return ThresholdTest(self.eta, self.gamma, looks, theta=self.theta, forced=False)


@dataclasses.dataclass(frozen=True)
class CertifyRecord:
    """The verdict with what it rests on (written as JSON, logged to MLflow)."""

    verdict: Verdict
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


def plan(request: CertifyRequest) -> tuple[UserPolicySpec, RolloutJob]:
    """The policy's spec and the rollout job, checked: the policy built and run on rollout 0's first frame."""
    conf = find_conf()
    scenario_file, weather_file = (
        conf / "scenario" / f"{request.world}.yaml",
        conf / "weather" / f"{request.weather}.yaml",
    )
    for key, path in (("--world", scenario_file), ("--weather", weather_file)):
        if not path.is_file():
            names = sorted(p.stem for p in path.parent.glob("*.yaml"))
            raise ConfigError(f"{key}={path.stem!r} is not known; choose one of {names}")
    where = Condition(ScenarioConfig.from_yaml(scenario_file), WeatherConfig.from_yaml(weather_file), request.noise)
    spec = load_policy(request.policy)
    job = RolloutJob(
        spec, where, request.base_seed, CameraConfig(), VehicleConfig(), request.control_hz, request.horizon_s
    )
    probe_policy(job)
    return spec, job


def run_certify(request: CertifyRequest) -> CertifyRecord:
    """Plan, test (rollouts until decided), write the record, log it."""
    test = request.test()
    spec, job = plan(request)
    consumer = {
        "test": "threshold",
        "eta": request.eta,
        "theta": request.theta,
        "gamma": request.gamma,
        "looks": test.looks,
    }
    key = cell_key(job, consumer, None, __name__)
    log = Path(request.root) / "cache" / "rollouts" / "certify" / f"{key}.jsonl"
    log.parent.mkdir(parents=True, exist_ok=True)
    with CellRunner("process", request.workers, progress=request.progress) as runner:
        run = runner.run("certify", job, key, log, request.base_seed, test.run, request.budget, ahead=runner.batch)
    decision = run.outcome
    interval_gamma = request.gamma / len(test.looks)
    low, high = clopper_pearson_interval(decision.k, decision.n, interval_gamma)
    record = CertifyRecord(
        VERDICTS[decision.decision], spec.name, spec.kind, spec.digest, request.world, request.weather,
        request.noise, request.eta, request.theta, request.gamma, decision.n, decision.k,
        decision.k / decision.n, float(low), float(high), interval_gamma, request.budget, request.base_seed,
        key, run.reused, run.seconds, "".join("1" if r.safe else "0" for r in run.results[: decision.n]),
    )  # fmt: skip
    write_record(request.out, record)
    log_certify(request, record)
    return record


def log_certify(request: CertifyRequest, record: CertifyRecord) -> None:
    """One MLflow run in `<prefix>/certify`: the request as params, the verdict as a tag and metrics."""
    config = {"certify": {k: v for k, v in dataclasses.asdict(request).items() if k not in ("root", "progress")}}
    tags = {"verdict": record.verdict, "policy_digest": record.policy_digest, "cell_key": record.cell_key}
    with stage_run(
        request.root, "certify", config, run_name=f"{Path(record.policy).name} · {record.verdict}", tags=tags
    ):
        mlflow.log_metrics({
            "certified": float(record.verdict == "certified"), "rollouts": record.rollouts,
            "eta1_hat": record.eta1_hat, "eta1_low": record.eta1_low, "eta1_high": record.eta1_high,
        })  # fmt: skip
        mlflow.log_artifact(request.out)


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
    defaults = CertifyRequest("")
    p = argparse.ArgumentParser(prog="uqdrive certify", description=__doc__.splitlines()[0].split(": ", 1)[1])
    p.add_argument("--policy", required=True, help="a TorchScript (.pt), ONNX (.onnx) or policy YAML file")
    p.add_argument("--world", default=defaults.world, help="location in conf/scenario/ (default: the roundabout)")
    p.add_argument("--weather", default=defaults.weather, help="weather in conf/weather/ (default: clear_noon)")
    p.add_argument("--noise", type=float, default=defaults.noise, help="sensor noise sigma (default: 0)")
    p.add_argument("--eta", type=float, default=defaults.eta, help="target: certify eta1 >= this (default: 0.9)")
    p.add_argument("--theta", type=float, default=defaults.theta, help="indifference half-width (default: 0)")
    p.add_argument("--gamma", type=float, default=defaults.gamma, help="error probability (default: 0.05)")
    p.add_argument("--look-size", type=int, default=defaults.look_size, help="rollouts between looks (default: 4)")
    p.add_argument("--budget", type=int, default=defaults.budget, help="most rollouts run (default: 400)")
    p.add_argument("--seed", type=int, default=defaults.base_seed, help="rollout i uses seed SEED + i (default: 0)")
    p.add_argument("--horizon", type=float, default=defaults.horizon_s, help="episode length T in s (default: 20)")
    p.add_argument("--workers", type=int, default=defaults.workers, help="worker processes (default: 1)")
    p.add_argument("--out", default=defaults.out, help="the JSON record written (default: certify.json)")
    p.add_argument("--root", default=defaults.root, help="project folder: rollout cache, MLflow store (default: .)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    request = CertifyRequest(
        a.policy, a.world, a.weather, a.noise, a.eta, a.theta, a.gamma, a.look_size, a.budget, a.seed, a.horizon,
        workers=a.workers, out=a.out, root=a.root, progress=not a.no_progress,
    )  # fmt: skip
    try:
        record = run_certify(request)
    except (PolicyFailure, ConfigError, ValueError) as err:
        print(f"uqdrive certify: {err}", file=sys.stderr)
        return BAD_INPUT
    print(f"{describe(record)} -> {request.out}")
    return EXIT[record.verdict]
