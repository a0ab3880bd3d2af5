"""A stable-baselines3 agent built and saved inside the test (no download; untrained, its action head scaled so that
its steering follows the frame): certified from its ``.zip`` in the pybullet world and in a Gymnasium world rollout
for rollout as the same agent driven through SB3's own ``PPO.load(...).predict``; a zip of something else, or an
agent that does not observe uqdrive's frame, fails before any rollout in one line naming the file."""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch
from omegaconf import DictConfig

from uqdrive.pipeline.certify_stage import compose_certify, parse, run_certify
from uqdrive.policy.policy_files import load_policy
from uqdrive.policy.sb3_policy import SB3Policy, load_sb3
from uqdrive.policy.slots import PolicyFailure
from uqdrive.safety.rollout_log import RolloutLog

sb3 = pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (pip install 'uqdrive[sb3]')")
CENTRES = np.round(np.linspace(-1.0, 1.0, 21), 1)
WRAPPER = '''
from stable_baselines3 import PPO

from uqdrive.network_input import preprocess_frame
from uqdrive.policy.interface import Action


class ViaPredict:
    """The agent as SB3 itself loads and runs it, on the grey frame its env observes."""

    def __init__(self, path):
        self.model = PPO.load(path, device="cpu")

    def reset(self, seed):
        pass

    def act(self, frame, info):
        action, _ = self.model.predict(preprocess_frame(frame), deterministic=True)
        return Action(float(action[0]))
'''


def save_agent(path: Path, env_id: str = "uqdrive/Roundabout-v0") -> Path:
    """A PPO agent of uqdrive's Gymnasium env (observes the grey 48x64 frame, acts [steer]), saved by SB3."""
    import uqdrive.sim.gym_env  # noqa: F401  (registers uqdrive/Roundabout-v0)

    model = sb3.PPO("MlpPolicy", gymnasium.make(env_id), n_steps=16, batch_size=16, seed=0, device="cpu")
    with torch.no_grad():
        model.policy.action_net.weight.mul_(50.0)  # the untrained head's 0.01 gain: steering of a few tenths
    model.save(path)
    return path


def frames() -> list[np.ndarray]:
    """RGB frames of one drive of uqdrive's Gymnasium env, turning."""
    with gymnasium.make("uqdrive/Roundabout-v0") as env:
        grey, done = [env.reset(seed=0)[0]], False
        while not done and len(grey) < 30:
            obs, _, terminated, truncated, _ = env.step(np.array([0.3], np.float32))
            grey, done = [*grey, obs], terminated or truncated
    return [np.repeat(g[..., None], 3, axis=2) for g in grey]


def request(tmp_path: Path, policy: Path, *world: str) -> DictConfig:
    argv = ["--policy", str(policy), "--out", str(tmp_path / "certify.json"), "--root", str(tmp_path), "--no-progress"]
    short = ["--horizon=3.0", "--eta=0.5", "--look-size=4", "--budget=8"]
    return compose_certify(parse([*argv, *short, *world]))


@pytest.mark.slow  # whole certify runs, MLflow included
def test_an_agent_file_drives_the_rollouts_sb3_itself_drives_in_both_kinds_of_world(tmp_path, monkeypatch):
    agent = save_agent(tmp_path / "agent.zip")
    steers = {round(SB3Policy(str(agent), CENTRES, load_sb3(agent)).act(f, {}).steer, 4) for f in frames()}
    assert len(steers) > 5 and max(map(abs, steers)) < 1  # the frame steers it, unclipped: a test that can fail
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "h50_sb3.py").write_text(WRAPPER)
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.delitem(sys.modules, "h50_sb3", raising=False)
    wrapper = tmp_path / "via_predict.yaml"
    wrapper.write_text(f"policy:\n  _target_: h50_sb3.ViaPredict\n  path: {agent}\n")
    gym = ("--world", "uqdrive_roundabout", "gym_world.horizon_steps=45")
    for world in ((), gym):
        record = run_certify(request(tmp_path, agent, *world))
        same = run_certify(request(tmp_path, wrapper, *world))
        assert record.policy_kind == "sb3" and record.cell_key != same.cell_key
        assert (record.verdict, record.outcomes) == (same.verdict, same.outcomes)
        mine, theirs = (RolloutLog(tmp_path / "cache/rollouts/certify" / f"{r.cell_key}.jsonl", r.cell_key, 0).load()
                        for r in (record, same))  # fmt: skip
        for a, b in zip(mine, theirs, strict=True):
            assert a.termination == b.termination and np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)


def test_a_zip_that_is_no_agent_fails_in_one_line_naming_it(tmp_path):
    path = tmp_path / "notes.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("notes.txt", "not an agent")
    with pytest.raises(PolicyFailure) as err:
        load_policy(path).build(15.0)
    assert str(err.value).startswith(f"{path}: expected a stable-baselines3 agent (model.save), got ")
    assert "\n" not in str(err.value)


def test_an_agent_that_does_not_observe_uqdrives_frame_fails_before_any_rollout(tmp_path):
    agent = save_agent(tmp_path / "cartpole.zip", "CartPole-v1")
    with pytest.raises(PolicyFailure) as err:
        load_policy(agent).build(15.0)
    assert str(err.value).startswith(
        f"{agent}: expected an agent observing uqdrive's frame (uint8 grey [48, 64], [1, 48, 64], [48, 64, 1] or RGB "
        "[H, W, 3]), got observation space Box("
    )
    with pytest.raises(PolicyFailure, match=r"mc_draws=4: a stable-baselines3 agent acts deterministically$"):
        load_policy(agent, mc_draws=4)
