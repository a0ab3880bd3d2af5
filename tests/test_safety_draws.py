"""Sequential draws on synthetic posteriors whose predictive mode and η2 are known exactly: π(o) and the warning tier
come out right (error rates by simulation, their Clopper–Pearson interval below γ), with few draws where the draws
agree; the paper's fixed draws stay selectable and give the same decisions there. Warnings off and on draw alike:
a warnings-off controller records what a warning rule reads, and on the same seed the two drive identically until
a warning first acts."""

import math

import numpy as np
import pytest
import torch
from conftest import CONF, compose_stage
from omegaconf import OmegaConf
from scipy import stats
from test_uq_tier import tier_probabilities, wrong_tier_rate

from uqdrive.data.binning import SteeringBins
from uqdrive.models import load_posterior
from uqdrive.models.posterior import Posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.interface import NO_WARNING
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.policy.warnings import WarningConfig, WarningController, WarningRule, levels_of
from uqdrive.safety.rollout import run_rollout
from uqdrive.schema import ConfigError, validate
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.uq.tier import CONFIDENT, DOUBTFUL, UNSURE

BINS = SteeringBins()  # 21 classes, centres -1.0 … 1.0
SEQUENTIAL = DrawSettings("sequential")
UNRECORDED = DrawSettings("sequential", unacted="skip")  # a controller without warnings that nothing replays
WARNING = WarningConfig()  # δ1 0.7, δ2 0.6, τ 0.45; 738 draws per frame at θ = γ = 0.05
RULE = WarningRule(WARNING, SEQUENTIAL)  # the paper's rule with sequential draws


class MixturePosterior:
    """Each draw is one of the probability vectors ``vectors`` [S, C], picked with ``weights`` from the generator:
    the predictive q = weights @ vectors, and η2 around its mode, are known exactly."""

    def __init__(self, vectors: np.ndarray, weights: list[float]):
        self.vectors = torch.as_tensor(vectors, dtype=torch.float32)
        self.weights = torch.as_tensor(weights, dtype=torch.float64)

    def eval(self) -> "MixturePosterior":
        return self

    def features_each(self, x: torch.Tensor) -> torch.Tensor:
        return x.flatten(1)[:, :1]

    def head_probs(self, features: torch.Tensor, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        index = torch.multinomial(self.weights, n, replacement=True, generator=generator)
        return self.vectors[index][:, None, :].expand(n, len(features), -1)

    head_probs_each = Posterior.head_probs_each  # one head_probs call per frame, as every posterior can

    def mode(self) -> int:
        return int((self.weights.float() @ self.vectors).argmax())

    def eta2(self, eps: float = 0.1) -> float:
        centres = torch.as_tensor(BINS.centres)
        inside = (centres[self.vectors.argmax(-1)] - centres[self.mode()]).abs() <= eps + 1e-9
        return float(self.weights[inside].sum())


def peaked(cls: int, top: float = 0.98, second: int | None = None, runner_up: float = 0.0) -> np.ndarray:
    """A draw with ``top`` on class ``cls`` (and ``runner_up`` on ``second``), the rest spread evenly."""
    vector = np.full(BINS.num_classes, (1 - top - runner_up) / (BINS.num_classes - 1 - (second is not None)))
    vector[cls] = top
    if second is not None:
        vector[second] = runner_up
    return vector


POSTERIORS = {  # name: (posterior, its η2 tier at the paper's thresholds)
    "confident": (MixturePosterior(np.stack([peaked(10)]), [1.0]), CONFIDENT),
    "overlapping labels": (MixturePosterior(np.stack([peaked(10, 0.55, 11, 0.40)]), [1.0]), CONFIDENT),
    "mostly agreeing": (MixturePosterior(np.stack([peaked(10), peaked(11), peaked(2)]), [0.8, 0.12, 0.08]), CONFIDENT),
    "split": (MixturePosterior(np.stack([peaked(4), peaked(16)]), [0.55, 0.45]), DOUBTFUL),
    "unsure": (MixturePosterior(np.stack([peaked(10), peaked(3), peaked(17)]), [0.65, 0.2, 0.15]), UNSURE),
}


WEATHER = WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml")


@pytest.fixture(scope="module")
def frame():
    with DrivingEnv() as env:
        return env.reset(0, Condition(ScenarioConfig.from_yaml(CONF / "scenario" / "obstacle.yaml"), WEATHER))


def decisions(controller: Controller, frame, frames: int) -> list:
    """One frame decided ``frames`` times, each with its own seed (the controller's per-frame decision step)."""
    x = torch.from_numpy(frame).float()[None].flatten(1)
    out = []
    for seed in range(frames):
        controller.reset(seed)
        out.append(controller.decide(controller.posterior.features_each(x.view(1, 1, -1)), [0])[0])
    return out


def upper(errors: int, trials: int) -> float:
    """The top of the error rate's 95 % Clopper–Pearson interval."""
    return float(stats.beta.ppf(0.975, errors + 1, trials - errors))


@pytest.mark.parametrize("name", POSTERIORS)
def test_settled_modes_and_tiers_are_wrong_less_often_than_gamma(frame, name):
    """π(o): settled on a non-mode less often than γ (Ville), by simulation. The tier: the controller's wrong-tier
    count is what the rule's exact error at this η2 predicts (test_uq_tier's independent DP; two-sided binomial
    p > 0.001), and that error is ≤ γ: η2 = 0.55 and 0.65 sit on zone edges, where 200 frames cannot show an
    error below γ, but can show the controller reads its stream as the rule says."""
    posterior, tier = POSTERIORS[name]
    assert posterior.eta2() == pytest.approx({"split": 0.55, "unsure": 0.65}.get(name, posterior.eta2()))
    controller = WarningController(posterior, BINS, RULE, 0.1, 8.0, 15.0)
    frames = decisions(controller, frame, 200)
    mode = BINS.centres[posterior.mode()]
    wrongly_settled = sum(f.settled and not math.isclose(f.decision, mode, abs_tol=1e-6) for f in frames)
    assert upper(wrongly_settled, len(frames)) < SEQUENTIAL.gamma  # Ville: P(settle on a non-mode) ≤ γ
    exact = 1 - tier_probabilities(RULE.tier, np.array([posterior.eta2()]))[tier, 0]
    wrong = sum(f.tier != tier for f in frames)
    assert exact <= SEQUENTIAL.gamma and stats.binomtest(wrong, len(frames), exact).pvalue > 0.001
    assert all(f.draws <= 2 * WARNING.samples for f in frames)


def test_frames_whose_draws_agree_settle_in_one_head_call_or_three(frame):
    """Confident: 24 draws for π(o) and MI (h(3/24) < τ) and 24 for η2 (its first two looks and more, drawn in the
    same call), one head call. Overlapping labels (every draw 0.55 / 0.40): the mode's small margin takes two more
    looks of π(o)."""
    for name, draws in (("confident", {48}), ("overlapping labels", {64})):
        posterior, _ = POSTERIORS[name]
        controller = WarningController(posterior, BINS, RULE, 0.1, 8.0, 15.0)
        frames = decisions(controller, frame, 20)
        assert {f.draws for f in frames} == draws and all(f.settled and f.tier == CONFIDENT for f in frames), name
        assert {f.eta2 for f in frames} == {1.0} and all(f.mutual_information < WARNING.tau for f in frames)


def test_a_controller_that_acts_on_no_warning_and_skips_draws_no_eta2_set(frame):
    posterior, _ = POSTERIORS["confident"]
    controller = Controller(posterior, BINS, WARNING.samples, 0.1, 8.0, UNRECORDED)
    controller.reset(3)
    command = controller.act(frame, {})
    assert command.draw_count == 24 and math.isnan(command.eta2) and command.warning == NO_WARNING
    assert command.steer == pytest.approx(BINS.centres[10])


def stage_array(frames: list) -> np.ndarray:
    """Recorded MI stages [frames, S, 3], NaN past each frame's last (as a rollout records them)."""
    out = np.full((len(frames), max(len(f.mi_stages) for f in frames), 3), np.nan)
    for row, f in zip(out, frames):
        row[: len(f.mi_stages)] = f.mi_stages
    return out


@pytest.mark.parametrize("name", ["mostly agreeing", "unsure", "split"])
def test_a_controller_that_acts_on_no_warning_records_what_a_warning_rule_reads(frame, name):
    """The avoid stage's warnings-off cells are replayed by the threshold calibration over a grid of rules: on the
    same seed, a warnings-off controller takes the warning controller's π(o) from the same draws and reads both of
    its streams further, to the cap; from what it records, the rule's tier and MI, and so its warning level, are
    the ones the warning controller decides."""
    posterior, _ = POSTERIORS[name]
    off = Controller(posterior, BINS, WARNING.samples, 0.1, 8.0, SEQUENTIAL)
    on = WarningController(posterior, BINS, RULE, 0.1, 8.0, 15.0)
    recorded, decided = decisions(off, frame, 30), decisions(on, frame, 30)
    for a, b in zip(recorded, decided):
        assert (a.decision, a.settled) == (b.decision, b.settled)
        assert a.mi_stages[: len(b.mi_stages)] == b.mi_stages and a.mi_stages[-1][0] == WARNING.samples
        assert len(a.eta2_counts) == len(RULE.looks) and a.eta2_counts[: len(b.eta2_counts)] == b.eta2_counts
    counts, stages = np.array([f.eta2_counts for f in recorded]), stage_array(recorded)
    assert RULE.tier.tiers(counts).tolist() == [f.tier for f in decided]
    levels = [int(levels_of(f.tier, f.mutual_information, WARNING.tau)) for f in decided]
    assert RULE.levels(counts, stages).tolist() == levels
    assert abs(counts[:, -1].mean() / WARNING.samples - posterior.eta2()) < WARNING.theta
    grid = [RULE.with_thresholds(d, d - 0.05, 0.3) for d in np.linspace(0.5, 0.95, 10)]
    assert len(np.unique([r.levels(counts, stages) for r in grid])) > 1  # the candidates tell the frames apart


def test_split_posteriors_reach_the_cap_and_take_the_mode_of_all_its_draws(frame):
    posterior, _ = POSTERIORS["split"]
    controller = Controller(posterior, BINS, WARNING.samples, 0.1, 8.0, UNRECORDED)
    frames = decisions(controller, frame, 20)
    unsettled = [f for f in frames if not f.settled]
    assert unsettled and all(f.draws == WARNING.samples for f in unsettled)


@pytest.mark.parametrize("name", ["confident", "mostly agreeing", "split"])
def test_sequential_and_fixed_draws_agree_on_class_and_warning_level(frame, name):
    posterior, _ = POSTERIORS[name]
    levels = {}
    for scheme in ("fixed", "sequential"):
        controller = WarningController(posterior, BINS, WarningRule(WARNING, DrawSettings(scheme)), 0.1, 8.0, 15.0)
        commands = []
        for seed in range(30):
            controller.reset(seed)
            commands.append(controller.act(frame, {}))
        levels[scheme] = [(c.steer, c.warning) for c in commands]
    agree = np.mean([a == b for a, b in zip(levels["fixed"], levels["sequential"])])
    assert agree >= 0.9 if name == "split" else agree == 1.0


def test_a_policy_s_warning_rule_draws_as_the_policy_does_and_its_tier_rule_is_within_gamma(random_models):
    """Warnings on and off differ only by the warnings: a policy's rule must have the policy's draw settings.
    Thresholds of 0 and 1 have sequential rules (the calibration may choose them); a rule whose exact tier error
    exceeds γ is refused before any rollout, naming its settings."""
    path = str(random_models["vi"])
    with pytest.raises(ValueError, match=r"a controller with warnings must have samples=738 .* the rule's"):
        ControllerSpec(8.0, path, "vi", BINS, 738, 0.1, warnings=RULE)  # the policy's draws: fixed
    edge = WarningRule(WarningConfig(delta1=1.0, delta2=0.0), SEQUENTIAL)
    assert ControllerSpec(8.0, path, "vi", BINS, 738, 0.1, warnings=edge, draws=SEQUENTIAL).warnings is edge
    loose = DrawSettings("sequential", theta=0.1, gamma=0.3, look=1)  # looks 3, 6, …, 48, 67
    with pytest.raises(ConfigError) as err:
        WarningRule(WarningConfig(delta1=0.6, delta2=0.4, theta=0.2, gamma=0.01), loose)
    assert str(err.value).startswith("warning.delta1=0.6, warning.delta2=0.4: sequential tier rule delta1=0.6, ")
    assert "exact wrong-tier error is 0." in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"scheme": "adaptive"}, "draws.scheme='adaptive': input should be 'fixed' or 'sequential'"),
        ({"theta": 0.0}, "draws.theta=0.0: input should be greater than 0"),
        ({"look": 0}, "draws.look=0: input should be greater than or equal to 1"),
        ({"unacted": "drop"}, "draws.unacted='drop': input should be 'record' or 'skip'"),
        ({"gama": 0.1}, "draws.gama: unknown key; did you mean 'gamma'?"),
    ],
)
def test_bad_draw_settings_are_one_line_naming_key_value_and_what_is_allowed(values, message):
    from uqdrive.schema import validate

    with pytest.raises(ConfigError) as err:
        validate(DrawSettings, values, "draws")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def first_action(rule: WarningRule, levels: np.ndarray) -> int:
    """The first frame whose level's action changes the command (a slow-down or a hand-over), else the frame count."""
    acts = [rule.config.actions[level].speed < 1 or rule.config.actions[level].handover for level in (0, 1, 2)]
    changing = [i for i, level in enumerate(levels) if level >= 0 and acts[level]]
    return changing[0] if changing else len(levels)


def test_warnings_off_and_on_drive_identically_until_a_warning_first_changes_a_command(random_models):
    """One draw scheme with warnings off and on: on the same seed a warning controller sees the same frames, takes
    the same π(o) and reads the same streams as the warnings-off controller, raising the levels its rule gives on the
    warnings-off record, until its first action changes a command (from there the path may differ). Rules that
    act mid-run (MI above τ; η2's middle tier) and one that never fires (the whole rollout is the same)."""
    posterior = load_posterior(random_models["vi"])
    draws = DrawSettings("sequential", theta=0.1, gamma=0.1)  # cap 185 (chernoff_n(0.1, 0.05))
    world = Condition(ScenarioConfig.from_yaml(CONF / "scenario" / "obstacle.yaml"), WEATHER, 0.05)
    never = {"delta1": 0.0, "delta2": 0.0, "tau": 10.0}
    configs = [
        {"delta1": 0.35, "delta2": 0.1, "tau": 0.06},
        {"delta1": 0.4, "delta2": 0.1},
        never,
    ]  # random weights' η2
    acted_mid_run = never_acted = 0
    with DrivingEnv(horizon_s=1.5) as env:
        for seed in (11, 12):
            off = run_rollout(env, Controller(posterior, BINS, 185, 0.1, 8.0, draws), seed, world)
            for overrides in configs:
                rule = WarningRule(WarningConfig(theta=0.1, **(never | overrides)), draws)
                on = run_rollout(env, WarningController(posterior, BINS, rule, 0.1, 8.0, 15.0), seed, world)
                levels = rule.levels(off.eta2_counts, off.mi_stages)
                j = first_action(rule, levels)
                assert on.warning[: j + 1].tolist() == levels[: j + 1].tolist()
                assert np.array_equal(on.x[: j + 1], off.x[: j + 1]) and np.array_equal(on.y[: j + 1], off.y[: j + 1])
                assert np.array_equal(on.command_speed[:j], off.command_speed[:j])
                for a, b in zip(on.eta2_counts[: j + 1], off.eta2_counts):
                    assert np.array_equal(a[a >= 0], b[: (a >= 0).sum()])
                if j == off.steps:
                    never_acted += 1
                    assert on.summary() == off.summary() | {"mean_eta2": on.mean_eta2}
                    assert np.array_equal(on.x, off.x) and np.array_equal(on.y, off.y)
                else:
                    acted_mid_run += 0 < j
                    assert on.command_speed[j] < off.command_speed[j]
    assert acted_mid_run >= 2 and never_acted >= 2


@pytest.mark.parametrize("profile", ["quick", "paper"])
def test_the_profiles_deployed_tier_rules_compute_their_exact_error_and_say_if_the_middle_tier_is_owed(
    tmp_path, profile
):
    """The rule the avoid stage deploys on each profile (conf/warning, conf/avoid.yaml's draws, the profile's θ):
    its exact wrong-tier error, recomputed by test_uq_tier's independent DP, is ≤ γ; quick's thresholds lie closer
    than 2θ, so no η2 is owed the middle tier there."""
    cfg = compose_stage(tmp_path, "avoid", f"profile={profile}")
    draws = validate(DrawSettings, OmegaConf.to_container(cfg.avoid.draws, resolve=True), "avoid.draws")
    rule = WarningRule(WarningConfig.from_config(OmegaConf.to_container(cfg.warning, resolve=True)), draws)
    outside, anywhere = wrong_tier_rate(rule.tier, rule.tier.theta)
    print(f"{profile}: {rule.describe()}")
    assert rule.tier.error == pytest.approx(anywhere, abs=1e-9) and outside <= anywhere + 1e-12 <= 0.05 + 1e-12
    assert rule.tier.middle_guaranteed == (profile == "paper")
    assert rule.looks == {"quick": (24, 48, 96, 185), "paper": (24, 48, 96, 192, 384, 738)}[profile]


def test_each_draw_scheme_the_config_names_is_an_object_of_that_name():
    import typing

    from uqdrive.policy.draws import DRAW_SCHEMES

    names = typing.get_args(typing.get_type_hints(DrawSettings)["scheme"])
    assert set(names) == set(DRAW_SCHEMES) and all(DrawSettings(n).method.name == n for n in names)
    assert DrawSettings("fixed").looks(64) == (64,) and DrawSettings("fixed").records(acts_on_warnings=True)
    assert DrawSettings("sequential", look=8).looks(96) == (24, 48, 96)
    assert not DrawSettings("sequential").records(acts_on_warnings=True)
