"""The certify gate's ledger: every attempt to certify a policy name, so that running the gate again and again
(a CI job on every commit) stays honest.

An attempt is a policy's digest in a world at the test's settings. The same attempt submitted again replays it:
the same seeds, the same γ_k, the same verdict (its rollouts come back from the log). Anything else — a changed
policy, or the same one at other settings — is the name's next attempt k: seeds from a block no earlier attempt
of the name used (``SEED_BLOCK`` apart, from the config's ``base_seed``) and error γ_k = 6γ / (π² k²)
(`uqdrive.uq.gate.attempt_gamma`), so that P(some attempt ever certifies a policy whose η1 < η − θ) ≤ Σ γ_k = γ
whatever is resubmitted. An attempt is
written before its first rollout, so an interrupted one still counts (and resumes when resubmitted).

The file is JSON in the run's folder; one that is not a ledger (corrupt, another tool's, another version) is
refused in one line and left as it is.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

from uqdrive.files import write_json
from uqdrive.schema import ConfigError

FORMAT = "uqdrive certify ledger"
VERSION = 1
SEED_BLOCK = 1_000_000  # attempt k of a name draws seeds base + (k − 1)·SEED_BLOCK + 0, 1, …: budgets stay below it
RULE = "gamma_k = 6 gamma / (pi^2 k^2)"


@dataclasses.dataclass(frozen=True)
class Attempt:
    """Attempt ``number`` (1, 2, …) of a policy name: what it tested (``identity``: digest, world and settings),
    its seeds' start, the error it spends and its verdict ("running" until decided)."""

    number: int
    identity: str
    digest: str
    seed_base: int
    gamma: float
    verdict: str = "running"


class Ledger:
    """The attempts per policy name kept at ``path`` (read on construction: a bad file raises `ConfigError`)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.names: dict[str, list[Attempt]] = self._read()

    def _read(self) -> dict[str, list[Attempt]]:
        if not self.path.exists():
            return {}
        try:
            data = json.loads(self.path.read_text())
            if not isinstance(data, dict) or data.get("format") != FORMAT:
                raise ValueError(f"not a {FORMAT!r} file (its 'format' is {_format(data)!r})")
            if data.get("version") != VERSION:
                raise ValueError(f"version {data.get('version')!r}, this uqdrive reads {VERSION}")
            return {name: [Attempt(**a) for a in attempts] for name, attempts in data["policies"].items()}
        except (ValueError, TypeError, KeyError, AttributeError) as err:
            raise ConfigError(
                f"ledger {self.path}: {str(err).splitlines()[0]}; left as it is — move it aside or give another "
                "--out-dir (a fresh ledger restarts the error spending: the gate's guarantee then holds only from it)"
            ) from None

    def attempt(
        self,
        name: str,
        identity: str,
        digest: str,
        gamma: float,
        base_seed: int = 0,
        fresh: bool = False,
        check: Callable[[float], object] | None = None,
    ) -> Attempt:
        """The attempt this submission is: an earlier one with the same ``identity`` (unless ``fresh``), else the
        name's next, reserved in the file before it runs — after ``check(γ_k)``, which may refuse it (raise), so a
        refused submission spends no attempt. Attempt k's seeds start at base_seed + (k − 1)·SEED_BLOCK, or past
        every earlier attempt's block where that would overlap one."""
        from uqdrive.uq.gate import attempt_gamma

        earlier = self.names.get(name, [])
        same = [a for a in earlier if a.identity == identity]
        if same and not fresh:
            if check is not None:
                check(same[-1].gamma)
            return same[-1]
        number = len(earlier) + 1
        start = base_seed + (number - 1) * SEED_BLOCK
        if any(abs(start - a.seed_base) < SEED_BLOCK for a in earlier):
            start = max(a.seed_base for a in earlier) + SEED_BLOCK
        new = Attempt(number, identity, digest, start, attempt_gamma(gamma, number))
        if check is not None:
            check(new.gamma)
        self.names[name] = [*earlier, new]
        self._write()
        return new

    def decided(self, name: str, attempt: Attempt, verdict: str) -> None:
        """Write the attempt's verdict."""
        self.names[name] = [dataclasses.replace(a, verdict=verdict) if a == attempt else a for a in self.names[name]]
        self._write()

    def _write(self) -> None:
        policies = {name: [dataclasses.asdict(a) for a in attempts] for name, attempts in self.names.items()}
        write_json(self.path, {"format": FORMAT, "version": VERSION, "rule": RULE, "policies": policies})


def _format(data: object) -> object:
    return data.get("format") if isinstance(data, dict) else type(data).__name__
