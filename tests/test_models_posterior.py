"""The `Posterior` interface shared by every method, and the model files it is saved in."""

import pytest
import torch

from uqdrive.bench.posterior_bench import random_posteriors
from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet, to_inputs
from uqdrive.models.checkpoint import load_posterior, save_posterior
from uqdrive.models.heads import flatten_mcd_head
from uqdrive.models.hmc import HMCPosterior

METHODS = ("mcd", "vi", "hmc", "ensemble", "laplace")


@pytest.fixture(scope="module")
def posteriors():
    return random_posteriors(torch.Generator().manual_seed(0))


@pytest.fixture(scope="module")
def frames():
    return torch.rand((5, 1, 48, 64), generator=torch.Generator().manual_seed(1))


@pytest.mark.parametrize("method", METHODS)
def test_sample_probs_is_n_by_batch_by_classes_and_seeded(posteriors, frames, method):
    post = posteriors[method]
    probs = post.sample_probs(frames, 7, torch.Generator().manual_seed(3))
    assert probs.shape == (7, 5, 21)
    torch.testing.assert_close(probs.sum(-1), torch.ones(7, 5))
    again = post.head_probs(post.features(frames), 7, torch.Generator().manual_seed(3))
    assert torch.equal(probs, again)  # features + head_probs is the same computation, split
    other = post.sample_probs(frames, 7, torch.Generator().manual_seed(4))
    assert not torch.equal(probs, other)  # draws are random (fixed trunk, sampled head)


@pytest.mark.parametrize("method", ("mcd", "hmc", "ensemble"))
def test_a_draw_is_one_network_for_every_frame_of_a_batch(posteriors, frames, method):
    twice = torch.cat([frames[:1], frames[:1]])
    probs = posteriors[method].sample_probs(twice, 50, torch.Generator().manual_seed(0))
    # equal up to float rounding: a batched matmul may block the two rows differently
    torch.testing.assert_close(probs[:, 0], probs[:, 1], atol=1e-6, rtol=0)
    assert probs[:, 0].std(0).max() > 0.01


@pytest.mark.parametrize("method", ("vi", "laplace"))
def test_per_frame_draws_match_in_distribution_across_batch_positions(posteriors, frames, method):
    twice = torch.cat([frames[:1], frames[:1]])
    probs = posteriors[method].sample_probs(twice, 4000, torch.Generator().manual_seed(0))
    torch.testing.assert_close(probs[:, 0].mean(0), probs[:, 1].mean(0), atol=0.01, rtol=0)


def test_hmc_indexes_stored_samples_with_replacement_only_beyond_the_store(posteriors, frames):
    mcd = posteriors["mcd"]
    samples = flatten_mcd_head(mcd) + 0.5 * torch.randn(
        (6, len(flatten_mcd_head(mcd))), generator=torch.Generator().manual_seed(0)
    )
    hmc = HMCPosterior.from_heads(mcd, samples)
    features = hmc.features(frames[:1])
    each = hmc.head_probs(features, 6, torch.Generator().manual_seed(0))[:, 0]
    assert len({tuple(p.tolist()) for p in each}) == 6  # a permutation of the 6 stored samples
    many = hmc.head_probs(features, 40, torch.Generator().manual_seed(0))[:, 0]
    assert len({tuple(p.tolist()) for p in many}) == 6  # 40 draws from 6: repeats


@pytest.mark.parametrize("method", METHODS)
def test_save_then_load_reproduces_the_predictive_distribution_exactly(posteriors, frames, method, tmp_path):
    path = save_posterior(posteriors[method], tmp_path / f"{method}.pt")
    loaded = load_posterior(path, expected_method=method, expected_classes=SteeringBins())
    assert type(loaded) is type(posteriors[method]) and loaded.bins == SteeringBins()
    before = posteriors[method].sample_probs(frames, 30, torch.Generator().manual_seed(9))
    after = loaded.sample_probs(frames, 30, torch.Generator().manual_seed(9))
    assert torch.equal(before, after)
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically, no temporary left


def test_loading_the_wrong_file_fails_clearly(posteriors, tmp_path):
    path = save_posterior(posteriors["vi"], tmp_path / "vi.pt")
    with pytest.raises(ValueError, match="holds a 'vi' model, expected 'mcd'"):
        load_posterior(path, expected_method="mcd")
    with pytest.raises(ValueError, match="predicts 21 classes, expected 11"):
        load_posterior(path, expected_classes=11)
    with pytest.raises(ValueError, match="trained on classes"):
        load_posterior(path, expected_classes=SteeringBins(per_unit=5))
    with pytest.raises(ValueError, match="holds a 'vi' model, expected 'lasso'"):
        load_posterior(path, expected_method="lasso")
    with pytest.raises(ValueError, match="is not a method name"):
        load_posterior(path, expected_method="../vi")
    (tmp_path / "notes.pt").write_text("not a model")
    with pytest.raises(ValueError, match="not a uqdrive model file"):
        load_posterior(tmp_path / "notes.pt")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a uqdrive model file"):
        load_posterior(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError, match="train it first"):
        load_posterior(tmp_path / "missing.pt")


def test_bad_draw_counts_and_inputs_are_rejected(posteriors, frames):
    for n in (0, -3, 2.5):
        with pytest.raises(ValueError, match="must be a positive integer"):
            posteriors["mcd"].sample_probs(frames, n)
    with pytest.raises(ValueError, match=r"expected frames \[B, 1, 48, 64\]"):
        posteriors["vi"].sample_probs(torch.zeros(2, 48, 64), 3)


def test_frame_sets_scale_pixels_and_refuse_empty_or_out_of_range_data():
    images = torch.full((3, 48, 64), 255, dtype=torch.uint8)
    x = to_inputs(images)
    assert x.shape == (3, 1, 48, 64) and x.dtype == torch.float32 and float(x.max()) == 1.0
    with pytest.raises(ValueError, match="0 frames"):
        FrameSet(images[:0], torch.zeros(0, dtype=torch.int64), 21)
    with pytest.raises(ValueError, match="outside the 21 classes"):
        FrameSet(images, torch.tensor([0, 5, 21]), 21)
    batches = list(FrameSet(images, torch.tensor([0, 1, 2]), 21).batches(2, torch.Generator().manual_seed(0)))
    assert [len(y) for _, y in batches] == [2, 1]


def test_ensemble_draws_are_its_members(posteriors, frames):
    ensemble = posteriors["ensemble"]
    features = ensemble.features(frames)
    members = ensemble.stored_probs(features)  # [M, B, C], one network each
    m = len(members)
    draws = ensemble.head_probs(features, 3 * m + 2, torch.Generator().manual_seed(0))
    match = [[torch.allclose(d, member, atol=1e-6) for member in members] for d in draws]
    assert all(sum(row) == 1 for row in match)  # every draw is exactly one member, for every frame at once
    counts = torch.tensor(match).sum(0)
    assert counts.min() == 3 and counts.max() == 4  # cycles through a permutation: each member 3 or 4 times
    few = ensemble.head_probs(features, m, torch.Generator().manual_seed(1))
    torch.testing.assert_close(few.mean(0), members.mean(0))  # n = M draws: the mixture exactly
