"""`uqdrive certify`'s config section, stage schema and record: apart from the command's module so that its
argument path (`--help`, a bad flag) imports none of them (pydantic and the world's schemas take a second)."""

from __future__ import annotations

import dataclasses
from typing import Literal

from uqdrive.safety.certify_ledger import SEED_BLOCK
from uqdrive.schema import Count, OpenUnit, Seed, Str, Unit, invalid, schema
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import SimConfig
from uqdrive.stage_schemas import ExecutorSettings, Stage

CertifyVerdict = Literal["certified", "refuted", "undecided"]


@schema(frozen=True)
class CertifySection:
    """conf/certify.yaml's `certify`: the policy file, the target η and the test's (θ, γ), looks and budget, the
    seeds (a ledger's attempt's, or ``base_seed`` on with ``ledger`` off) and the record's path."""

    policy: Str
    eta: OpenUnit = 0.9
    theta: Unit = 0.0
    gamma: OpenUnit = 0.05
    look_size: Count = 4
    budget: Count = 400
    base_seed: Seed = 0
    ledger: bool = True
    fresh_seeds: bool = False
    out: Str = "certify.json"

    def __post_init__(self) -> None:
        if self.budget < self.look_size:
            raise invalid("budget", self.budget, f"must be >= look_size ({self.look_size})")
        if self.budget > SEED_BLOCK:
            raise invalid("budget", self.budget, f"must be <= {SEED_BLOCK} (an attempt's block of seeds)")
        if not self.theta < min(self.eta, 1 - self.eta):
            raise invalid("theta", self.theta, f"must be < min(eta, 1 - eta) = {min(self.eta, 1 - self.eta):g}")

    def test(self, gamma: float | None = None):
        """The sequential test at error ``gamma`` (default: the section's) — unforced: undecided at the budget
        rather than a guess."""
        from uqdrive.uq import ThresholdTest
        from uqdrive.uq.gate import looks_for

        gamma = self.gamma if gamma is None else gamma
        return ThresholdTest(self.eta, gamma, looks_for(self.look_size, self.budget), theta=self.theta, forced=False)


@schema(root=True)
class CertifyStage(WorldChoice, SimConfig, Stage):
    """`stages/certify.py` and `uqdrive certify`: a policy in a pybullet location and weather, or in a Gymnasium
    world (`WorldChoice`: then its own horizon and control rate), the car, camera and horizon (`SimConfig`), the
    workers, the test."""

    executor: ExecutorSettings
    certify: CertifySection


@dataclasses.dataclass(frozen=True)
class CertifyRecord:
    """The verdict with what it rests on (written as JSON, logged to MLflow). ``guarantee``: what the verdict
    proves, in words; ``interval_gamma``: each end of [eta1_low, eta1_high] holds with confidence 1 − it at the
    stopping time (the attempt's γ_k); ``attempt``: the policy name's attempt in the ledger (0: no ledger)."""

    verdict: CertifyVerdict
    guarantee: str
    policy: str
    policy_kind: str
    policy_digest: str
    world: str
    weather: str
    noise: float
    eta: float
    theta: float
    gamma: float
    attempt: int
    attempt_gamma: float
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
