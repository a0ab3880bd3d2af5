"""`uqdrive certify`: a user's policy certified "η1 ≥ target" in a world, or refused — a gate a CI job can call.

The sequential threshold test (`uqdrive.uq.threshold`, unforced) looks after every ``look_size`` rollouts and stops
as soon as it decides: certified (a policy with η1 < η − θ passes with probability ≤ γ_k), refuted (η1 ≥ η + θ
refuted likewise) or, after ``budget`` rollouts, undecided. θ > 0 stops sooner but then certifies only η1 ≥ η − θ.
The interval printed beside the verdict inverts the same test at the stopping time (`uqdrive.uq.gate`): its low end
is ≥ η − θ exactly when certified. A budget that cannot certify even with no failure is refused before any rollout.

Each attempt of a policy name is kept in a ledger (`certify_ledger`): a resubmitted unchanged policy replays its
attempt, a changed one gets fresh seeds and γ_k = 6γ/(π²k²), so re-running the gate never spends more than γ.
Rollouts are kept in a log under the cell's key (policy, world, seeds — not the test's settings) and replayed, and
extended where the test needs more. Everything goes under one folder (``--out-dir``). Exit status: 0 certified,
1 refuted, 3 undecided, 2 bad input. Nothing heavy is imported before the arguments are read.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from omegaconf import DictConfig

    from uqdrive.policy.policy_files import UserPolicySpec
    from uqdrive.safety.certify_config import CertifyRecord, CertifyStage
    from uqdrive.safety.executors import RolloutJob

EXIT = {"certified": 0, "refuted": 1, "undecided": 3}
BAD_INPUT = 2
DESCRIPTION = (
    'Tests "eta1 >= ETA" for a policy file in a world by the sequential threshold test, stopping once decided; prints '
    "what the verdict proves, an interval valid at the stopping time and the rollouts used, writes a JSON record, an "
    "MLflow run and the ledger of attempts under --out-dir, and exits 0 certified, 1 refuted, 3 undecided within the "
    "budget, 2 for a bad policy file or flag (one line)."
)
NEAR_DEFAULT = (
    "Near the target: with theta = 0 there is no indifference zone, so a policy with eta1 close to ETA is seldom "
    "decided. Each attempt k of a policy name spends gamma_k = 6 gamma / (pi^2 k^2) of gamma (the ledger): at the "
    "defaults (eta 0.9, gamma 0.05, budget 400, a look every 4) a first attempt runs at gamma_1 = 0.0304, and exactly, "
    "over the stopping rule, at eta1 = eta it certifies with probability 0.03 and ends undecided with 0.94; for eta1 "
    "in (0.827, 0.955) the right verdict has probability below 1 - 0.0304. A theta > 0 decides sooner but certifies "
    "only eta1 >= ETA - THETA."
)
SUMMARIES = ("collision_rate", "off_road_rate", "left_corridor_rate", "mean_eta2", "mean_mutual_information")
VERDICTS = {"above": "certified", "below": "refuted", None: "undecided"}
DEFAULT_DIR = "uqdrive-certify"


def __getattr__(name: str):
    """The config section, stage schema and record, imported when first asked for (`certify_config`)."""
    if name in {"CertifySection", "CertifyStage", "CertifyRecord", "CertifyVerdict"}:
        from uqdrive.safety import certify_config

        return getattr(certify_config, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def plan(stage: CertifyStage) -> tuple[UserPolicySpec, RolloutJob]:
    """The policy's spec and the rollout job, checked: the policy resolved (`uqdrive.safety.drive.user_driver`: a
    user's, over the env's own spaces where the world is driven as it is) and run on rollout 0's first frame."""
    from uqdrive.safety.drive import user_driver
    from uqdrive.safety.executors import RolloutJob, job_world

    where = stage.condition()
    drive = user_driver("certify.policy", stage.certify.policy, where.native)
    world = job_world(where, stage.camera, stage.vehicle, float(stage.control_hz), float(stage.horizon_s))
    job = RolloutJob(drive.spec, where, stage.certify.base_seed, **world)
    drive.probe(job)
    return drive.spec, job


def run_certify(cfg: DictConfig) -> CertifyRecord:
    """Validate, check the budget's floor, plan, take the ledger's attempt, test (rollouts until decided), write
    the record, log it."""
    from uqdrive.safety.certify_config import CertifyStage
    from uqdrive.schema import validate

    stage = validate(CertifyStage, cfg)
    section = stage.certify
    check_floor(section, first_gamma(section))  # before the policy is even built: the best case cannot certify
    spec, job = plan(stage)
    attempt, job = take_attempt(stage, spec, job)
    test = section.test(attempt.gamma)
    record = _decide(stage, spec, job, attempt, test)
    if section.ledger:
        from uqdrive.safety.certify_ledger import Ledger

        Ledger(ledger_path(stage)).decided(spec.name, attempt, record.verdict)
    log_certify(cfg, stage, record)
    return record


def _decide(stage: CertifyStage, spec: UserPolicySpec, job: RolloutJob, attempt, test) -> CertifyRecord:
    """The rollouts until the test decides (replayed from the cell's log, extended where it needs more), the
    record written."""
    from uqdrive.records import write_record
    from uqdrive.safety.certify_config import CertifyRecord
    from uqdrive.safety.rollout_metrics import summarise
    from uqdrive.safety.runner import CellRunner, cell_key
    from uqdrive.uq.gate import stop_interval

    section = stage.certify
    key = cell_key(job, {"test": "certify"}, None, __name__)  # not the test's settings: rollouts do not depend on them
    log = Path(stage.paths.root) / "cache" / "rollouts" / "certify" / f"{key}.jsonl"
    log.parent.mkdir(parents=True, exist_ok=True)
    with CellRunner.of(stage.executor, stage.progress) as runner:
        run = runner.run("certify", job, key, log, job.base_seed, test.run, section.budget, ahead=runner.batch)
    decision, where = run.outcome, job.where
    read = run.results[: decision.n]
    interval = stop_interval(test, decision.k, decision.n)
    verdict = VERDICTS[decision.decision]
    record = CertifyRecord(
        verdict, guarantee(verdict, section, attempt.gamma), spec.name, spec.kind, spec.digest, where.location,
        where.weather_name, where.noise, section.eta, section.theta, section.gamma, attempt.number, attempt.gamma,
        decision.n, decision.k, decision.k / decision.n, interval.low, interval.high, attempt.gamma,
        section.budget, job.base_seed, key, run.reused, run.seconds,
        "".join("1" if r.verdict.safe else "0" for r in read),
        **summarise(read, SUMMARIES), warning_share=_warning_share(spec, read),
    )  # fmt: skip
    write_record(section.out, record)  # before logging: a tracking failure never loses the verdict
    return record


def ledger_path(stage: CertifyStage) -> Path:
    return Path(stage.paths.root) / "ledger.json"


def first_gamma(section) -> float:
    """The most error any attempt may spend: the first attempt's γ_1 under a ledger, else γ."""
    from uqdrive.uq.gate import attempt_gamma

    return attempt_gamma(section.gamma, 1) if section.ledger else section.gamma


def check_floor(section, gamma: float, test=None) -> None:
    """Refuse a budget that cannot certify at error ``gamma`` even with no failed rollout (the zero-failure floor,
    or ``test`` itself), naming a budget that can."""
    from uqdrive.schema import ConfigError
    from uqdrive.uq.gate import budget_floor, certifies_all_safe, zero_failure_floor

    floor = zero_failure_floor(section.eta, section.theta, gamma)
    if section.budget >= floor and (test is None or certifies_all_safe(test)):
        return
    enough = budget_floor(section.eta, section.theta, gamma, section.look_size)
    raise ConfigError(
        f"budget={section.budget}: can never certify eta1 >= {section.eta - section.theta:g} at gamma={gamma:.4g}, "
        f"even with every rollout safe (the zero-failure floor ln(gamma)/ln(eta - theta) is {floor} rollouts); "
        f"--budget {enough} can"
    )


def take_attempt(stage: CertifyStage, spec: UserPolicySpec, job: RolloutJob):
    """The ledger's attempt for this policy, world and test (its seeds in ``job``), its budget checked against the
    floor at its γ_k before it is written; without a ledger, attempt 0 at the section's seeds and full γ."""
    import dataclasses
    import hashlib

    from uqdrive.safety.certify_ledger import Attempt, Ledger
    from uqdrive.safety.runner import cell_key

    section = stage.certify
    if not section.ledger:
        check_floor(section, section.gamma, section.test())
        return Attempt(0, "", spec.digest, section.base_seed, section.gamma, "unledgered"), job
    settings = [section.eta, section.theta, section.gamma, section.look_size, section.budget, section.base_seed]
    world = cell_key(dataclasses.replace(job, base_seed=0), {"test": "certify"}, None, __name__)
    identity = hashlib.sha256(json.dumps([world, settings]).encode()).hexdigest()[:16]
    ledger = Ledger(ledger_path(stage))
    attempt = ledger.attempt(
        spec.name, identity, spec.digest, section.gamma, section.base_seed, section.fresh_seeds,
        check=lambda gamma: check_floor(section, gamma, section.test(gamma)),  # refused: no attempt spent
    )  # fmt: skip
    return attempt, dataclasses.replace(job, base_seed=attempt.seed_base)


def _warning_share(spec: UserPolicySpec, results: list) -> float | None:
    """The share of steps that raised a warning; None without warnings configured."""
    steps = sum(r.steps for r in results)
    if spec.warnings is None or not steps:
        return None
    return float(sum(int((r.warning >= 0).sum()) for r in results) / steps)


def log_certify(cfg: DictConfig, stage: CertifyStage, record: CertifyRecord) -> None:
    """One MLflow run in `<prefix>/certify`: the `certify` section and the world (location, weather, noise) as params,
    the verdict as a tag and metrics."""
    import mlflow

    from uqdrive.tracking import numeric_metrics, register_certified, stage_run

    tags = {"verdict": record.verdict, "policy_digest": record.policy_digest, "cell_key": record.cell_key}
    tags["guarantee"] = f"{record.verdict.upper()}: {record.guarantee}"  # what the verdict proves, at which γ (θ)
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


def guarantee(verdict: str, section, gamma: float) -> str:
    """What the verdict proves, in words nobody can misread."""
    eta, theta = section.eta, section.theta
    low, high = eta - theta, eta + theta
    zone = f" (target {eta:g}, indifference zone {low:g}..{high:g} where either verdict may come)" if theta else ""
    return {
        "certified": f"eta1 >= {low:g}{zone}: a policy with eta1 < {low:g} passes with probability <= {gamma:.3g}",
        "refuted": f"eta1 < {high:g}{zone}: a policy with eta1 >= {high:g} is refuted with probability <= {gamma:.3g}",
        "undecided": f"neither eta1 >= {low:g} nor eta1 < {high:g} shown within {section.budget} rollouts{zone}",
    }[verdict]


def describe(record: CertifyRecord) -> str:
    """The verdict as the command prints it."""
    attempt = (
        f"attempt {record.attempt} of this policy name (gamma {record.gamma:g} spent as 6 gamma/(pi^2 k^2))"
        if record.attempt
        else f"no ledger: seeds from {record.base_seed}"
    )
    from uqdrive.uq.gate import GateInterval

    shown = GateInterval(record.eta1_low, record.eta1_high).shown()
    return (
        f"{record.verdict.upper()}: {record.guarantee}. For {record.policy} in {record.world}"
        f" ({record.weather}, noise {record.noise:g}): {record.safe}/{record.rollouts} rollouts safe, "
        f"eta1 in {shown} (each end at confidence 1 - {record.interval_gamma:.3g} at the stopping time); {attempt}"
        f"{' (replayed)' if record.reused else ''}"
    )


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="uqdrive certify", description=DESCRIPTION, epilog=NEAR_DEFAULT)
    kinds = "a TorchScript (.pt), ONNX (.onnx), stable-baselines3 (.zip) or policy YAML file"
    p.add_argument("--policy", required=True, help=kinds)
    p.add_argument(
        "--world",
        default=None,
        help="a location in conf/scenario/, a Gymnasium world in conf/gym_world/, or a file DIR/gym_world/NAME.yaml "
        "(default: roundabout)",
    )
    _env_flags(p)
    p.add_argument(
        "--weather", default="clear_noon", help="weather in conf/weather/, pybullet only (default: clear_noon)"
    )
    p.add_argument("--noise", type=float, default=0.0, help="sensor noise sigma (default: 0)")
    p.add_argument("--eta", type=float, default=0.9, help="target: certify eta1 >= this (default: 0.9)")
    p.add_argument(
        "--theta",
        type=float,
        default=0.0,
        help="indifference half-width: certifies only eta1 >= ETA - THETA (default: 0)",
    )
    p.add_argument(
        "--gamma",
        type=float,
        default=0.05,
        help="error probability of a wrong verdict over all attempts (default: 0.05)",
    )
    p.add_argument("--look-size", type=int, default=4, help="rollouts between the test's looks (default: 4)")
    p.add_argument("--budget", type=int, default=400, help="most rollouts run; undecided after (default: 400)")
    p.add_argument(
        "--seed-base",
        "--seed",
        type=int,
        default=None,
        dest="seed",
        help="rollout i uses seed SEED + i and no ledger: the full gamma every run, so re-running changed policies "
        "until one passes (or tuning one to these seeds) multiplies the error (default: the ledger's seeds)",
    )
    p.add_argument(
        "--fresh-seeds",
        action="store_true",
        help="a new attempt even for an unchanged policy: fresh seeds, and it spends the next gamma_k",
    )
    p.add_argument("--horizon", type=float, default=20.0, help="episode length T in seconds (default: 20)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (default: 1)")
    p.add_argument(
        "--out-dir",
        "--root",
        default=DEFAULT_DIR,
        dest="out_dir",
        help=f"where a run writes: rollout cache, MLflow store, ledger, record (default: {DEFAULT_DIR})",
    )
    p.add_argument(
        "--out", default=None, help="the JSON record, refused if it exists (default: OUT_DIR/certify.json, rewritten)"
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("overrides", nargs="*", help="more Hydra overrides of conf/certify.yaml, e.g. vehicle.max_speed=9")
    return p.parse_args(argv)


def _env_flags(p: argparse.ArgumentParser) -> None:
    """A world from a plain env id, judged by its own signals (`uqdrive.sim.gym_world`, hooks: native)."""
    g = p.add_argument_group("a world from a plain Gymnasium env id (the agent sees its observation, acts in it)")
    g.add_argument("--env", help="a registered env id, or module:Id (the module is imported: it registers Id)")
    g.add_argument("--env-kwargs", default="{}", help="gymnasium.make keyword arguments as a JSON object")
    g.add_argument("--unsafe-if", action="append", default=[], metavar="KEY", help="info KEY true: unsafe (repeat)")
    g.add_argument(
        "--safe-if", action="append", default=[], metavar="KEY=VALUE", help="info KEY must be VALUE (true/false) always"
    )
    g.add_argument(
        "--terminated",
        choices=("end", "unsafe"),
        default="end",
        help="a termination: the episode's end, judged by the other signals (default), or a failure; a truncation is "
        "always the end of time",
    )
    g.add_argument("--safe-when", default="", metavar="MOD:FUNC", help="predicate(obs, info) -> bool; False: unsafe")
    g.add_argument("--steps", type=int, default=1000, help="most steps of an episode (default: 1000, or the env's own)")
    g.add_argument(
        "--observe",
        choices=("obs", "view"),
        default="obs",
        help="what the agent sees: the env's observation (default), or its RGB rendering (an image agent)",
    )


def _quoted(value: object) -> str:
    return json.dumps(str(value))  # a Hydra quoted string: paths with '=', ',' or spaces stay one value


def compose_certify(a: argparse.Namespace) -> DictConfig:
    """conf/certify.yaml with the flags as overrides (a world or weather that is not there: one line)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from uqdrive.resolvers import register_resolvers
    from uqdrive.sim.config import find_conf, register_schemas

    conf = find_conf()
    place = _world_overrides(a, conf)
    register_schemas()
    register_resolvers()
    root = Path(a.out_dir).resolve()
    seeds = [f"certify.base_seed={a.seed}", "certify.ledger=false"] if a.seed is not None else []
    overrides = [
        f"certify.policy={_quoted(Path(a.policy).resolve())}", f"certify.out={_quoted(record_path(a).resolve())}",
        f"certify.eta={a.eta}", f"certify.theta={a.theta}", f"certify.gamma={a.gamma}",
        f"certify.look_size={a.look_size}", f"certify.budget={a.budget}", *seeds,
        f"certify.fresh_seeds={str(a.fresh_seeds).lower()}",
        *place, f"noise={a.noise}", f"horizon_s={a.horizon}",
        f"executor.workers={a.workers}", f"paths.root={_quoted(root)}", f"progress={str(not a.no_progress).lower()}",
        *a.overrides,
    ]  # fmt: skip
    values = _env_world(a) if a.env is not None else {}
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cfg = compose("certify", overrides=overrides)
    for key, value in values.items():  # after composing: JSON values need no Hydra quoting
        OmegaConf.update(cfg, f"gym_world.{key}", value, merge=False)
    return cfg


def _env_world(a: argparse.Namespace) -> dict[str, Any]:
    """``--env`` and its safe set: the values of conf/gym_world/env.yaml's keys they set."""
    from uqdrive.schema import ConfigError

    if a.world is not None:
        raise ConfigError(f"--world={a.world!r} beside --env={a.env!r}: the env is the world; give one of them")
    try:
        kwargs = json.loads(a.env_kwargs)
        if not isinstance(kwargs, dict):
            raise ValueError(f"a JSON object, got {type(kwargs).__name__}")
    except ValueError as err:
        raise ConfigError(f"--env-kwargs={a.env_kwargs!r}: expected a JSON object ({err})") from None
    safe_if = {}
    for pair in a.safe_if:
        key, sep, value = pair.partition("=")
        if not (sep and key and value.lower() in ("true", "false")):
            raise ConfigError(f"--safe-if={pair!r}: expected KEY=true or KEY=false")
        safe_if[key] = value.lower() == "true"
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", a.env.rpartition(":")[2]).lstrip(".-") or "env"
    values = {
        "env_id": a.env, "name": name, "env_kwargs": kwargs, "unsafe_if": a.unsafe_if, "safe_if": safe_if,
        "terminated": a.terminated, "safe_when": a.safe_when, "horizon_steps": a.steps, "observe": a.observe,
    }  # fmt: skip
    return values


def _world_overrides(a: argparse.Namespace, conf: Path) -> list[str]:
    """Where ``--world`` (or ``--env``) and ``--weather`` put the policy, as overrides: a location of
    conf/scenario/ in a weather of conf/weather/, a Gymnasium world of conf/gym_world/, a world file of the user's
    own in a folder named ``gym_world`` (its parent joins Hydra's search path), or a plain env id (`_env_world`).
    Anything else: one line saying what there is."""
    from uqdrive.schema import ConfigError

    if a.env is not None:
        return ["gym_world=env"]  # its keys: set after composing (`_env_world`)
    if a.world is None:
        a.world = "roundabout"
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


def record_path(a: argparse.Namespace) -> Path:
    return Path(a.out) if a.out else Path(a.out_dir) / "certify.json"


def main(argv: list[str] | None = None) -> int:
    a = parse(argv)
    if a.out and Path(a.out).exists() and not a.force:
        print(
            f"uqdrive certify: --out={a.out!r} exists; give another path, or --force to overwrite it", file=sys.stderr
        )
        return BAD_INPUT
    from uqdrive.policy.policy_path import missing

    if (refusal := missing(Path(a.policy).resolve())) is not None:  # before anything heavy is imported
        print(f"uqdrive certify: {refusal}", file=sys.stderr)
        return BAD_INPUT
    try:
        cfg = compose_certify(a)
        record = run_certify(cfg)
    except Exception as err:  # a bad flag, config value or policy: one line, exit 2
        from uqdrive.schema import ConfigError
        from uqdrive.stage import one_line

        if not isinstance(err, ConfigError) and type(err).__module__.split(".")[0] not in ("hydra", "omegaconf"):
            raise
        print(f"uqdrive certify: {one_line(err) if not isinstance(err, ConfigError) else err}", file=sys.stderr)
        return BAD_INPUT
    print(f"{describe(record)} -> {cfg.certify.out}")
    return EXIT[record.verdict]
