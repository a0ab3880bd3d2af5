"""A method of one's own: a Posterior subclass and a conf/model yaml, nothing else, through train and evaluate.

The toy method (defined here, as a user would in their own package) is the MCD head's deterministic
weights with Gaussian noise of a fixed scale on its last layer. Its yaml lives in a config folder of
the test's own, added to Hydra's search path: no file of the project is touched.
"""

from dataclasses import dataclass

import pytest
import torch
from hydra import compose, initialize_config_dir
from test_evaluate import write_heldout
from test_train import CONF, write_processed
from torch import nn

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.posterior import Fitted, Posterior, check_draws
from uqdrive.models.training import TrainingData, curve_row, evaluate
from uqdrive.pipeline.evaluate_stage import run_evaluate
from uqdrive.pipeline.train_stage import run_train


@dataclass(frozen=True)
class NoisyHeadSettings:
    scale: float = 0.5

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"model.scale={self.scale!r} is invalid: must be > 0")


class NoisyHeadPosterior(Posterior):
    """The MCD head, its last layer's weights perturbed by N(0, scale²) per draw."""

    method = "noisy_head"
    Settings = NoisyHeadSettings

    def __init__(self, arch, bins: SteeringBins, scale: float = 0.5) -> None:
        super().__init__(arch, bins)
        self.scale = scale
        self.head = nn.ModuleList(nn.Linear(i, o) for i, o in arch.head_shapes(bins.num_classes))

    def init_kwargs(self) -> dict:
        return {"scale": self.scale}

    @classmethod
    def fit(cls, settings: NoisyHeadSettings, data: TrainingData, generator, progress=False) -> Fitted:
        post = cls(data.base.arch, data.bins, settings.scale)
        post.trunk.load_state_dict(data.base.trunk.state_dict())
        post.head.load_state_dict(data.base.head.state_dict())
        scores = evaluate(post, data.val_features, data.val.labels, data.eval_samples, generator)
        return Fitted(post, [curve_row(1, 0.0, scores)], {"diagnostics": f"noise scale {settings.scale}"})

    @torch.no_grad()
    def head_probs(self, features, n, generator=None):
        h = features
        for layer in self.head[:-1]:
            h = torch.relu(layer(h))
        last = self.head[-1]
        weights = last.weight.T + self.scale * torch.randn((check_draws(n), *last.weight.T.shape), generator=generator)
        return torch.softmax(torch.matmul(h, weights) + last.bias, -1)


TOY_YAML = f"""# A user's method: nothing else in the project names it.
name: noisy_head
_target_: {__name__}.NoisyHeadPosterior
scale: 0.5
"""


@pytest.mark.slow
def test_a_user_posterior_trains_and_evaluates_through_the_pipeline(tmp_path):
    user_conf = tmp_path / "user_conf"
    (user_conf / "model").mkdir(parents=True)
    (user_conf / "model" / "noisy_head.yaml").write_text(TOY_YAML)
    write_processed(tmp_path / "data/processed/joint/train.parquet", 320, seed=1)
    write_processed(tmp_path / "data/processed/joint/val.parquet", 80, seed=2)
    for weather in ("clear_noon", "rain"):
        write_heldout(tmp_path, weather, 0.0, frames=12)

    def config(stage: str, *overrides: str):
        with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
            return compose(
                stage,
                overrides=[
                    f"paths.root={tmp_path}",
                    "profile=tiny",
                    "progress=false",
                    "experiment=joint",
                    f"hydra.searchpath=[file://{user_conf}]",
                    *overrides,
                ],
            )

    run_train(config("train", "model=mcd"))
    metrics = run_train(config("train", "model=noisy_head", "model.scale=0.3"))
    assert metrics.method == "noisy_head" and metrics.diagnostics == "noise scale 0.3"
    loaded = load_posterior(tmp_path / "models/joint/noisy_head/seed0.pt", expected_method="noisy_head")
    assert isinstance(loaded, NoisyHeadPosterior) and loaded.scale == 0.3
    result = run_evaluate(config("evaluate", "methods=[mcd,noisy_head]", "weathers=[clear_noon,rain]", "noises=[0.0]"))
    cell = result.cell("noisy_head", "rain", 0.0)
    assert cell.frames == 12 and cell.mean_mutual_information > 0
    assert (tmp_path / "plots/evaluate/figures/reliability_noisy_head.png").exists()
    with pytest.raises(ValueError, match="model.scale=0.0 is invalid"):
        run_train(config("train", "model=noisy_head", "model.scale=0.0"))
