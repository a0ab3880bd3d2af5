"""`uqdrive bench sim|posterior|gym_step|train|controller|rollout` run end to end on small sizes and end with their
RESULT line.

Only the output contract is tested here; the speed targets are measured by running the
benchmarks themselves (README), never asserted in timed tests.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from uqdrive.bench.posterior_bench import random_posteriors
from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import save_posterior
from uqdrive.tools.cli import main


@pytest.mark.parametrize(
    ("argv", "pattern"),
    [
        (["sim", "--steps", "30", "--repeats", "1"], r"RESULT sim step_over_render=[\d.]+"),
        (["posterior", "--samples", "50", "--repeats", "2"], r"RESULT posterior worst_ms=[\d.]+ min_speedup=[\d.]+"),
        (
            ["gym_step", "--world", "uqdrive", "--steps", "30", "--repeats", "1"],
            r"RESULT gym_step adapter_over_env=[\d.]+",
        ),
        (  # HighwayEnv's roundabout through the adapter, as the rollout bench names it
            ["rollout", "--env", "highway", "--steps", "30", "--repeats", "1"],
            r"RESULT gym_step adapter_over_env=[\d.]+",
        ),
        (
            "train --replicates 2 --train-frames 32 --val-frames 16 --methods mcd vi --steps 1 --repeats 1 "
            "--override train.mcd.epochs=1 --override arch.conv=[4,4,4,4,4]".split(),
            r"RESULT train batched_speedup=[\d.]+ mcd=[\d.]+ vi=[\d.]+ mcd_step_speedup=[\d.]+ "
            r"replicates_per_min=[\d.]+",
        ),
        (
            ["controller", "--frames", "1", "--methods", "vi"],
            r"RESULT controller controller=(trained|random) worst_ms=[\d.]+ worst_p95_ms=[\d.]+ fixed_worst_ms=[\d.]+ "
            r"min_speedup=[\d.]+ "
            r"median_draws=\d+ recorded_ratio=[\d.]+",
        ),
    ],
)
def test_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str], argv: list[str], pattern: str) -> None:
    assert main(["bench", *argv]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(pattern, last), last


@pytest.mark.slow
@pytest.mark.parametrize("world", ["uqdrive_roundabout", "highway_roundabout"])
def test_the_peer_benchmark_answers_with_both_tools_and_counts_their_episodes(
    capsys: pytest.CaptureFixture, world: str
) -> None:
    """A question both must certify (every 10-step episode of a gentle or no steer is safe): PyDSMC's sound method
    runs its worst-case count for half-width 0.3 (12 episodes), uqdrive's test stops at its first look. In
    HighwayEnv PyDSMC drives the same `GymWorld` (env, hooks, safe set) through `WorldEnv`."""
    pytest.importorskip("pydsmc", reason="PyDSMC is not installed (pip install 'uqdrive[peer]')")
    steer = "0.15" if world == "uqdrive_roundabout" else "0"
    argv = ["--world", world, "--steer", steer, "--horizon", "10", "--eta", "0.5", "--theta", "0.3", "--look-size", "4"]
    assert main(["bench", "peer", *argv]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    pattern = r"RESULT peer episodes_ratio=([\d.]+) pydsmc_episodes=(\d+) uqdrive_episodes=(\d+) (.*)"
    ratio, theirs, ours, verdicts = re.fullmatch(pattern, last).groups()
    assert verdicts == "pydsmc_verdict=certified uqdrive_verdict=certified same_verdict=true"
    assert int(ours) == 4 and int(theirs) >= 8 and float(ratio) == pytest.approx(int(theirs) / int(ours), abs=0.01)


@pytest.mark.slow
def test_rollout_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str]) -> None:
    """Spawns two worker processes (torch and pybullet start-up in each): tens of seconds."""
    argv = ["--samples", "20", "--steps", "15", "--repeats", "1", "--chunks", "4", "--lockstep", "2", "--frames", "1"]
    assert main(["bench", "rollout", *argv]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith("closed loop, 160x120:") for line in out)
    pattern = (
        r"RESULT rollout controller=(trained|random) overhead=[\d.]+ speedup2=[\d.]+ render_speedup=[\d.]+ "
        r"env_speedup=[\d.]+ "
        r"draws_per_frame=[\d.]+ agreement=[\d.]+"
    )
    assert re.fullmatch(pattern, out[-1]), out[-1]


def test_rollout_benchmark_refuses_chunks_that_time_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "rollout", "--chunks", "3"])
    assert "--chunks=3 must be >= 4" in capsys.readouterr().err


def test_unknown_benchmark_is_named_with_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "warp"]) == 2
    assert "unknown benchmark 'warp'; choose one of" in capsys.readouterr().err


@pytest.mark.slow
def test_benchmarks_drive_trained_models_of_an_experiments_class_set(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """--models: the pipeline's models folder; the checkpoints' own class set (here 7 classes), not the default 21;
    the RESULT lines say the controllers were trained ones."""
    bins = SteeringBins(10, -0.3, 0.3)
    for method, posterior in random_posteriors(torch.Generator().manual_seed(0), bins).items():
        for experiment in ("avoid", "offline"):
            save_posterior(posterior, tmp_path / experiment / method / "seed0.pt")
    assert main(["bench", "controller", "--models", str(tmp_path), "--frames", "2"]) == 0
    assert (
        main(
            ["bench", "rollout", "--models", str(tmp_path), "--samples", "20", "--steps", "15"]
            + ["--repeats", "1", "--chunks", "4", "--lockstep", "2", "--frames", "1"]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert re.search(r"^RESULT controller controller=trained ", out, re.M), out[-2000:]
    assert re.search(r"^RESULT rollout controller=trained ", out, re.M), out[-2000:]


def test_rare_benchmark_prints_a_row_per_suite_world_and_its_result_line(capsys: pytest.CaptureFixture[str]) -> None:
    """``--quick``: 20 runs at p = 10⁻³ and 50 at the null boundary per world and method (the suite's coverage at
    size is tests/test_uq_rare_suite.py's); the exact test is computed, not run."""
    from uqdrive.bench.rare_bench import splits
    from uqdrive.bench.rare_suite import suite

    assert main(["bench", "rare", "--quick"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    rows = [line for line in out if re.search(r" (IS|split) +[\d.]+ +[\d.]+ +[\d.]+ +[\d.]+ +[\d.]+ +50 ", line)]
    assert len(rows) == len(suite()) + sum(map(splits, suite())), out
    assert all(world.name in "\n".join(rows) for world in suite())
    pattern = (
        r"RESULT rare saving_min=[\d.]+ saving_median=[\d.]+ coverage_worst=[\d.]+ error_cp_worst=[\d.]+ "
        r"certify_rollouts_at_0=35948 certify_over_floor=1.20"
    )
    assert re.fullmatch(pattern, out[-1]), out[-1]
    with pytest.raises(SystemExit) as bad:
        main(["bench", "rare", "--runs", "0"])
    assert bad.value.code == 2 and "--runs=0 is out of range" in capsys.readouterr().err


def test_the_peer_grid_compares_both_tools_over_every_eta1(capsys: pytest.CaptureFixture[str]) -> None:
    """`bench peer --grid`: the synthetic agent at 21 true η1; PyDSMC's sound method takes its fixed Clopper–Pearson
    sample (the n at which the interval at η̂ = ½ has half-width θ, in whole runs of 4) whatever η1 is; uqdrive's
    expected episodes are exact, and the ratios are read off them."""
    pytest.importorskip("pydsmc", reason="PyDSMC is not installed (pip install 'uqdrive[peer]')")
    from uqdrive.bench.peer_grid import GRID
    from uqdrive.uq import ThresholdTest, clopper_pearson_interval
    from uqdrive.uq.gate import looks_for

    assert main(["bench", "peer", "--grid", "--reps", "2", "--budget", "400"]) == 0
    out = capsys.readouterr().out
    line = out.strip().splitlines()[-1]
    assert re.fullmatch(r"RESULT peer ratio_min=[\d.]+ ratio_median=[\d.]+ ratio_at_target=[\d.]+ "
                        r"worst_ratio_min=[\d.]+ worst_ratio_median=[\d.]+ grid=21", line)  # fmt: skip
    rows = [row.split() for row in out.splitlines() if re.match(r"^\s+[01]\.\d{3}\s", row)]
    assert [float(r[0]) for r in rows] == list(GRID)
    low, high = clopper_pearson_interval(202, 404, 0.05)
    assert high - low <= 0.1 < float(np.subtract(*clopper_pearson_interval(200, 400, 0.05)[::-1]))
    assert {r[3] for r in rows} == {"404.0"}  # PyDSMC: 404 episodes at every η1
    test = ThresholdTest(0.9, 0.05, looks_for(4, 400), theta=0.05, forced=False)
    expected = test.operating_characteristics(np.array(GRID))[2]
    assert np.allclose([float(r[1]) for r in rows], expected, atol=0.05)  # uqdrive's E[n]: exact, as printed
    values = dict(pair.split("=") for pair in line.split()[2:])
    assert float(values["ratio_min"]) == pytest.approx(min(404 / expected), abs=0.01)
    assert float(values["ratio_median"]) == pytest.approx(np.median(404 / expected), abs=0.01)
    assert float(values["ratio_at_target"]) == pytest.approx(404 / expected[GRID.index(0.9)], abs=0.01)


@pytest.mark.slow  # fresh processes: helps, a refusal, a certify run to its first rollout
def test_the_startup_benchmark_prints_its_result_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "startup", "--repeats", "1"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(
        r"RESULT startup help_s=[\d.]+ refuse_s=[\d.]+ first_rollout_s=[\d.]+ uqdrive_help_s=[\d.]+ "
        r"other_help_s=[\d.]+ python_s=[\d.]+ help_over_python=[\d.]+ refuse_over_python=[\d.]+",
        line,
    )


@pytest.mark.slow
def test_the_real_world_rare_benchmark_runs_pilot_monte_carlo_and_the_stage(tmp_path, random_models, capsys) -> None:
    """`bench rare_real` on random-weight controllers, which leave the road: the pilot counts every rollout of its
    fixed size as a failure, the exact test refutes at its only look, the stage within its first round."""
    from conftest import ALL_TENTHS

    (tmp_path / "conf").symlink_to(Path(__file__).parents[1] / "conf")
    model = f"envelope.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    tiny = ["rare.refute_budget=8", "rare.round_size=4", "rare.certify=false", model, *ALL_TENTHS]
    argv = ["bench", "rare_real", "--root", str(tmp_path), "--profile", "tiny", "--pilot", "6", "--mc-cap", "10"]
    assert main([*argv, *tiny]) == 0
    out = capsys.readouterr().out
    assert "pilot: 6 failures in 6 rollouts" in out, out[-2000:]
    found = re.search(
        r"^RESULT rare_real p_pilot=1 p_low=[\d.]+ p_high=1 mc_rollouts=10 mc_refuted=1 "
        r"is_rollouts=(\d) is_refuted=1 saving=[\d.]+$",
        out,
        re.M,
    )
    assert found and int(found.group(1)) <= 4, out[-2000:]
