"""Replicates trained as one stacked batch (`Posterior.fit_replicates`) are the runs each seed trains alone: the same
initialisation, data order and noise bit for bit, the same weights up to float rounding, models that load unchanged,
and (slow) validation accuracies within the lone runs' seed-to-seed spread."""

from pathlib import Path

import numpy as np
import pytest
import torch

import uqdrive.models.heads
import uqdrive.models.mcd
import uqdrive.models.stacking
import uqdrive.models.vi
from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet
from uqdrive.data.synthetic import synthetic_road_frames
from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.models.ensemble import EnsemblePosterior, EnsembleSettings
from uqdrive.models.hmc import HMCPosterior, HMCSettings
from uqdrive.models.laplace import LaplacePosterior, LaplaceSettings
from uqdrive.models.mcd import MCDPosterior, MCDSettings
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.training import TrainingData
from uqdrive.models.vi import VIPosterior, VISettings

SMALL = Architecture(conv=(4, 4, 4, 4, 4), features=8, hidden=(8, 6, 6))
BINS = SteeringBins(per_unit=10, low=-0.6, high=0.6)
SEEDS = (0, 1, 2)
SETTINGS = {
    "mcd": MCDSettings(epochs=2, batch_size=16, lr=1e-3),
    "vi": VISettings(epochs=2, batch_size=16, lr=1e-3),
    "ensemble": EnsembleSettings(members=2, epochs=2, batch_size=16, lr=1e-3),
    "laplace": LaplaceSettings(epochs=2, batch_size=16, lr=1e-3),
    "hmc": HMCSettings(chains=4, samples=4, warmup=4, bayesian_layers=1, map_epochs=1),
}
CLASSES = {"mcd": MCDPosterior, "vi": VIPosterior, "ensemble": EnsemblePosterior, "laplace": LaplacePosterior}
CLASSES["hmc"] = HMCPosterior


def road_split(count: int, seed: int) -> FrameSet:
    images, steer = synthetic_road_frames(count, np.random.default_rng(seed))
    return FrameSet(torch.from_numpy(images), torch.from_numpy(BINS.to_class(steer)), BINS.num_classes)


@pytest.fixture(scope="module")
def problem(tmp_path_factory) -> tuple[FrameSet, FrameSet, Path]:
    """Small road frames and, per seed, a small MCD model trained on them (the heads' trunks)."""
    folder = tmp_path_factory.mktemp("bases")
    train, val = road_split(56, 1), road_split(24, 2)
    for fitted, seed in zip(fit("mcd", SEEDS, (train, val, folder)), SEEDS):
        save_posterior(fitted.posterior, folder / f"seed{seed}.pt")
    return train, val, folder


def fit(method: str, seeds: tuple[int, ...], problem: tuple[FrameSet, FrameSet, Path]):
    """``method``'s replicates ``seeds`` as one batch; returns their fits and generators."""
    train, val, folder = problem
    data = [TrainingData(train, val, BINS, SMALL, folder / f"seed{s}.pt", eval_samples=3) for s in seeds]
    generators = [torch.Generator().manual_seed(s) for s in seeds]
    fits = CLASSES[method].fit_replicates(SETTINGS[method], data, generators)
    for fitted, generator, d in zip(fits, generators, data):
        fitted.extra["generator_state"] = generator.get_state()
        fitted.extra["features"] = [vars(d)[k] for k in ("train_features", "val_features") if k in vars(d)]
    return fits


@pytest.fixture
def draws(monkeypatch) -> list[torch.Tensor]:
    """Every stacked draw (`per_replicate`: data orders, dropout uniforms, VI's normals) and every stack of initial
    parameters (`stack_parameters`), in call order."""
    log: list[torch.Tensor] = []
    per_replicate, stack_parameters = uqdrive.models.stacking.per_replicate, uqdrive.models.stacking.stack_parameters

    def recorded_draws(generators, draw):
        log.append(per_replicate(generators, draw).clone())
        return log[-1]

    def recorded_stack(modules):
        stacked = stack_parameters(modules)
        log.extend(p.detach().clone() for p in stacked.values())
        return stacked

    for module in (uqdrive.models.stacking, uqdrive.models.mcd, uqdrive.models.vi, uqdrive.models.heads):
        monkeypatch.setattr(module, "per_replicate", recorded_draws, raising=False)
    for module in (uqdrive.models.mcd, uqdrive.models.vi):
        monkeypatch.setattr(module, "stack_parameters", recorded_stack)
    return log


@pytest.mark.parametrize("method", ["mcd", "vi", "ensemble", "laplace", "hmc"])
def test_each_stacked_replicate_draws_and_learns_what_its_lone_run_does(problem, draws, method):
    """Initialisation, data order and noise bit for bit (every draw, and the generator's state after the fit: no
    replicate drew a number more or less than alone); the trunk features and weights equal up to the rounding of
    batched kernels; HMC, whose chains amplify that rounding, bit for bit given the stacked features."""
    lone = []
    for seed in SEEDS:
        draws.clear()
        lone.append((fit(method, (seed,), problem)[0], list(draws)))
    draws.clear()
    stacked = fit(method, SEEDS, problem)
    if method == "hmc":  # not stacked (`HMCPosterior.fit_replicates`): the replicates' lone fits in turn
        expected = [draw for _, alone_draws in lone for draw in alone_draws]
        assert len(draws) == len(expected) and all(map(torch.equal, draws, expected))
    for r, (alone, alone_draws) in enumerate(lone):
        if method != "hmc":
            assert len(draws) == len(alone_draws)
            assert all(torch.equal(both[r], one[0]) for both, one in zip(draws, alone_draws)), f"replicate {r}"
        assert torch.equal(stacked[r].extra["generator_state"], alone.extra["generator_state"])
        for both, one in zip(stacked[r].extra["features"], alone.extra["features"]):
            torch.testing.assert_close(both, one, rtol=1e-3, atol=1e-4)
        state, alone_state = stacked[r].posterior.state_dict(), alone.posterior.state_dict()
        if method == "hmc":  # its chains amplify the features' rounding: given the same features, the same samples
            alone_state = refit_hmc_on(*stacked[r].extra["features"], SEEDS[r], problem).posterior.state_dict()
        tolerance = {"rtol": 0, "atol": 0} if method == "hmc" else {"rtol": 1e-3, "atol": 1e-4}
        for key in state:
            torch.testing.assert_close(state[key], alone_state[key], **tolerance, msg=f"{r} {key}")


def refit_hmc_on(train_features: torch.Tensor, val_features: torch.Tensor, seed: int, problem):
    """Replicate ``seed``'s lone HMC fit on the given trunk features (head methods' only input)."""
    train, val, folder = problem
    data = TrainingData(train, val, BINS, SMALL, folder / f"seed{seed}.pt", eval_samples=3)
    data.train_features, data.val_features = train_features, val_features
    return HMCPosterior.fit(SETTINGS["hmc"], data, torch.Generator().manual_seed(seed))


@pytest.mark.parametrize("method", ["mcd", "vi", "ensemble", "laplace", "hmc"])
def test_stacked_replicates_save_models_that_load_unchanged(problem, tmp_path, method):
    x = torch.rand((5, 1, 48, 64), generator=torch.Generator().manual_seed(9))
    for seed, fitted in zip(SEEDS, fit(method, SEEDS, problem)):
        path = save_posterior(fitted.posterior, tmp_path / f"seed{seed}.pt")
        loaded = load_posterior(path, expected_method=method, expected_classes=BINS)
        trained = fitted.posterior.eval()
        assert torch.equal(
            loaded.sample_probs(x, 7, torch.Generator().manual_seed(3)),
            trained.sample_probs(x, 7, torch.Generator().manual_seed(3)),
        )


def test_replicates_stack_only_on_the_same_frames(problem):
    train, val, folder = problem
    data = [TrainingData(train, val, BINS, SMALL, folder / "seed0.pt", 3) for _ in range(2)]
    data[1].val = road_split(24, 2)  # equal frames, but another split object: nothing checks they are equal
    with pytest.raises(ValueError, match="must share their train and validation frames"):
        MCDPosterior.fit_replicates(SETTINGS["mcd"], data, [torch.Generator(), torch.Generator()])


@pytest.mark.slow
def test_stacked_mcd_replicates_validate_within_the_lone_runs_seed_spread():
    """The real network on road frames, 3 seeds: each stacked replicate's validation accuracy lies within the lone
    runs' range widened by its own width (rounding differences grow over training, as another seed's would)."""
    train, val = road_split(480, 1), road_split(160, 2)
    data = [TrainingData(train, val, BINS, Architecture(), Path("unused"), eval_samples=20) for _ in SEEDS]
    settings = MCDSettings(epochs=4, batch_size=16, lr=1e-3)

    def accuracies(groups):
        fits = [
            f
            for g in groups
            for f in MCDPosterior.fit_replicates(
                settings, data[: len(g)], [torch.Generator().manual_seed(s) for s in g]
            )
        ]
        return np.array([f.curve[-1]["val_accuracy"] for f in fits])

    alone, stacked = accuracies([(s,) for s in SEEDS]), accuracies([SEEDS])
    spread = alone.max() - alone.min()
    assert alone.max() > 0.5  # it learned (the majority class is ~0.45)
    assert np.all((stacked >= alone.min() - spread) & (stacked <= alone.max() + spread)), (alone, stacked)
