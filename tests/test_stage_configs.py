"""Every stage checks its whole config against its schema before it works: a typo'd key, a wrong type and a value
out of range each end it with one line naming the full key path, and it has written nothing."""

import shutil
from pathlib import Path

import pytest
from conftest import ALL_TENTHS

from uqdrive.pipeline.acquire_stage import run_acquire
from uqdrive.pipeline.acquire_summary_stage import run_acquire_summary
from uqdrive.pipeline.avoid_stage import run_avoid
from uqdrive.pipeline.avoid_summary_stage import run_avoid_summary
from uqdrive.pipeline.certify_stage import run_certify
from uqdrive.pipeline.collect_stage import run_collect
from uqdrive.pipeline.envelope_stage import run_envelope
from uqdrive.pipeline.evaluate_stage import run_evaluate
from uqdrive.pipeline.findings_stage import run_findings
from uqdrive.pipeline.heldout_stage import run_heldout
from uqdrive.pipeline.preprocess_stage import run_preprocess
from uqdrive.pipeline.rare_stage import run_rare
from uqdrive.pipeline.report_stage import run_report
from uqdrive.pipeline.safety_stage import run_safety, run_safety_sweep
from uqdrive.pipeline.safety_summary_stage import run_safety_summary
from uqdrive.pipeline.train_stage import run_train, run_train_replicates
from uqdrive.schema import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def first(generator_stage):
    """A grid stage is a generator: its checks run when the first cell is asked for."""
    return lambda cfg: next(generator_stage(cfg, []))


STAGES = {
    "collect": run_collect,
    "heldout": run_collect,
    "heldout_sweep": first(run_heldout),
    "preprocess": run_preprocess,
    "train": run_train,
    "train_replicates": lambda cfg: run_train_replicates(cfg, []),
    "safety": run_safety,
    "safety_sweep": first(run_safety_sweep),
    "gym_safety_sweep": first(run_safety_sweep),
    "evaluate": run_evaluate,
    "avoid": run_avoid,
    "gym_avoid": run_avoid,
    "gym_avoid_acquired": run_avoid,
    "safety_summary": run_safety_summary,
    "avoid_summary": run_avoid_summary,
    "findings": run_findings,
    "gym_findings": run_findings,
    "report": run_report,
    "envelope": run_envelope,
    "rare": run_rare,
    "certify": run_certify,
    "acquire": lambda cfg: run_acquire(cfg, []),
    "gym_acquire": lambda cfg: run_acquire(cfg, []),
    "acquire_summary": run_acquire_summary,
}

# stage: (a typo'd key, a wrong type, a value out of range), each an override and the start of its one line
BAD = {
    "collect": [
        ("+collect.episodez=3", "collect.episodez: unknown key; did you mean 'episodes'?"),
        ("collect.episodes=many", "collect.episodes='many': input should be a valid integer"),
        ("collect.episodes=0", "collect.episodes=0: input should be greater than or equal to 1"),
    ],
    "heldout": [
        ("+collect.mosaic_row=2", "collect.mosaic_row: unknown key; did you mean 'mosaic_rows'?"),
        ("noise=loud", "noise='loud': input should be a valid number"),
        ("noise=-0.1", "noise=-0.1: input should be greater than or equal to 0"),
    ],
    "heldout_sweep": [
        ("+sweep.weather=[rain]", "sweep.weather: unknown key; did you mean 'weathers'?"),
        ("sweep.noises=[low]", "sweep.noises[0]='low': input should be a valid number"),
        ("sweep.noises=[-0.1]", "sweep.noises[0]=-0.1: input should be greater than or equal to 0"),
    ],
    "preprocess": [
        ("+preprocess.val_fractoin=0.1", "preprocess.val_fractoin: unknown key; did you mean 'val_fraction'?"),
        ("preprocess.split_seed=0.5", "preprocess.split_seed=0.5: input should be a valid integer"),
        ("preprocess.val_fraction=1.5", "preprocess.val_fraction=1.5: input should be less than 1"),
    ],
    "train": [
        ("+arch.hiden=[8,8,8]", "arch.hiden: unknown key; did you mean 'hidden'?"),
        ("train.mcd.epochs=ten", "model.epochs='ten': input should be a valid integer"),
        ("train.mcd.lr=-0.1", "model.lr=-0.1: input should be greater than 0"),
    ],
    "safety": [
        ("+safety.thetaa=0.1", "safety.thetaa: unknown key; did you mean 'theta'?"),
        ("safety.samples=lots", "safety.samples='lots': input should be a valid integer"),
        ("safety.theta=2", "safety.theta=2: input should be less than 1"),
    ],
    "safety_sweep": [
        ("+scenario.ring_radiuss=20", "scenario.ring_radiuss: unknown key; did you mean 'ring_radius'?"),
        ("weather.shadow=sometimes", "weather.shadow='sometimes': input should be a valid boolean"),
        ("camera.width=4", "camera.width=4: input should be greater than or equal to 8"),
    ],
    "gym_safety_sweep": [
        ("+sweep.world_axes=1", "sweep.world_axes: unknown key; did you mean 'world_axis'?"),
        ("sweep.world_axis={key: 3, values: {a: 1}}", "sweep.world_axis.key=3: input should be a valid string"),
        ("sweep.noises=[-1]", "sweep.noises[0]=-1: input should be greater than or equal to 0"),
    ],
    "gym_avoid": [
        ("avoid.unknown=[{name: x, wrld: {}}]", "avoid.unknown[0].wrld: unknown key; did you mean 'world'?"),
        ("avoid.unknown=[{name: x, world: 3}]", "avoid.unknown[0].world=3: input should be a valid dictionary"),
        ("avoid.unknown=[{name: x, noise: -1}]", "avoid.unknown[0].noise=-1: input should be greater than or equal"),
    ],
    "gym_avoid_acquired": [
        ("+avoid.model_pth=x", "avoid.model_pth: unknown key; did you mean 'model_path'?"),
        ("avoid.speed=fast", "avoid.speed='fast': input should be a valid number"),
        ("avoid.speed=-1", "avoid.speed=-1: input should be greater than 0"),
    ],
    "evaluate": [
        ("+evaluate.sample=3", "evaluate.sample: unknown key; did you mean 'samples'?"),
        ("evaluate.eps=wide", "evaluate.eps='wide': input should be a valid number"),
        ("evaluate.batch_size=0", "evaluate.batch_size=0: input should be greater than or equal to 1"),
    ],
    "avoid": [
        (
            "+warning.actions.warning0.alertt=true",
            "warning.actions.warning0.alertt: unknown key; did you mean 'alert'?",
        ),
        ("warning.actions.warning1.alert=maybe", "warning.actions.warning1.alert='maybe': input should be a valid"),
        ("avoid.calibration.gamma=1.5", "avoid.calibration.gamma=1.5: input should be less than 1"),
    ],
    "safety_summary": [
        ("+summary.figure_dir=x", "summary.figure_dir: unknown key; did you mean 'figures_dir'?"),
        ("noises=[none]", "noises[0]='none': input should be a valid number"),
        ("locations=[]", "locations=[]: tuple should have at least 1 item"),
    ],
    "train_replicates": [
        ("+train.worker=2", "train.worker: unknown key; did you mean 'workers'?"),
        ("replicates=[first]", "replicates[0]='first': input should be a valid integer"),
        ("replicates=[]", "replicates=[]: tuple should have at least 1 item"),
    ],
    "avoid_summary": [
        ("+summary.result_dir=x", "summary.result_dir: unknown key; did you mean 'results_dir'?"),
        ("methods=[1]", "methods[0]=1: input should be a valid string"),
        ("methods=[]", "methods=[]: tuple should have at least 1 item"),
    ],
    "findings": [
        ("+findings.alhpa=0.1", "findings.alhpa: unknown key; did you mean 'alpha'?"),
        ("replicates=[first]", "replicates[0]='first': input should be a valid integer"),
        ("findings.alpha=0", "findings.alpha=0: input should be greater than 0"),
    ],
    "gym_findings": [
        ("+findings.cell_dir=x", "findings.cell_dir: unknown key; did you mean 'cells_dir'?"),
        ("findings.experiment=1", "findings.experiment=1: input should be a valid string"),
        ("findings.margin=1", "findings.margin=1: input should be less than 1"),
    ],
    "report": [
        ("+report.outdir=x", "report.outdir: unknown key; did you mean 'out_dir'?"),
        ("noises=[high]", "noises[0]='high': input should be a valid number"),
        ("noises=[-1]", "noises[0]=-1: input should be greater than or equal to 0"),
    ],
    "envelope": [
        ("+envelope.thresold=0.8", "envelope.thresold: unknown key; did you mean 'threshold'?"),
        ("envelope.region_budget=many", "envelope.region_budget='many': input should be a valid integer"),
        ("envelope.gamma=1.5", "envelope.gamma=1.5: input should be less than 1"),
    ],
    "rare": [
        ("+rare.targte=0.9", "rare.targte: unknown key; did you mean 'target'?"),
        ("rare.refute_budget=many", "rare.refute_budget='many': input should be a valid integer"),
        ("rare.defensive=1.5", "rare.defensive=1.5: input should be less than or equal to 1"),
    ],
    "acquire": [
        ("+acquire.round=1", "acquire.round: unknown key; did you mean 'rounds'?"),
        ("acquire.beta=often", "acquire.beta='often': input should be a valid number"),
        ("acquire.rounds=-1", "acquire.rounds=-1: input should be greater than or equal to 0"),
    ],
    "gym_acquire": [
        ("+acquire.episode=3", "acquire.episode: unknown key; did you mean 'episodes'?"),
        ("acquire.margin=wide", "acquire.margin='wide': input should be a valid number"),
        ("acquire.margin=1", "acquire.margin=1: input should be less than 1"),
    ],
    "acquire_summary": [
        ("+summary.alhpa=0.1", "summary.alhpa: unknown key; did you mean 'alpha'?"),
        ("summary.margin=wide", "summary.margin='wide': input should be a valid number"),
        ("summary.alpha=0", "summary.alpha=0: input should be greater than 0"),
    ],
}


WORLD_OF = {stage: ("gym_world=highway_roundabout",) for stage in ("gym_avoid", "gym_avoid_acquired")}


@pytest.mark.parametrize(
    ("stage", "override", "message"), [(s, o, m) for s, cases in BAD.items() for o, m in cases], ids=str
)
def test_a_bad_key_type_or_value_in_any_stage_is_one_line_naming_the_key_and_nothing_is_written(
    tmp_path, stage_config, stage, override, message
):
    shutil.copy(ROOT / "params.yaml", tmp_path / "params.yaml")  # the lists the stages read (${params:...})
    world = WORLD_OF.get(stage, ())  # the unknown conditions come from the world's own axis: name it, as dvc.yaml does
    cfg = stage_config(stage, *world, override)
    with pytest.raises(ConfigError) as err:
        STAGES[stage](cfg)
    assert str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)
    assert [p.name for p in tmp_path.iterdir()] == ["params.yaml"]  # no output, no MLflow store


def test_every_stage_config_is_covered():
    assert set(STAGES) == {p.stem for p in (ROOT / "conf").glob("*.yaml")} - {"common", "sim"}


def test_the_paper_profile_keeps_the_papers_guarantee_in_fewer_rollouts(stage_config, random_models):
    """θ = γ = 0.05 in every cell, as the paper's Chernoff n = 738 gives it, by the sequential scheme (36 rollouts
    where η1 is 0 or 1): the safety sweep, and avoidance on the paper's cells (the known condition, the unknown ones
    as one mixture cell), each running a fixed sample large enough to calibrate on."""
    from uqdrive.avoid.calibration import min_calibration_runs
    from uqdrive.avoid.plan import KNOWN, UNKNOWN, build_settings
    from uqdrive.pipeline.safety_stage import SafetyStage
    from uqdrive.schema import validate

    safety = validate(SafetyStage, stage_config("safety", "profile=paper")).estimator
    assert (safety.scheme, safety.theta, safety.gamma) == ("sequential", 0.05, 0.05)
    assert safety.fixed_rollouts() == 36 and safety.planned_rollouts() < 738
    model = f"avoid.model_path={random_models['mcd'].parent}/${{model.name}}.pt"
    controllers = "avoid.calibration.fresh_check.controllers=3"  # the project's params.yaml: not in this tmp root
    avoid = build_settings(stage_config("avoid", "profile=paper", model, controllers, *ALL_TENTHS))
    assert (avoid.estimator.scheme, avoid.estimator.theta, avoid.estimator.gamma) == ("sequential", 0.05, 0.05)
    assert [c.name for c in avoid.conditions] == [KNOWN, UNKNOWN] and len(avoid.unknown[0].variants) == 4
    calibration = avoid.calibration
    assert avoid.fixed_rollouts() == 100 >= min_calibration_runs(calibration.autonomy_target, calibration.gamma)
    assert calibration.fresh_check.target == 0.8 and calibration.fresh_runs() == 44  # power 0.8 at 0.95, γ / 3
