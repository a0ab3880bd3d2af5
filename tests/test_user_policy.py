"""A user's own policy in the pybullet world: a class by ``_target_``, a TorchScript file and an ONNX export of one
torch module drive the same rollouts; a Bayesian policy's draws give η2 and mutual information; its randomness is
its episode's seed's; bad input fails before any rollout in one line naming the file, what was expected and what came
back, and a policy that raises mid-rollout names the seed and step."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from omegaconf import DictConfig
from user_policy_kit import (
    Constant,
    linear_module,
    save_onnx,
    save_torchscript,
    save_weights,
    write_package,
    write_yaml,
)

from uqdrive.pipeline.certify_stage import CertifyStage, compose_certify, parse, plan, run_certify
from uqdrive.policy.interface import Command
from uqdrive.policy.policy_files import load_policy
from uqdrive.policy.slots import PolicyFailure
from uqdrive.safety.rollout import run_rollouts
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.safety.runner import cell_key
from uqdrive.schema import validate
from uqdrive.sim import DrivingEnv

SHORT = {"horizon": 3.0, "eta": 0.5, "look_size": 4, "budget": 8}


def request(tmp_path, policy, **changes) -> DictConfig:
    """conf/certify.yaml as `uqdrive certify` composes it: a short horizon, a low target, a small budget."""
    argv = ["--policy", str(policy), "--out", str(tmp_path / "certify.json"), "--root", str(tmp_path), "--no-progress"]
    return compose_certify(parse(argv + [f"--{k.replace('_', '-')}={v}" for k, v in {**SHORT, **changes}.items()]))


def planned(cfg: DictConfig):
    return plan(validate(CertifyStage, cfg))


def rollouts(tmp_path, record) -> list:
    log = tmp_path / "cache" / "rollouts" / "certify" / f"{record.cell_key}.jsonl"
    return RolloutLog(log, record.cell_key, record.base_seed).load()


@pytest.mark.slow  # whole certify runs, MLflow included
def test_a_class_a_torchscript_file_and_an_onnx_export_of_one_function_drive_the_same_rollouts(tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")  # torch's exporter
    write_package(tmp_path / "site", monkeypatch)
    module = linear_module()
    weights = save_weights(module, tmp_path / "linear.npz")
    policies = {
        "class": write_yaml(
            tmp_path / "linear.yaml",
            f"policy:\n  _target_: h50_user_policies.policies.LinearLogits\n  weights: {weights}\n",
        ),
        "torchscript": save_torchscript(module, tmp_path / "linear.pt"),
        "onnx": save_onnx(module, tmp_path / "linear.onnx"),
    }
    records = {kind: run_certify(request(tmp_path, path)) for kind, path in policies.items()}
    assert {r.policy_kind for r in records.values()} == set(policies)
    assert len({r.cell_key for r in records.values()}) == 3  # three policies, three cells
    runs = {kind: rollouts(tmp_path, r) for kind, r in records.items()}
    reference = runs["torchscript"]
    assert len({r.steps for r in reference}) > 3  # the frames steer it: paths of many lengths, compared below
    for kind in ("class", "onnx"):
        assert records[kind].verdict == records["torchscript"].verdict
        assert records[kind].outcomes == records["torchscript"].outcomes
        for mine, theirs in zip(runs[kind], reference, strict=True):
            assert mine.seed == theirs.seed and mine.termination == theirs.termination
            np.testing.assert_allclose(mine.x, theirs.x, atol=1e-9)
            np.testing.assert_allclose(mine.y, theirs.y, atol=1e-9)


def drive(spec, seeds, horizon_s=3.0, render=True) -> list:
    job = plan_job(spec, horizon_s)
    policy = spec.build(job.control_hz)
    with DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s) as env:
        return run_rollouts([env], policy, list(seeds), [job.where] * len(seeds))


def plan_job(spec, horizon_s):
    from uqdrive.safety.executors import RolloutJob
    from uqdrive.sim.condition import Condition
    from uqdrive.sim.config import ScenarioConfig, WeatherConfig, find_conf

    conf = find_conf()
    where = Condition(
        ScenarioConfig.from_yaml(conf / "scenario" / "roundabout.yaml"),
        WeatherConfig.from_yaml(conf / "weather" / "clear_noon.yaml"),
    )
    return RolloutJob(spec, where, 0, horizon_s=horizon_s)


def test_a_bayesian_class_policy_gets_eta2_and_mutual_information_from_its_seeded_draws(tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    path = write_yaml(tmp_path / "bayes.yaml", "policy:\n  _target_: h50_user_policies.policies.BayesianKeeper\n")
    spec = load_policy(path)
    first, again, other = drive(spec, [3]), drive(spec, [3]), drive(spec, [4])
    (result,) = first
    assert result.steps > 10 and (result.draws == 16).all()
    assert ((result.eta2 >= 0) & (result.eta2 <= 1)).all() and result.eta2.min() < 1  # draws disagree at times
    assert (result.mutual_information > 0).all() and np.isfinite(result.mutual_information_se).all()
    np.testing.assert_array_equal(result.eta2, again[0].eta2)  # the episode's seed fixes every draw
    np.testing.assert_array_equal(result.mutual_information, again[0].mutual_information)
    assert not np.array_equal(result.mutual_information, other[0].mutual_information[: result.steps])


class MeasuresItself:
    """A plain policy that measures its own decision, as uqdrive's controllers do: it returns a `Command`."""

    needs_camera = False

    def reset(self, seed):
        pass

    def act(self, frame, info):
        return Command(0.0, 6.0, eta2=0.25, draw_count=3)


def test_any_policy_instance_drives_rollouts_in_lockstep_as_it_drives_them_alone(tmp_path, monkeypatch):
    """A policy with no lockstep path of its own goes to `run_rollouts` as it is: a copy per slot, each seeded by its
    rollout, so two slots give what one does; a `Command` it returns keeps the measures it made."""
    write_package(tmp_path / "site", monkeypatch)
    from h50_user_policies.policies import BayesianKeeper

    job, seeds = plan_job(None, 3.0), [3, 4, 5]
    with (
        DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s) as a,
        DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s) as b,
    ):
        alone = run_rollouts([a], BayesianKeeper(), seeds, [job.where] * 3)
        paired = run_rollouts([a, b], BayesianKeeper(), seeds, [job.where] * 3)
        (measured,) = run_rollouts([a], MeasuresItself(), [3], [job.where])
    assert all((r.draws == 16).all() for r in alone)
    for one, two in zip(alone, paired):
        np.testing.assert_array_equal(one.eta2, two.eta2)
        np.testing.assert_array_equal(one.x, two.x)
    assert (measured.eta2 == 0.25).all() and (measured.draws == 3).all()


def test_mc_dropout_of_a_torchscript_module_gives_its_draws_reproducibly(tmp_path):
    torch.manual_seed(0)
    module = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Dropout(0.5), torch.nn.Linear(48 * 64, 21))
    path = save_torchscript(module, tmp_path / "mcd.pt")
    spec = load_policy(write_yaml(tmp_path / "mcd.yaml", "file: mcd.pt\nmc_draws: 8\n"))
    assert spec.path == str(path)
    (result,) = drive(spec, [5], horizon_s=1.0)
    (again,) = drive(spec, [5], horizon_s=1.0)
    assert (result.draws == 8).all() and np.isfinite(result.eta2).all() and np.isfinite(result.mutual_information).all()
    assert (result.mutual_information > 0).any()  # dropout is on: the draws differ
    np.testing.assert_array_equal(result.mutual_information, again.mutual_information)
    np.testing.assert_array_equal(result.x, again.x)
    plain = save_torchscript(linear_module(), tmp_path / "plain.pt")
    with pytest.raises(PolicyFailure, match=r"plain\.pt: mc_draws=8 needs dropout in the module, and it has none"):
        load_policy(write_yaml(tmp_path / "plain.yaml", "file: plain.pt\nmc_draws: 8\n")).build(15.0)
    assert plain.exists()


def test_editing_a_policy_changes_its_cell_key_and_moving_it_does_not(tmp_path, monkeypatch):
    source = write_package(tmp_path / "site", monkeypatch)
    keeper = write_yaml(tmp_path / "keeper.yaml", "policy:\n  _target_: h50_user_policies.policies.LaneKeeper\n")
    module = save_torchscript(Constant(0.2), tmp_path / "steer.pt")

    def key(path) -> str:
        return cell_key(plan_job(load_policy(path), 3.0), {}, None, "uqdrive.pipeline.certify_stage")

    before = {"class": key(keeper), "file": key(module)}
    moved = tmp_path / "elsewhere" / "steer.pt"
    moved.parent.mkdir()
    moved.write_bytes(module.read_bytes())
    assert key(moved) == before["file"]  # the same bytes elsewhere: the same cell
    source.write_text(source.read_text() + "\n# a comment: still an edit of the policy's source\n")
    save_torchscript(Constant(0.3), module)
    edited = key(keeper)
    assert edited != before["class"] and key(module) != before["file"]
    (source.parent / "helpers.py").write_text("GAIN = 1.0\n")  # a module of its package, which it might import
    assert key(keeper) != edited
    weights = save_weights(linear_module(), tmp_path / "weights.npz")
    target = "policy:\n  _target_: h50_user_policies.policies.LinearLogits\n"
    linear = write_yaml(tmp_path / "w.yaml", f"{target}  weights: {weights}\n")
    trained = key(linear)
    save_weights(linear_module(seed=1), weights)  # retrained at the same path: a file its settings name
    assert key(linear) != trained
    settings = write_yaml(tmp_path / "keeper2.yaml", "policy:\n  _target_: h50_user_policies.policies.LaneKeeper\n")
    assert key(settings) == key(keeper)
    settings.write_text(settings.read_text() + "  kp: 2.0\n")
    assert key(settings) != key(keeper)  # its settings are in its identity too


BAD_MODULES = {
    "shape.pt": (Constant(0.0, width=7), r"expected \[batch, 21\] class logits or \[batch, 1\] steering in \[-1, 1\], "
                 r"got output of shape \(1, 7\)"),
    "range.pt": (Constant(3.0), r"expected \[batch, 21\] class logits or \[batch, 1\] steering in \[-1, 1\], "
                 r"got steering 3\.0"),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(BAD_MODULES))
def test_a_network_of_the_wrong_shape_or_range_fails_before_any_rollout(tmp_path, name):
    module, message = BAD_MODULES[name]
    path = save_torchscript(module, tmp_path / name)
    with pytest.raises(PolicyFailure, match=rf"^{tmp_path / name}: {message}$"):
        planned(request(tmp_path, path))


def bad_files(tmp_path) -> dict[str, tuple[object, str]]:
    """File name → (what to write, the line expected)."""
    state = tmp_path / "state.pt"
    torch.save(linear_module().state_dict(), state)
    return {
        "missing.pt": (None, r"no such file; expected a TorchScript \(\.pt, \.ts\), ONNX \(\.onnx\), stable-baselines3 "
                       r"\(\.zip\) or policy YAML"),
        "corrupt.pt": (b"\x00not a zip", r"expected a TorchScript module \(torch\.jit\.save\), got RuntimeError: "),
        "state.pt": (state.read_bytes(), r"expected a TorchScript module \(torch\.jit\.save\), got "),
        "corrupt.onnx": (b"\x08\x01garbage", r"expected an ONNX model, got "),
        "policy.txt": (b"steer: 0", r"expected a TorchScript \(\.pt, \.ts\), ONNX \(\.onnx\), stable-baselines3 "
                       r"\(\.zip\) or policy YAML \(\.yaml\) file, got a \.txt file"),
        "typo.yaml": (b"file: x.pt\nmc_draw: 2\n", r"mc_draw: unknown key; did you mean 'mc_draws'\?"),
        "both.yaml": (b"file: x.pt\npolicy: {_target_: a.B}\n", r"give exactly one of `policy` .* and `file`"),
        "import.yaml": (b"policy: {_target_: no_such_package.Policy}\n", r"policy\._target_=no_such_package\.Policy: "
                        r"expected an importable class, got "),
    }  # fmt: skip


@pytest.mark.parametrize(
    "name",
    ["missing.pt", "corrupt.pt", "state.pt", "corrupt.onnx", "policy.txt", "typo.yaml", "both.yaml", "import.yaml"],
)
def test_a_missing_corrupt_or_wrong_kind_of_file_fails_in_one_line_naming_it(tmp_path, name):
    if name.endswith(".onnx"):
        pytest.importorskip("onnxruntime")
    content, message = bad_files(tmp_path)[name]
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises((PolicyFailure,)) as raised:
        planned(request(tmp_path, path))
    line = str(raised.value)
    assert "\n" not in line and line.startswith(str(path) if "_target_" not in message else "policy._target_")
    assert raised.match(message)
    assert not (tmp_path / "cache").exists()  # no rollout ran


def test_a_policy_that_raises_mid_rollout_says_the_seed_and_step(tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    path = write_yaml(tmp_path / "fails.yaml", "policy:\n  _target_: h50_user_policies.policies.FailsAtStep\n")
    with pytest.raises(PolicyFailure) as raised:
        run_certify(request(tmp_path, path, seed=70))
    assert str(raised.value) == (
        "h50_user_policies.policies.FailsAtStep raised ZeroDivisionError in act() at seed 70, step 5: the user's bug"
    )


@pytest.mark.parametrize(
    ("what", "message"),
    [
        ("steer", "expected steer in [-1, 1], got 2.0"),
        ("draws", "expected draws of [n] steering in [-1, 1] or [n, 21] class probabilities, got shape (4, 7), "
                  "range [0.143, 0.143]"),
        ("type", "act() must return uqdrive.policy.interface.Action, got float"),
    ],
)  # fmt: skip
def test_a_class_that_answers_out_of_shape_or_range_fails_before_any_rollout(tmp_path, monkeypatch, what, message):
    write_package(tmp_path / "site", monkeypatch)
    path = write_yaml(
        tmp_path / "bad.yaml", f"policy:\n  _target_: h50_user_policies.policies.BadAction\n  what: {what}\n"
    )
    with pytest.raises(PolicyFailure) as raised:
        planned(request(tmp_path, path))
    assert str(raised.value) == f"h50_user_policies.policies.BadAction at seed 0, step 0: {message}"
    assert not (tmp_path / "cache").exists()


@pytest.mark.slow  # whole certify runs, MLflow included
def test_a_package_beside_its_yaml_drives_in_worker_processes_and_their_failure_comes_back_whole(tmp_path, monkeypatch):
    """Not installed, not on the path: found beside the YAML, in this process and in each worker's."""
    write_package(tmp_path, monkeypatch, package="h50_beside", on_path=False)
    path = write_yaml(tmp_path / "fails.yaml", "policy:\n  _target_: h50_beside.policies.FailsAtStep\n  step: 7\n")
    with pytest.raises(PolicyFailure) as raised:
        run_certify(request(tmp_path, path, workers=2))
    assert str(raised.value) == (
        "h50_beside.policies.FailsAtStep raised ZeroDivisionError in act() at seed 0, step 7: the user's bug"
    )


WARN = "  delta1: 1.0\n  delta2: {delta2}\n  tau: 100.0\n  hold_s: 0.0\n"


def test_warnings_act_on_a_bayesian_policys_own_draws(tmp_path, monkeypatch):
    """Warning 1 wherever η̂2 < δ1 (= 1: a draw disagreed): that frame at half speed; with δ2 = 1 it is warning 2,
    and the car brakes to a stop and hands over."""
    write_package(tmp_path / "site", monkeypatch)
    target = "policy:\n  _target_: h50_user_policies.policies.BayesianKeeper\n  spread: 0.005\nwarnings:\n"
    slow = target + WARN.format(delta2=0.0) + "  actions: {warning1: {speed: 0.5, alert: true}}\n"
    (result,) = drive(load_policy(write_yaml(tmp_path / "slow.yaml", slow)), [3])
    doubtful = result.eta2 < 1
    assert doubtful.any() and not doubtful.all()
    np.testing.assert_array_equal(result.warning, np.where(doubtful, 1, -1))
    np.testing.assert_array_equal(result.command_speed, np.where(doubtful, 3.0, 6.0))

    stop = target + WARN.format(delta2=1.0)
    (result,) = drive(load_policy(write_yaml(tmp_path / "stop.yaml", stop)), [3])
    first = int(np.argmax(result.warning == 2))
    assert result.termination == "handover" and (result.command_speed[first:] == 0).all()
    assert first == int(np.argmax(doubtful))  # the same draws: the first doubtful frame hands over


def test_warnings_need_draws(tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    path = write_yaml(
        tmp_path / "keeper.yaml",
        "policy:\n  _target_: h50_user_policies.policies.LaneKeeper\nwarnings:\n" + WARN.format(delta2=0.0),
    )
    with pytest.raises(PolicyFailure) as raised:
        planned(request(tmp_path, path))
    assert str(raised.value) == (
        "h50_user_policies.policies.LaneKeeper at seed 0, step 0: expected draws (warnings are on), got an action "
        "without"
    )


def test_the_certify_record_carries_a_bayesian_policys_eta2_mi_and_warnings(tmp_path, monkeypatch):
    write_package(tmp_path / "site", monkeypatch)
    text = "policy:\n  _target_: h50_user_policies.policies.BayesianKeeper\n  spread: 0.005\nwarnings:\n"
    path = write_yaml(tmp_path / "bayes.yaml", text + WARN.format(delta2=0.0))
    record = run_certify(request(tmp_path, path))
    runs = rollouts(tmp_path, record)
    assert 0 < record.mean_eta2 < 1 and record.mean_mutual_information > 0
    assert record.mean_eta2 == pytest.approx(np.mean([r.mean_eta2 for r in runs]))
    steps = np.concatenate([r.warning for r in runs])
    assert record.warning_share == pytest.approx((steps >= 0).mean()) and 0 < record.warning_share < 1


@pytest.mark.slow
def test_a_seeded_bayesian_policy_gives_the_same_rollouts_on_one_worker_or_two(tmp_path, monkeypatch):
    """Rollout i's draws come from seed base + i alone: the lockstep slot, worker and order it ran in change nothing."""
    write_package(tmp_path / "site", monkeypatch)
    path = write_yaml(tmp_path / "bayes.yaml", "policy:\n  _target_: h50_user_policies.policies.BayesianKeeper\n")
    records = [run_certify(request(tmp_path / name, path, workers=workers)) for name, workers in (("a", 1), ("b", 2))]
    assert records[0].cell_key == records[1].cell_key and not records[1].reused
    one, two = (rollouts(tmp_path / name, r) for name, r in zip("ab", records))
    assert len(one) == len(two) == records[0].rollouts
    for mine, theirs in zip(one, two, strict=True):
        np.testing.assert_array_equal(mine.eta2, theirs.eta2)
        np.testing.assert_array_equal(mine.mutual_information, theirs.mutual_information)
        np.testing.assert_array_equal(mine.x, theirs.x)
