"""The peer over every η1: episodes PyDSMC's sound method and uqdrive's gate take for a synthetic agent of exact
η1, on a grid 0.5 … 1, at the same question and guarantee ("η1 ≥ eta?", error γ, indifference θ).

uqdrive: the certify test with a look every ``look_size`` episodes up to ``budget``, at the full γ (fixed seeds, no
ledger: what PyDSMC does), its expected episodes exact (`ThresholdTest.operating_characteristics`) and its worst
the most any of ``reps`` simulated runs took. PyDSMC: its own property object (`create_custom_property`, binomial,
``sound=True``: Clopper–Pearson at confidence 1 − γ to half-width θ) fed the same simulated episodes in runs of
``look_size`` until `converged()`, as its evaluator does; expected the mean over the runs, worst the most.
A ratio is PyDSMC's episodes over uqdrive's: ``ratio_*`` of expected episodes over the grid (min, median, at
η1 = eta), ``worst_ratio_*`` of the worst runs.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

GRID = tuple(np.round(np.linspace(0.5, 1.0, 21), 3))


@dataclass(frozen=True)
class GridPoint:
    """One true η1: each tool's expected and worst episodes."""

    eta1: float
    uqdrive_mean: float
    uqdrive_worst: int
    pydsmc_mean: float
    pydsmc_worst: int


def pydsmc_episodes(draws: np.ndarray, theta: float, gamma: float, look_size: int) -> int:
    """Episodes PyDSMC's sound binomial property takes on these outcomes (runs of ``look_size``)."""
    import pydsmc

    logging.getLogger("pydsmc.utils").setLevel(logging.ERROR)  # its "sound: will take long" warning, per property
    prop = pydsmc.create_custom_property(
        "safe", lambda *_: 0.0, epsilon=theta, kappa=gamma, bounds=(0, 1), binomial=True, sound=True
    )
    used = 0
    while not prop.converged():
        if used + look_size > draws.size:
            raise ValueError(f"PyDSMC did not converge within {draws.size} episodes")
        prop.add_samples(draws[used : used + look_size].tolist())
        used += look_size
    return used


def grid_point(eta1: float, args, test, rng: np.random.Generator) -> GridPoint:
    """``reps`` runs of Bernoulli(η1) episodes through both tools; uqdrive's mean exact."""
    limit = max(args.pydsmc_limit, test.looks[-1])
    ours, theirs = [], []
    for _ in range(args.reps):
        draws = (rng.random(limit) < eta1).astype(int)
        ours.append(_run(test, draws))
        theirs.append(pydsmc_episodes(draws, args.theta, args.gamma, args.look_size))
    mean = float(test.operating_characteristics(eta1)[2][0])
    return GridPoint(float(eta1), mean, max(ours), float(np.mean(theirs)), max(theirs))


def _run(test, draws: np.ndarray) -> int:
    """Episodes the test reads from ``draws`` (in order) before it stops."""
    position = [0]

    def draw(m: int) -> np.ndarray:
        start = position[0]
        position[0] += m
        return draws[start : start + m]

    return test.run(draw).n


def grid(args) -> list[GridPoint]:
    from uqdrive.uq import ThresholdTest
    from uqdrive.uq.gate import looks_for

    test = ThresholdTest(args.eta, args.gamma, looks_for(args.look_size, args.budget), theta=args.theta, forced=False)
    rng = np.random.default_rng(args.seed)
    return [grid_point(eta1, args, test, rng) for eta1 in GRID]


def report(points: list[GridPoint], eta: float) -> str:
    """The table and the RESULT line."""
    lines = ["  eta1  uqdrive E[n]  worst  PyDSMC E[n]  worst  ratio  worst_ratio"]
    ratios, worst = [], []
    for p in points:
        ratios.append(p.pydsmc_mean / p.uqdrive_mean)
        worst.append(p.pydsmc_worst / p.uqdrive_worst)
        lines.append(
            f"  {p.eta1:.3f}  {p.uqdrive_mean:12.1f}  {p.uqdrive_worst:5d}  {p.pydsmc_mean:11.1f}  "
            f"{p.pydsmc_worst:5d}  {ratios[-1]:5.2f}  {worst[-1]:11.2f}"
        )
    at = min(range(len(points)), key=lambda i: abs(points[i].eta1 - eta))
    lines.append(
        f"RESULT peer ratio_min={min(ratios):.2f} ratio_median={np.median(ratios):.2f} "
        f"ratio_at_target={ratios[at]:.2f} worst_ratio_min={min(worst):.2f} "
        f"worst_ratio_median={np.median(worst):.2f} grid={len(points)}"
    )
    return "\n".join(lines)
