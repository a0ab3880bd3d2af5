"""Rollouts in lockstep: a rollout's result does not depend on which rollouts share its batch, nor on the
lockstep width or the worker count (the same seeds alone and batched give the same outcomes and traces)."""

import dataclasses

import numpy as np
import pytest
import torch
from conftest import CONF

from uqdrive.bench.posterior_bench import random_posteriors
from uqdrive.data.binning import SteeringBins
from uqdrive.envelope.sources import UniformIn
from uqdrive.envelope.space import Axis, AxisSettings, ConditionSpace
from uqdrive.models import load_posterior
from uqdrive.policy.controller import Controller
from uqdrive.policy.draws import DrawSettings
from uqdrive.policy.recipes import ControllerSpec
from uqdrive.policy.warnings import WarningConfig, WarningController, WarningRule
from uqdrive.safety import executors
from uqdrive.safety.executors import RolloutJob, RolloutWorker, lockstep_chunks, make_executor
from uqdrive.safety.rollout import run_rollout, run_rollouts
from uqdrive.schema import ConfigError, validate
from uqdrive.sim import DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition

TRACES = (
    "x",
    "y",
    "eta2",
    "mutual_information",
    "warning",
    "command_speed",
    "draws",
    "mutual_information_se",
    "eta2_counts",
    "mi_stages",
)


def assert_same_rollouts(a: list, b: list) -> None:
    assert [repr(r.summary()) for r in a] == [repr(r.summary()) for r in b]  # repr: NaN (no η2 drawn) equals NaN
    for ra, rb in zip(a, b):
        for key in TRACES:
            assert np.array_equal(getattr(ra, key), getattr(rb, key), equal_nan=True), key


@pytest.mark.parametrize("method", ["mcd", "vi", "hmc", "ensemble", "laplace"])
def test_each_frames_features_are_those_of_the_frame_alone_in_any_batch(method):
    posterior = random_posteriors(torch.Generator().manual_seed(0))[method]
    frames = torch.rand((12, 1, 48, 64), generator=torch.Generator().manual_seed(1))
    alone = torch.cat([posterior.features_each(frames[i : i + 1]) for i in range(len(frames))])
    for size in (2, 3, 5, 8, 12):
        assert torch.equal(posterior.features_each(frames[:size]), alone[:size])
    order = torch.randperm(len(frames), generator=torch.Generator().manual_seed(2))
    assert torch.equal(posterior.features_each(frames[order]), alone[order])
    assert torch.allclose(alone, posterior.features(frames), atol=1e-5)  # the trunk's features within rounding


@pytest.mark.parametrize("method", ["mcd", "vi", "hmc", "ensemble", "laplace"])
def test_each_frames_head_draws_are_those_of_the_frame_alone_in_any_batch(method):
    """One head call for every lockstep frame (`head_probs_each`), each frame drawing from its own generator: its
    draws are bit for bit those of the frame alone, at a few draws (HMC: a gathered subset of its store) and at
    more draws than the store holds; and they are `head_probs`'s draws of the frame, within rounding."""
    posterior = random_posteriors(torch.Generator().manual_seed(0))[method]
    features = posterior.features_each(torch.rand((8, 1, 48, 64), generator=torch.Generator().manual_seed(1)))

    def generators(seeds) -> list:
        return [torch.Generator().manual_seed(int(seed)) for seed in seeds]

    for n in (16, 40, 1476):
        alone = torch.cat([posterior.head_probs_each(features[i : i + 1], n, generators([i])) for i in range(8)])
        assert alone.shape == (8, n, 21)
        for size in (3, 8):
            assert torch.equal(posterior.head_probs_each(features[:size], n, generators(range(size))), alone[:size])
        order = torch.randperm(8, generator=torch.Generator().manual_seed(2))
        assert torch.equal(posterior.head_probs_each(features[order], n, generators(order)), alone[order])
        single = torch.cat(
            [posterior.head_probs(features[i : i + 1], n, g) for i, g in enumerate(generators(range(8)))], 1
        )
        torch.testing.assert_close(alone, single.transpose(0, 1), rtol=0, atol=1e-6)


@pytest.fixture(scope="module")
def rain():
    return ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml"), WeatherConfig.from_yaml(
        CONF / "weather" / "rain.yaml"
    )


def controllers(model_path) -> dict:
    bins = SteeringBins()
    posterior = load_posterior(model_path, expected_method="vi", expected_classes=bins)
    warning = WarningConfig(theta=0.3, delta1=0.45, delta2=0.12, tau=0.03)  # every level fires on random weights
    sequential = DrawSettings("sequential", theta=0.3, gamma=0.1, unacted="skip")
    # sequential tiers test each threshold ±θ: zones that reach 0 would never say "doubtful" on random weights' η2
    tiered = WarningRule(
        WarningConfig(theta=0.2, delta1=0.5, delta2=0.3, tau=0.03), dataclasses.replace(sequential, theta=0.15)
    )
    return {
        "plain": Controller(posterior, bins, 20, 0.1, 6.0),
        "warnings": WarningController(posterior, bins, WarningRule(warning, DrawSettings()), 0.1, 6.0, 15.0),
        "plain, sequential": Controller(posterior, bins, 40, 0.1, 6.0, sequential),
        "plain, recorded": Controller(posterior, bins, 40, 0.1, 6.0, dataclasses.replace(sequential, unacted="record")),
        "warnings, sequential": WarningController(posterior, bins, tiered, 0.1, 6.0, 15.0),
    }


@pytest.mark.parametrize("kind", ["plain", "warnings", "plain, sequential", "plain, recorded", "warnings, sequential"])
def test_rollouts_in_lockstep_are_the_rollouts_alone(random_models, rain, kind):
    """Five seeds, three slots: slots refill as rollouts end, and each frame batch mixes different rollouts."""
    seeds = [31, 32, 33, 34, 35]
    with DrivingEnv(horizon_s=1.5) as env:
        alone = [
            run_rollout(env, controllers(random_models["vi"])[kind], seed, Condition(*rain, 0.05)) for seed in seeds
        ]
    envs = [DrivingEnv(horizon_s=1.5) for _ in range(3)]
    try:
        batched = run_rollouts(
            envs, controllers(random_models["vi"])[kind], seeds, [Condition(*rain, 0.05)] * len(seeds)
        )
    finally:
        for env in envs:
            env.close()
    assert [r.seed for r in batched] == seeds
    assert len({r.steps for r in alone}) > 1  # rollouts end at different steps: slots refill mid-batch
    assert_same_rollouts(alone, batched)
    assert all(np.isfinite(r.mutual_information_se).all() for r in alone)  # the MI's precision is recorded
    if kind.startswith("warnings"):
        assert {1, 2} <= set(np.concatenate([r.warning for r in alone]).tolist())


def test_executors_give_the_same_rollouts_at_any_lockstep_width(random_models, rain):
    spec = ControllerSpec(6.0, str(random_models["vi"]), "vi", SteeringBins(), samples=10, eps=0.1)
    job = RolloutJob(spec, Condition(*rain, 0.05), base_seed=700, horizon_s=1.0)
    runs = []
    for lockstep in (1, 4):
        executor = make_executor("process", job, 1, lockstep=lockstep)
        try:
            runs.append(list(executor.run(range(2, 7))))
        finally:
            executor.close()
    assert [r.seed for r in runs[0]] == list(range(702, 707))
    assert_same_rollouts(*runs)


def test_chunks_keep_the_order_and_feed_every_worker():
    assert lockstep_chunks(list(range(4)), 2, 8) == [(0, 1), (2, 3)]  # a sequential look of 4 on 2 workers
    assert lockstep_chunks(list(range(19)), 2, 8) == [tuple(range(10)), tuple(range(10, 19))]
    chunks = lockstep_chunks(list(range(738)), 2, 8)
    assert {len(c) for c in chunks[:-1]} == {32} and sum(chunks, ()) == tuple(range(738))
    assert lockstep_chunks([5], 3, 8) == [(5,)]


@pytest.mark.parametrize("width", [0, 2.5, True])
def test_lockstep_width_must_be_a_positive_integer(random_models, rain, width):
    spec = ControllerSpec(6.0, str(random_models["vi"]), "vi", SteeringBins(), samples=10, eps=0.1)
    with pytest.raises(ConfigError, match=rf"executor.lockstep={width!r}: must be an integer >= 1"):
        make_executor("process", RolloutJob(spec, Condition(*rain, 0.0), base_seed=0), 1, lockstep=width)


def test_a_worker_builds_only_the_envs_its_chunk_needs_and_leaves_them_to_the_next_job(random_models, rain):
    """A sweep's next cell (here another location and weather) takes the envs the last one left; its rollouts are
    those of fresh envs."""
    spec = ControllerSpec(6.0, str(random_models["vi"]), "vi", SteeringBins(), samples=10, eps=0.1)
    first = RolloutJob(spec, Condition(*rain, 0.05), base_seed=0, horizon_s=0.5)
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout_large.yaml")
    fog = WeatherConfig.from_yaml(CONF / "weather" / "fog.yaml")
    second = RolloutJob(spec, Condition(scenario, fog, 0.0), 40, horizon_s=0.5)
    executors._spare_envs.clear()
    fresh = RolloutWorker(second, width=8)
    expected = fresh.run([1, 2, 3])
    executors._spare_envs.clear()  # the fresh worker keeps its envs: the next one builds its own
    worker = RolloutWorker(first, width=8)
    try:
        assert [r.seed for r in worker.run([3, 4])] == [3, 4] and len(worker.slots.envs) == 2
        envs = list(worker.slots.envs)
    finally:
        worker.close()
    reused = RolloutWorker(second, width=8)
    try:
        assert reused.slots.envs == envs
        assert_same_rollouts(reused.run([1, 2, 3]), expected)
    finally:
        reused.close()
        fresh.close()


@pytest.mark.parametrize("axes", [("noise", "weather.blend"), ("noise", "scenario.ring_radius")])
def test_envelope_conditions_in_lockstep_are_the_rollouts_alone(random_models, rain, axes):
    """Each rollout in its own world (noise, weather, a ring's radius): batched, each is what it is alone."""
    ranges = {"noise": (0.0, 0.2), "weather.blend": (0.0, 1.0), "scenario.ring_radius": (10.0, 24.0)}
    space = ConditionSpace(
        tuple(Axis.of(validate(AxisSettings, {"key": k, "range": list(ranges[k])})) for k in axes),
        Condition(rain[0], WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml"), 0.0),
        (WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml"), rain[1]) if "weather.blend" in axes else None,
    )
    spec = ControllerSpec(6.0, str(random_models["vi"]), "vi", SteeringBins(), samples=10, eps=0.1)
    job = RolloutJob(spec, UniformIn(space, (0.0, 0.0), (1.0, 1.0)), base_seed=900, horizon_s=1.0)
    worlds = [job.condition(i) for i in range(5)]
    assert len({repr(w) for w in worlds}) == 5
    with DrivingEnv(horizon_s=1.0) as env:
        policy = spec.build(job.control_hz)
        runs = [[run_rollout(env, policy, 900 + i, w) for i, w in enumerate(worlds)]]
    for lockstep in (1, 3):
        executor = make_executor("process", job, 1, lockstep=lockstep)
        try:
            runs.append(list(executor.run(range(5))))
        finally:
            executor.close()
    assert [r.seed for r in runs[1]] == list(range(900, 905))
    assert_same_rollouts(runs[0], runs[1])
    assert_same_rollouts(runs[0], runs[2])
