"""What drives a closed-loop stage's cells, said once: the config fields every driving stage shares (`DriveSection`,
`CorridorDrive`) and the one resolver from them to a `Driver` (`resolve_driver`): the method name, the picklable
recipe each worker builds (`PolicyRecipe`), and what a stage may still ask of it (the draws a frame gives, how a
warning rule reads them, the recipe acting on a rule's warnings).

Two drivers answer: the experiment's trained controller (`TrainedDriver`: its model file loaded here as the
configured method's, with the experiment's classes; a missing or mismatched file is one line naming the key and the
DVC stage that trains it) and a user's policy (`UserDriver`: its file or YAML loaded, and run on a job's first frame
by `Driver.probe`). The safety, envelope, avoid and certify stages all resolve through here; none of them asks which
driver it has.
"""

from __future__ import annotations

import abc
import dataclasses
from pathlib import Path

from uqdrive.models.model_stage import ModelStage
from uqdrive.models.posterior import posterior_from_config
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.policy_files import UserPolicySpec, load_policy
from uqdrive.policy.recipes import ControllerSpec, PolicyRecipe
from uqdrive.policy.warnings import WarningRule
from uqdrive.resolvers import driver
from uqdrive.safety.cells import cell_posterior
from uqdrive.safety.executors import RolloutJob, probe_policy
from uqdrive.schema import Count, Positive, Str, schema
from uqdrive.sim.config import names_gym_world
from uqdrive.stage_schemas import training_stage


@schema(frozen=True, kw_only=True)
class DriveSection:
    """The fields of a driving stage's section (`safety`, `envelope`, `avoid`) that say what drives its cells and
    where they write: the trained model (``model_path``) or a user's policy in its place (``policy``), the cruise
    speed, η2's ball, the draws a frame takes, the horizon T, and the result, plots and rollout-log paths."""

    model_path: Str
    policy: Str | None = None  # a user's policy file or YAML (`load_policy`), driving in place of model_path
    speed: Positive  # m/s, at most vehicle.max_speed (a Gymnasium world: its car's own limits)
    eps: Positive  # η2's ball, steering units
    draws: DrawSettings  # fixed (the paper's) or sequential draws per frame
    horizon_s: Positive  # T (a Gymnasium world: its own horizon_steps)
    out: Str
    plots_dir: Str
    rollout_log: Str


@schema(frozen=True, kw_only=True)
class CorridorDrive(DriveSection):
    """A drive whose controller draws its own ``samples`` a frame and whose runs are judged in a corridor
    (`safety`, `envelope`); the avoid stage's controller draws warning.samples and has no corridor."""

    samples: Count  # posterior draws per frame (the cap, with sequential draws)
    half_width: Positive | None  # corridor half-width (m); None = the lane (a gym_world: its safe_if, no corridor)


@dataclasses.dataclass(frozen=True)
class Driver(abc.ABC):
    """What drives a stage's cells, resolved: ``method`` (a trained model's method, or the user's policy's name: its
    file's stem), ``spec`` (the recipe its workers build), ``source`` (``key=value`` of the config entry naming it)."""

    method: str
    spec: PolicyRecipe
    source: str

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """What its errors call it."""

    @abc.abstractmethod
    def probe(self, job: RolloutJob) -> int:
        """Check the driver on ``job``'s first frame where that needs a run (a user's policy: built, run once in the
        job's world, failing in one line before any rollout); the draws a frame gives (0: none)."""

    @property
    @abc.abstractmethod
    def warning_draws(self) -> DrawSettings:
        """How a warning rule reads a frame's draws of this driver."""

    @abc.abstractmethod
    def warned(self, rule: WarningRule) -> PolicyRecipe:
        """``spec`` acting on ``rule``'s warnings."""


@dataclasses.dataclass(frozen=True)
class TrainedDriver(Driver):
    """The experiment's trained controller (`ControllerSpec`), its model file checked when resolved."""

    spec: ControllerSpec

    @property
    def name(self) -> str:
        return f"the trained {self.method} model"

    def probe(self, job: RolloutJob) -> int:
        return self.spec.samples  # loaded and checked already: the draws it takes a frame, at most

    @property
    def warning_draws(self) -> DrawSettings:
        return self.spec.draws

    def warned(self, rule: WarningRule) -> ControllerSpec:
        """uqdrive's warning controller: its draws and their tiers by the rule itself."""
        return dataclasses.replace(self.spec, warnings=rule)


@dataclasses.dataclass(frozen=True)
class UserDriver(Driver):
    """A user's policy (`UserPolicySpec`), loaded when resolved, run on a first frame by `probe`."""

    spec: UserPolicySpec

    @property
    def name(self) -> str:
        return self.spec.name

    def probe(self, job: RolloutJob) -> int:
        return probe_policy(job).draw_count

    @property
    def warning_draws(self) -> DrawSettings:
        return DrawSettings(scheme="fixed")  # its own n draws a frame, read at once (the paper's fixed tier rule)

    def warned(self, rule: WarningRule) -> UserPolicySpec:
        """The paper's warning system on the policy's own draws (`uqdrive.policy.slots.UserWarnings`: the levels
        ``rule`` gives on them, its fixed tier being η̂2's)."""
        return dataclasses.replace(self.spec, warnings=rule.config)


def resolve_driver(key: str, drive: DriveSection, stage: ModelStage, samples: int, native: bool = False) -> Driver:
    """What drives the cells of the stage whose section ``key`` is ``drive``: a user's policy (``<key>.policy``,
    loaded; ``native``: an agent over the env's own spaces) or the trained model (``<key>.model_path``, loaded here
    as ``stage.model``'s method with the experiment's classes, drawing ``samples`` a frame)."""
    if drive.policy is not None:
        return user_driver(f"{key}.policy", drive.policy, native, speed=drive.speed, eps=drive.eps)
    method, bins = posterior_from_config(stage.model).method, stage.experiment.bins
    trained_by = training_stage(stage.experiment.name, method, names_gym_world(stage.experiment.name))
    path = Path(drive.model_path)
    cell_posterior(f"{key}.model_path", path, method, bins, trained_by)
    spec = ControllerSpec(drive.speed, str(path), method, bins, samples, drive.eps, draws=drive.draws)
    return TrainedDriver(method, spec, f"{key}.model_path={drive.model_path}")


def user_driver(key: str, policy: str, native: bool, **settings: float) -> UserDriver:
    """A user's policy file or YAML at config entry ``key`` (`load_policy`: ``settings`` are keys its YAML may
    override), named by its file."""
    spec = load_policy(policy, native=native, **settings)
    return UserDriver(driver(policy, ""), spec, f"{key}={policy}")
