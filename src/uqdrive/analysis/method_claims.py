"""Method-level answers: claims about posterior families (the mean over training runs), decided across replicates.

Three families, each at family-wise error α on its own (Bonferroni within it; sign test and betting interval,
valid whatever the training runs do, `uqdrive.uq.claims`):

- ``paper``: the paper's comparisons, fixed in advance — offline safety at the training location without noise
  over the sweep's weathers (VI > HMC > MCD, as the paper ranks them), MCD without rain against MCD in rain, and
  per method the warnings (on, and calibrated on fresh seeds) against none in the unknown conditions (the
  paper's VI: 0.00 → 0.90);
- ``exploratory``: every method pair at every condition of both experiments, and the warnings per condition;
- ``margin``: the paper's offline method pairs on each run's margin (`PathVerdict.margin`: the worst signed distance
  to the lane's edge over a run, in lane half-widths), a separate estimand, never η1. Its variance comes almost
  all from runs that leave the lane (their margin is negative and far from 0), so it measures how far failing runs
  go off the road more than how centred safe runs stay; unbounded, so decided by the sign test alone.

A claim reads "A is safer than B". Replicate r gives one paired difference from its cells on its own seeds
(pooled claims concatenate the pairs of their conditions); replicates drive disjoint seeds, so the differences
are independent across replicates.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence

import numpy as np

from uqdrive.analysis import paper
from uqdrive.avoid.results import PAIRS, AvoidCell, AvoidResult, Mode
from uqdrive.records import flattened, record
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.schema import ConfigError
from uqdrive.uq.claims import ClaimResult, MethodClaim, ScoreClaim, decide_claims
from uqdrive.uq.paired import paired_table
from uqdrive.uq.runs_needed import SIMS

PAPER_OFFLINE = (("vi", "hmc"), ("vi", "mcd"), ("hmc", "mcd"))  # the paper's ranking: VI 0.91 > HMC 0.766 > MCD 0.58
RAIN = "rain"


@record
class ClaimRecord:
    """One claim "``a`` is safer than ``b``" (``family``: paper, exploratory or margin) and how it was decided over the
    replicates (``result``: the sign test's runs and interval, the mean difference and its betting interval, the
    verdict and, if undecided, the reason and the runs that would decide it); ``per_replicate``: each replicate's
    difference (``unit``), ``a_rates``, ``b_rates`` its two sides; ``paper``: the paper's numbers."""

    family: str
    experiment: str
    a: str
    b: str
    paper: str | None
    unit: str
    result: ClaimResult = flattened()
    per_replicate: list[float]
    a_rates: list[float]
    b_rates: list[float]
    pairs: int


class _Claim:
    """A claim before it is decided: its sides' cells per replicate (A's and B's lists pair run by run)."""

    def __init__(self, name: str, experiment: str, a: str, b: str, paper_text: str | None, sides: dict):
        self.name, self.experiment, self.a, self.b, self.paper = name, experiment, a, b, paper_text
        self.sides = sides  # replicate → (A cells, B cells), paired position by position

    def outcomes(self, replicate: int) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.sides[replicate]
        return _concat(a, lambda c: c.safe), _concat(b, lambda c: c.safe)

    def margins(self, replicate: int) -> np.ndarray:
        a, b = self.sides[replicate]
        return _concat(a, lambda c: c.margin) - _concat(b, lambda c: c.margin)


def _concat(cells: Sequence[SafetyCell | AvoidCell], values) -> np.ndarray:
    """Each cell's first k runs (k fixed in advance: `fixed_rollouts`), concatenated."""
    k = min(c.fixed_rollouts for c in cells)
    return np.concatenate([np.asarray(values(c))[:k] for c in cells])


def _check_paired(sides: dict) -> None:
    for a, b in sides.values():
        if len(a) != len(b) or any(x.base_seed != y.base_seed for x, y in zip(a, b)):
            raise ValueError("a claim's cells must pair one to one on the same rollout seeds")


def offline_claims(cells: list[SafetyCell], methods: Sequence[str], location: str, noise: float) -> list[_Claim]:
    """The paper's offline comparisons at ``location`` without noise, over every weather of the sweep."""
    by = {(c.method, c.replicate, c.condition): c for c in cells}
    replicates = sorted({c.replicate for c in cells})
    weathers = list(dict.fromkeys(c.weather for c in cells if (c.location, c.noise) == (location, noise)))
    out = []
    for x, y in (p for p in PAPER_OFFLINE if set(p) <= set(methods)):
        sides = {
            r: ([by[x, r, (location, w, noise)] for w in weathers], [by[y, r, (location, w, noise)] for w in weathers])
            for r in replicates
        }
        text = f"{paper.OFFLINE_ALL_WEATHERS[x]:g} vs {paper.OFFLINE_ALL_WEATHERS[y]:g}"
        out.append(_Claim(f"{x} safer than {y} offline", "offline", x, y, text, sides))
    dry = [w for w in weathers if w != RAIN]
    if "mcd" in methods and RAIN in weathers and dry:
        sides = {
            r: ([by["mcd", r, (location, w, noise)] for w in dry], [by["mcd", r, (location, RAIN, noise)]] * len(dry))
            for r in replicates
        }
        # rain's cell pairs with each dry weather's: Δ̂_r is exact; the within-replicate floor counts those pairs
        # as apart, so it binds less (the variance between replicates carries the test)
        text = f"{paper.OFFLINE_WITHOUT_RAIN['mcd']:g} vs {paper.OFFLINE_ALL_WEATHERS['mcd']:g} (with rain)"
        out.append(_Claim("mcd safer without rain than in rain", "offline", "mcd dry", "mcd rain", text, sides))
    return out


def warning_claims(results: list[AvoidResult], methods: Sequence[str], as_paper: bool = True) -> list[_Claim]:
    """Per method, warnings on (and calibrated, on fresh seeds) against none in the unknown conditions; with the
    paper's numbers beside its own claim when ``as_paper`` (the obstacle road's results)."""
    out, experiment = [], results[0].experiment
    for method in methods:
        mine = [r for r in results if r.method == method]
        for with_warnings, without in PAIRS:
            sides = {
                r.replicate: (
                    [r.cell(c, with_warnings) for c in r.conditions[1:]],
                    [r.cell(c, without) for c in r.conditions[1:]],
                )
                for r in mine
            }
            paper_pair = as_paper and (method, with_warnings) == (paper.AVOID_METHOD, Mode.ON)
            text = f"{paper.AVOID_UNKNOWN_ON:g} vs {paper.AVOID_UNKNOWN_OFF:g}" if paper_pair else None
            name = f"{method}: warnings {with_warnings} safer than {without}, unknown conditions"
            out.append(_Claim(name, experiment, f"{method} {with_warnings}", f"{method} {without}", text, sides))
    return out


def exploratory_claims(cells: list[SafetyCell], results: list[AvoidResult], methods: Sequence[str]) -> list[_Claim]:
    """Every method pair at every condition of both experiments; the warnings per method and condition."""
    out = []
    by = {(c.method, c.replicate, c.condition): c for c in cells}
    replicates = sorted({c.replicate for c in cells})
    for condition in dict.fromkeys(c.condition for c in cells):
        label = condition_label(*condition)
        for x, y in itertools.combinations(methods, 2):
            sides = {r: ([by[x, r, condition]], [by[y, r, condition]]) for r in replicates}
            out.append(_Claim(f"{x} vs {y} at {label}", cells[0].experiment, x, y, None, sides))
    avoid = {(r.method, r.replicate): r for r in results}
    experiment = results[0].experiment if results else ""
    for condition in results[0].conditions if results else ():
        for x, y in itertools.combinations(methods, 2):
            sides = {
                r: ([avoid[x, r].cell(condition, Mode.OFF)], [avoid[y, r].cell(condition, Mode.OFF)])
                for m, r in avoid
                if m == x
            }
            out.append(_Claim(f"{x} vs {y} at {condition}, warnings off", experiment, x, y, None, sides))
        for method, (with_warnings, without) in itertools.product(methods, PAIRS):
            sides = {
                r: ([avoid[method, r].cell(condition, with_warnings)], [avoid[method, r].cell(condition, without)])
                for m, r in avoid
                if m == method
            }
            name = f"{method}: warnings {with_warnings} vs {without} at {condition}"
            out.append(_Claim(name, experiment, f"{method} {with_warnings}", f"{method} {without}", None, sides))
    return out


def check_replicates(cells: Iterable[SafetyCell], results: Iterable[AvoidResult], methods: Sequence[str]) -> None:
    """Every method has the same replicates in each experiment, or a claim would pair a replicate with nothing:
    one line naming the method, the replicates it lacks and the experiment (ConfigError), before any claim."""
    for experiment, owned in (("offline safety", cells), ("collision avoidance", results)):
        sets = {m: sorted({x.replicate for x in owned if x.method == m}) for m in methods}
        sets = {m: r for m, r in sets.items() if r}
        union = sorted(set().union(*sets.values())) if sets else []
        for method, replicates in sets.items():
            if replicates != union:
                missing = sorted(set(union) - set(replicates))
                raise ConfigError(
                    f"method claims, {experiment}: replicates {missing} of {union} missing from {method} "
                    f"(it has {replicates}): a claim pairs each replicate of one method with the same of the other"
                )


def _decide(
    family: str, claims: list[_Claim], margin: float, alpha: float, on_margins: bool = False, sims: int = 0
) -> list[ClaimRecord]:
    for claim in claims:
        _check_paired(claim.sides)
    if on_margins:
        scores = [ScoreClaim(_margin_name(c.name), {r: c.margins(r) for r in c.sides}, margin) for c in claims]
        decided = decide_claims(scores, alpha)
    else:
        tables = [{r: paired_table(*c.outcomes(r)) for r in c.sides} for c in claims]
        decided = decide_claims([MethodClaim(c.name, t, margin) for c, t in zip(claims, tables)], alpha, sims)
    return [_record(family, c, d, on_margins) for c, d in zip(claims, decided)]


def _record(family: str, claim: _Claim, decided: ClaimResult, on_margins: bool) -> ClaimRecord:
    sides = [claim.outcomes(r) if not on_margins else _margin_sides(claim, r) for r in claim.sides]
    rates = [float(np.mean(a)) for a, _ in sides], [float(np.mean(b)) for _, b in sides]
    what = (claim.experiment, claim.a, claim.b, None if on_margins else claim.paper)
    return claim_record(family, what, decided, rates, len(sides[0][0]), on_margins)


def claim_record(
    family: str,
    what: tuple[str, str, str, str | None],
    decided: ClaimResult,
    rates: tuple[list[float], list[float]],
    pairs: int,
    on_margins: bool,
) -> ClaimRecord:
    """The record of a decided claim: ``what`` is (experiment, a, b, the paper's numbers); ``rates`` each
    replicate's A and B (η̂1, or mean margin); ``pairs``: paired runs per replicate."""
    experiment, a, b, paper_text = what
    a_rates, b_rates = rates
    return ClaimRecord(
        family=family,
        experiment=experiment,
        a=a,
        b=b,
        paper=paper_text,
        unit="lane half-widths" if on_margins else "η1",
        result=decided,
        per_replicate=[x - y for x, y in zip(a_rates, b_rates)],
        a_rates=a_rates,
        b_rates=b_rates,
        pairs=pairs,
    )


def _margin_name(name: str) -> str:
    """ "vi safer than hmc offline" → "vi keeps a wider margin than hmc offline": never an η1 claim's name."""
    return name.replace(" safer than ", " keeps a wider margin than ")


def _margin_sides(claim: _Claim, replicate: int) -> tuple[np.ndarray, np.ndarray]:
    a, b = claim.sides[replicate]
    return _concat(a, lambda c: c.margin), _concat(b, lambda c: c.margin)


def has_margins(claims: Iterable[_Claim]) -> bool:
    """Whether every run of these claims' cells recorded a margin (cells of an older run, or of a world without a
    lane rule, record none)."""
    margins = [claim.margins(r) for claim in claims for r in claim.sides]
    return all(m.size > 1 and np.isfinite(m).all() for m in margins)


def method_claims(
    cells: list[SafetyCell],
    results: list[AvoidResult],
    methods: Sequence[str],
    training: tuple,
    alpha: float,
    margin: float,
    paper: bool = True,
    sims: int = SIMS,
) -> list[ClaimRecord]:
    """Every family of method claims, each decided at family-wise error ``alpha``; ``margin``: δ of equivalence
    (η1 units; the margin family, unbounded, is never called equivalent). ``paper``: the cells are the paper's
    offline experiment, so its claims are made (not for a Gymnasium world's cells, which only the exploratory family
    compares: there the warnings' claims over the unknown conditions are exploratory too). ``sims``: simulated
    studies per run count for the paper family's runs needed (the other families' are not computed: they are
    counted, not tabled)."""
    check_replicates(cells, results, methods)
    location, _, noise = training
    offline = offline_claims(cells, methods, location, noise) if paper else []
    warnings = warning_claims(results, methods, paper) if results else []
    families = {
        "paper": [*offline, *warnings] if paper else [],
        "exploratory": [*exploratory_claims(cells, results, methods), *([] if paper else warnings)],
    }
    out = [
        record
        for family, claims in families.items()
        if claims
        for record in _decide(family, claims, margin, alpha, sims=sims if family == "paper" else 0)
    ]
    pairs = [c for c in offline if c.a != "mcd dry"]
    if pairs and has_margins(pairs):
        out += _decide("margin", pairs, margin, alpha, on_margins=True)
    return out
