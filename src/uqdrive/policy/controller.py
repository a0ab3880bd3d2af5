"""uqdrive's Bayesian controller: camera frame → steering and speed, one control period at a time.

`Controller` is the paper's Bayesian end-to-end controller: the frame goes through the same
preprocessing the training data went through, then n posterior draws give π(o), η2 and the
mutual information. It implements `uqdrive.policy.interface.Policy` with the lockstep fast path (one trunk pass
for every slot's frame); the reference policies of known safety are in `uqdrive.policy.references`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import to_inputs
from uqdrive.models.posterior import Posterior
from uqdrive.network_input import preprocess_frame
from uqdrive.policy.draws import (
    ETA2_STREAM,
    PI_STREAM,
    Draws,
    DrawSettings,
    Eta2Stream,
    FrameDecision,
    first_draws,
    fixed_frame,
    frame_generator,
    mutual_information_stages,
    sequential_frame,
    settle_mode,
)
from uqdrive.policy.interface import Command, LockstepPolicy
from uqdrive.uq import draw_measures
from uqdrive.uq.tier import CONFIDENT, TierRule


class SlotDraws:
    """A lockstep slot's episode: its seed and the index of its current frame, whose streams (`frame_generator`)
    every draw comes from, so a frame that reads fewer draws changes no other draw."""

    def __init__(self, seed: int):
        self.seed, self.frame = int(seed), -1
        self.pi = torch.Generator().manual_seed(self.seed)  # the fixed draws' one stream per episode

    def next_frame(self) -> None:
        self.frame += 1

    def generator(self, stream: int) -> torch.Generator:
        """The current frame's generator of ``stream`` (`PI_STREAM`, `ETA2_STREAM`)."""
        return frame_generator(self.seed, self.frame, stream)


class Controller(LockstepPolicy):
    """Bayesian end-to-end controller: steer = π(o), the class centre of the predictive's mode.

    Each frame draws weight samples for π(o), the mutual information and the entropy, and separate ones for η2
    around that π(o) (`uqdrive.policy.draws`: 2·``n_samples`` of them with fixed draws, as many as the frame's
    decisions need with sequential ones). With π(o) picked from the draws that also count η2, η̂2 would not be a
    plain binomial mean (π(o) is chosen where the draws agree), and Chernoff's n (or any estimator in
    `uqdrive.uq`) would not apply as stated. Separate draws make η̂2 a binomial mean given π(o), exactly; the
    alternative, a union bound over the 21 class centres, needs ln(2·21/γ)/(2θ²) = 1347 draws (1.8×) at
    θ = γ = 0.05, nearly the same cost, and grows with the class count (`uqdrive bench controller`, budget 10 ms
    per frame).

    Rollouts in lockstep share one trunk pass and one first head call per step (`Posterior.features_each`,
    `Posterior.head_probs_each`: each frame's numbers those of the frame alone), each slot drawing from its own
    generators (`SlotDraws`), seeded by its episode's seed, so a rollout's commands do not depend on the rollouts
    beside it.
    """

    needs_camera = True

    tier: TierRule | None = None
    """The η2 tier rule a frame is decided by (a warning controller's); None: no tier is asked."""
    tau: float | None = None
    """The MI threshold a warning acts on (its MI is drawn on near it); None: MI is only measured."""

    def __init__(
        self,
        posterior: Posterior,
        bins: SteeringBins,
        n_samples: int,
        eps: float,
        speed: float,
        draws: DrawSettings | None = None,
    ):
        self.posterior = posterior.eval()
        self.centres = torch.as_tensor(bins.centres, dtype=torch.float32)
        self.n_samples, self.eps, self.speed = n_samples, float(eps), float(speed)
        self.draws = draws or DrawSettings()
        self.looks = self.draws.looks(n_samples)
        self.slots = {0: SlotDraws(0)}

    def reset(self, seed: int, slot: int = 0, world: Any = None) -> None:
        self.slots[slot] = SlotDraws(seed)

    @torch.inference_mode()  # no autograd bookkeeping on the frame's ~100 small tensor ops
    def act_batch(
        self, slots: Sequence[int], frames: Sequence[np.ndarray | None], infos: Sequence[dict]
    ) -> list[Command]:
        if any(frame is None for frame in frames):
            raise ValueError("Controller needs a camera frame; reset the env with render=True")
        x = to_inputs(
            np.stack([preprocess_frame(frame) for frame in frames])
        )  # exactly what the network was trained on
        return self.commands(slots, self.decide(self.posterior.features_each(x), slots), infos)

    def decide(self, features: torch.Tensor, slots: Sequence[int]) -> list[FrameDecision]:
        """Each frame's decisions from its features (a row of [K, F]) and its slot's draws: the first draws of every
        frame in one head call (`Posterior.head_probs_each`), more for a frame that needs them from that frame
        alone, and every step each frame's own (a reduction over a batch of frames could round differently), so a
        frame's decisions are those it takes alone."""
        episodes = [self.slots[slot] for slot in slots]
        for episode in episodes:
            episode.next_frame()
        return self.draws.method.decide(self, features, episodes)

    def decide_fixed(self, features: torch.Tensor, episodes: list[SlotDraws]) -> list[FrameDecision]:
        """The paper's fixed draws: 2n a frame in one head call (`uqdrive.policy.draws.fixed_frame`)."""
        probs = self.posterior.head_probs_each(features, 2 * self.n_samples, [e.pi for e in episodes])
        return [fixed_frame(p, self.centres, self.eps, self.tier) for p in probs]

    def decide_sequential(self, features: torch.Tensor, episodes: list[SlotDraws]) -> list[FrameDecision]:
        """Sequential draws (`uqdrive.policy.draws`): π(o) settled, then η2's stream read by the tier rule and MI's
        draws made while the controller's τ is undecided, or both streams read to the cap (recorded)."""
        record = self.draws.records(acts_on_warnings=self.tier is not None)
        reads_eta2 = record or (self.tier is not None and self.tier.reads_draws)
        pi = [e.generator(PI_STREAM) for e in episodes]
        eta2 = [e.generator(ETA2_STREAM) for e in episodes] if reads_eta2 else []
        pi_first, eta2_first = self._first_call(features, pi, eta2, first_draws(self.draws, self.n_samples))
        centres, cap = self.centres.numpy(), self.n_samples
        settled = [settle_mode(self._more(features, k, pi), first, cap, self.draws) for k, first in enumerate(pi_first)]
        decisions = [float(centres[choice]) for _, choice, _ in settled]
        streams = [
            Eta2Stream(self._more(features, k, eta2), self.looks, eta2_first[k], centres, decision, self.eps)
            for k, decision in enumerate(decisions)
            if reads_eta2
        ]
        if record:
            return self._recorded(features, {"pi": pi, "eta2": eta2}, settled, decisions, streams)
        frames = []
        for k, (probs, _, done) in enumerate(settled):
            stream = streams[k] if reads_eta2 else None
            level = self.tier.run(stream).tier if self.tier is not None else None
            tau = self.tau if level in (None, CONFIDENT) else None  # warning 0 needs η2's top tier
            stages = mutual_information_stages(self._more(features, k, pi), probs, cap, tau)
            frames.append(sequential_frame(decisions[k], done, stages, stream, level))
        return frames

    def _recorded(
        self,
        features: torch.Tensor,
        generators: dict[str, list[torch.Generator]],
        settled: list[tuple[np.ndarray, int, bool]],
        decisions: list[float],
        streams: list[Eta2Stream],
    ) -> list[FrameDecision]:
        """Both streams of every frame read to the cap, in the chunks a warning controller reads them in: η2's look
        by look, π(o)'s by MI's doublings (`mutual_information_stages`). Each round draws every frame's next chunk
        of each stream, those of one size in one head call (a frame settled in its first call needs the same sizes
        of both: `DrawSettings.looks`)."""
        cap = self.n_samples
        pi = [probs for probs, _, _ in settled]
        measures = [draw_measures(probs) for probs in pi]
        stages = [[(len(probs), *m[:2])] for probs, m in zip(pi, measures)]
        while asks := [
            (size, k, name)
            for k, stream in enumerate(streams)
            for name, size in (("eta2", stream.next_chunk()), ("pi", min(len(pi[k]), cap - len(pi[k]))))
            if size
        ]:
            for size in sorted({size for size, _, _ in asks}):
                batch = [(k, name) for n, k, name in asks if n == size]
                rows, gens = [k for k, _ in batch], [generators[name][k] for k, name in batch]
                for (k, name), probs in zip(batch, self.posterior.head_probs_each(features[rows], size, gens).numpy()):
                    if name == "eta2":
                        streams[k].extend(probs)
                        continue
                    pi[k] = np.concatenate([pi[k], probs])
                    measures[k] = draw_measures(pi[k])
                    stages[k].append((len(pi[k]), *measures[k][:2]))
        for stream in streams:
            stream(cap - stream.served)
        return [
            sequential_frame(decisions[k], done, (cap, tuple(stages[k]), measures[k][2]), streams[k], None)
            for k, (_, _, done) in enumerate(settled)
        ]

    def _first_call(
        self, features: torch.Tensor, pi: list[torch.Generator], eta2: list[torch.Generator], size: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every frame's first ``size`` draws of each stream [K, size, C] in one head call (each frame twice: with its
        π(o) generator, and with its η2 one where η2 is drawn; no η2 draws otherwise)."""
        frames = len(features)
        if not eta2:
            return self.posterior.head_probs_each(features, size, pi).numpy(), np.zeros((frames, 0, 1), np.float32)
        both = self.posterior.head_probs_each(torch.cat([features, features]), size, [*pi, *eta2]).numpy()
        return both[:frames], both[frames:]

    def _more(self, features: torch.Tensor, k: int, generators: list[torch.Generator]) -> Draws:
        """``draw(m)``: m more draws [m, C] of frame ``k`` from its generator in ``generators``."""
        return lambda m: self.posterior.head_probs_each(features[k : k + 1], m, [generators[k]])[0].numpy()

    def commands(self, slots: Sequence[int], frames: Sequence[FrameDecision], infos: Sequence[dict]) -> list[Command]:
        """Steer at π(o), at the cruise speed."""
        return [
            Command(
                f.decision,
                self.speed,
                eta2=f.eta2,
                mutual_information=f.mutual_information,
                entropy=f.entropy,
                draw_count=f.draws,
                mutual_information_se=f.mutual_information_se,
                eta2_counts=f.eta2_counts,
                mi_stages=f.mi_stages,
            )
            for f in frames
        ]
