"""Agents over the env's own spaces, certified by command line alone in a world made from a plain env id
(`uqdrive certify --env ID`), each built or trained inside the test: every one's outcome per seed equals a plain
Gymnasium loop over the same seeds (the loop in `native_kit.plain_outcomes`, apart from uqdrive's engine). Bad input
— mismatched spaces, an action outside the space, a predicate that raises, an `--unsafe-if` key the env never
reports — is one line and exit 2 before any rollout."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium
import native_kit
import numpy as np
import pytest
import torch
from user_policy_kit import write_yaml

from uqdrive.tools.cli import main

SEEDS = range(8)
SHORT = ("--eta", "0.5", "--look-size", "8", "--budget", "8", "--seed-base", "0")  # seeds 0 … 7, as the plain loops


def certify(tmp_path: Path, policy: Path | str, *args: str) -> tuple[int, dict]:
    out = tmp_path / "record.json"
    out.unlink(missing_ok=True)
    argv = ["certify", "--policy", str(policy), "--out", str(out), "--root", str(tmp_path), "--no-progress", *args]
    code = main(argv)
    return code, json.loads(out.read_text()) if out.exists() else {}


def function_yaml(tmp_path: Path, target: str, **settings: object) -> Path:
    lines = "".join(f"  {k}: {v}\n" for k, v in settings.items())
    return write_yaml(tmp_path / "agent.yaml", f"policy:\n  _target_: {target}\n{lines}")


def test_a_plain_function_by_target_is_certified_with_the_outcomes_of_a_plain_loop(tmp_path):
    """A function over a Dict observation with Discrete actions; the safe set from an info key and a predicate."""
    agent = function_yaml(tmp_path, "native_kit.toward_centre")
    env = f"native_kit:{native_kit.WALK}"
    code, record = certify(tmp_path, agent, "--env", env, "--unsafe-if", "fell", *SHORT)
    plain = native_kit.plain_outcomes(native_kit.WALK, native_kit.toward_centre, SEEDS, lambda o, i, t: i["fell"])
    assert record["outcomes"] == plain and code == {"11111111": 0}.get(plain, code)
    assert record["world"] == native_kit.WALK and record["policy_kind"] == "class"
    code, judged = certify(
        tmp_path, agent, "--env", env, "--safe-when", "native_kit:stays_near", "--unsafe-if", "fell", *SHORT
    )
    near = native_kit.plain_outcomes(
        native_kit.WALK, native_kit.toward_centre, SEEDS, lambda o, i, t: i["fell"] or not native_kit.stays_near(o, i)
    )
    assert judged["outcomes"] == near and judged["cell_key"] != record["cell_key"]
    assert "0" in near + plain  # the signals judge: a test that can fail


def test_an_agent_with_draws_keeps_eta2_and_mutual_information(tmp_path):
    """η̂2 per step: the share of the draws whose arg-max is the action taken; MI from the probabilities (computed
    here by hand, apart from uqdrive's measures), both averaged per rollout then over rollouts as a cell reports."""
    agent = function_yaml(tmp_path, "native_kit.Hesitant")
    code, record = certify(tmp_path, agent, "--env", f"native_kit:{native_kit.WALK}", "--unsafe-if", "fell", *SHORT)
    eta2, mi = [], []
    with gymnasium.make(native_kit.WALK) as env:
        for seed in SEEDS:
            hesitant, (obs, info), steps = native_kit.Hesitant(), env.reset(seed=seed), []
            hesitant.reset(seed)
            for _ in range(20):
                action = native_kit.toward_centre(obs)
                p = hesitant.draws(action)
                mean = p.mean(0)
                steps.append(
                    ((p.argmax(1) == action).mean(), -(mean * np.log(mean)).sum() + (p * np.log(p)).sum(1).mean())
                )
                obs, _, terminated, _, info = env.step(action)
                if terminated:
                    break
            eta2.append(np.mean([s[0] for s in steps]))
            mi.append(np.mean([s[1] for s in steps]))
    assert record["mean_eta2"] == pytest.approx(np.mean(eta2), abs=1e-9) and 0.3 < record["mean_eta2"] < 1
    assert (
        record["mean_mutual_information"] == pytest.approx(np.mean(mi), abs=1e-9)
        and record["mean_mutual_information"] > 0
    )


class Policy(torch.nn.Module):
    """An MLP over a vector observation: logits of a Discrete action space, or a tanh action of a Box."""

    def __init__(self, inputs: int, outputs: int, box: bool = False, seed: int = 0):
        super().__init__()
        torch.manual_seed(seed)
        self.net = torch.nn.Sequential(torch.nn.Linear(inputs, 8), torch.nn.Tanh(), torch.nn.Linear(8, outputs))
        self.box = box

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.net(x)
        return torch.tanh(out) if self.box else out


def test_an_onnx_mlp_over_a_vector_observation(tmp_path):
    """CartPole: an ONNX MLP's arg-max action; a termination is a failure (the pole fell), a truncation the end."""
    net = Policy(4, 2, seed=3)
    path = tmp_path / "cartpole.onnx"
    dynamic = {"obs": {0: "batch"}, "out": {0: "batch"}}
    torch.onnx.export(
        net, (torch.zeros(1, 4),), str(path), dynamo=False, input_names=["obs"], output_names=["out"],
        dynamic_axes=dynamic,
    )  # fmt: skip
    kwargs = {"max_episode_steps": 60}
    args = ("--env", "CartPole-v1", "--terminated", "unsafe", "--env-kwargs", json.dumps(kwargs), *SHORT)
    code, record = certify(tmp_path, path, *args)

    def act(obs):
        return int(net(torch.as_tensor(obs[None])).argmax())

    assert record["outcomes"] == native_kit.plain_outcomes("CartPole-v1", act, SEEDS, lambda o, i, t: t, **kwargs)
    assert record["policy_kind"] == "onnx" and code in (0, 1, 3)


def test_an_image_agent_in_a_vector_env_sees_the_envs_rendering(tmp_path, capsys):
    """`--observe view`: a function over CartPole's RGB rendering (its observation is a vector), outcomes per seed
    those of a plain loop that hands the agent `env.render()`; without it, the same agent is refused in one line."""
    agent = function_yaml(tmp_path, "native_kit.lean_from_picture")
    kwargs = {"max_episode_steps": 40}
    args = ("--env", "CartPole-v1", "--terminated", "unsafe", "--env-kwargs", json.dumps(kwargs), *SHORT)
    code, record = certify(tmp_path, agent, *args, "--observe", "view")
    plain = native_kit.plain_outcomes(
        "CartPole-v1", native_kit.lean_from_picture, SEEDS, lambda o, i, t: t, view=True, **kwargs
    )
    assert record["outcomes"] == plain and code in (0, 1, 3)
    blind = native_kit.plain_outcomes("CartPole-v1", lambda obs: 0, SEEDS, lambda o, i, t: t, **kwargs)
    assert plain != blind  # the picture steers it: a test that can fail
    capsys.readouterr()
    assert certify(tmp_path, agent, *args, "--out-dir", str(tmp_path / "vector"))[0] == 2  # it sees the vector
    err = capsys.readouterr().err
    assert err.startswith("uqdrive certify: ") and err.count("\n") == 1, err


def test_a_torchscript_policy_on_a_box_action_env(tmp_path):
    net = Policy(2, 1, box=True, seed=1)
    path = tmp_path / "slide.pt"
    torch.jit.save(torch.jit.script(net), str(path))
    env = f"native_kit:{native_kit.SLIDE}"
    code, record = certify(tmp_path, path, "--env", env, "--unsafe-if", "off", *SHORT)

    def act(obs):
        with torch.no_grad():
            return net(torch.as_tensor(obs[None])).numpy()[0]

    plain = native_kit.plain_outcomes(native_kit.SLIDE, act, SEEDS, lambda o, i, t: i["off"])
    assert record["outcomes"] == plain and record["policy_kind"] == "torchscript" and "0" in plain


sb3 = pytest.importorskip("stable_baselines3")


@pytest.mark.slow  # trains a PPO agent (64 steps) and certifies it
def test_a_ppo_multi_input_agent_on_a_dict_observation_env(tmp_path):
    model = sb3.PPO("MultiInputPolicy", gymnasium.make(native_kit.WALK), n_steps=32, batch_size=32, seed=0)
    model.learn(total_timesteps=64)
    path = tmp_path / "ppo.zip"
    model.save(path)
    code, record = certify(tmp_path, path, "--env", f"native_kit:{native_kit.WALK}", "--unsafe-if", "fell", *SHORT)
    loaded = sb3.PPO.load(path, device="cpu")
    plain = native_kit.plain_outcomes(
        native_kit.WALK, lambda o: loaded.predict(o, deterministic=True)[0], SEEDS, lambda o, i, t: i["fell"]
    )
    assert record["outcomes"] == plain and record["policy_kind"] == "sb3"


@pytest.mark.slow  # trains a PPO CnnPolicy agent (32 steps) and certifies it
def test_a_ppo_cnn_agent_on_an_image_env(tmp_path):
    """SB3 saves a channels-last image agent's space channels first; it still reads the env's images."""
    model = sb3.PPO("CnnPolicy", gymnasium.make(native_kit.PICTURE), n_steps=32, batch_size=32, n_epochs=1, seed=0)
    model.learn(total_timesteps=32)
    path = tmp_path / "cnn.zip"
    model.save(path)
    code, record = certify(tmp_path, path, "--env", f"native_kit:{native_kit.PICTURE}", "--unsafe-if", "fell", *SHORT)
    loaded = sb3.PPO.load(path, device="cpu")
    plain = native_kit.plain_outcomes(
        native_kit.PICTURE, lambda o: loaded.predict(o, deterministic=True)[0], SEEDS, lambda o, i, t: i["fell"]
    )
    assert record["outcomes"] == plain and record["policy_kind"] == "sb3"


@pytest.mark.slow  # trains a DQN agent (50 steps) on HighwayEnv and certifies it
def test_a_dqn_agent_on_highway_kinematics_with_discrete_meta_actions(tmp_path):
    pytest.importorskip("highway_env")
    kwargs = {"config": {"duration": 8, "vehicles_count": 10}}
    model = sb3.DQN("MlpPolicy", gymnasium.make("highway-fast-v0", **kwargs), learning_starts=10, seed=0)
    model.learn(total_timesteps=50)
    path = tmp_path / "dqn.zip"
    model.save(path)
    args = ("--env", "highway-fast-v0", "--env-kwargs", json.dumps(kwargs), "--unsafe-if", "crashed", *SHORT)
    code, record = certify(tmp_path, path, *args)
    loaded = sb3.DQN.load(path, device="cpu")
    plain = native_kit.plain_outcomes(
        "highway-fast-v0", lambda o: loaded.predict(o, deterministic=True)[0], SEEDS,
        lambda o, i, t: bool(i.get("crashed")), **kwargs,
    )  # fmt: skip
    assert record["outcomes"] == plain and record["world"] == "highway-fast-v0"
    assert code == {"11111111": 0}.get(plain, code) and record["rollouts"] == 8


class Declares:
    """An agent declaring the spaces it was trained on."""

    def __init__(self, observation: str = "walk", actions: int = 3):
        walk = gymnasium.make(native_kit.WALK)
        image = gymnasium.spaces.Box(0, 255, (64, 64, 3), np.uint8)
        self.observation_space = walk.observation_space if observation == "walk" else image
        self.action_space = gymnasium.spaces.Discrete(actions)

    def act(self, obs, info):
        return 1


def write_agent_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, body: str) -> None:
    (tmp_path / "bad_agents.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))


BAD = """
def seven(obs):
    return 7
"""


@pytest.mark.parametrize(
    ("target", "flags", "says"),
    [
        (
            "test_native_agents.Declares\n  observation: image",
            (),
            "the agent observes Box(0, 255, (64, 64, 3), uint8), but the env observes Dict(",
        ),
        (
            "test_native_agents.Declares\n  actions: 5",
            (),
            "the agent acts in Discrete(5), but the env acts in Discrete(3)",
        ),
        (
            "bad_agents.seven",
            (),
            "at seed 0, step 0: the agent's action 7 is outside the env's action space Discrete(3)",
        ),
        (
            "native_kit.toward_centre",
            ("--safe-when", "native_kit:raises"),
            "raised ZeroDivisionError in raises() at seed 0",
        ),
        ("native_kit.toward_centre", ("--unsafe-if", "crashed"), "'crashed' is not in the info of"),
    ],
    ids=["image-agent-in-a-vector-env", "discrete-5-in-discrete-3", "action-outside", "predicate-raises", "no-key"],
)
def test_bad_input_is_one_line_and_exit_2_before_any_rollout(tmp_path, monkeypatch, capsys, target, flags, says):
    write_agent_module(tmp_path, monkeypatch, BAD)
    agent = function_yaml(tmp_path, target)
    code, record = certify(tmp_path, agent, "--env", f"native_kit:{native_kit.WALK}", *flags, *SHORT)
    err = capsys.readouterr().err
    assert code == 2 and not record and err.count("\n") == 1 and says in err, err
    if "crashed" in flags:
        assert "(it reports ['fell'])" in err
    assert not list(tmp_path.glob("cache/rollouts/certify/*.jsonl")) or all(
        len(p.read_text().splitlines()) <= 1 for p in tmp_path.glob("cache/rollouts/certify/*.jsonl")
    )


def test_env_flags_refuse_bad_values_in_one_line(tmp_path, capsys):
    agent = function_yaml(tmp_path, "native_kit.toward_centre")
    env = ("--env", f"native_kit:{native_kit.WALK}")
    cases = [
        ((*env, "--env-kwargs", "[1]"), "--env-kwargs='[1]': expected a JSON object"),
        ((*env, "--safe-if", "fell"), "--safe-if='fell': expected KEY=true or KEY=false"),
        ((*env, "--world", "roundabout"), "--world='roundabout' beside --env="),
        (("--env", "NoSuchEnv-v9"), "NoSuchEnv"),
    ]
    for args, says in cases:
        assert certify(tmp_path, agent, *args, *SHORT)[0] == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and says in err, err


def test_an_sb3_agent_of_another_env_is_refused_by_its_saved_spaces(tmp_path, capsys):
    """A DQN made (untrained) on CartPole's Box(4) observation and Discrete(2) actions, certified in a Dict env."""
    path = tmp_path / "cartpole_dqn.zip"
    sb3.DQN("MlpPolicy", gymnasium.make("CartPole-v1"), learning_starts=0, seed=0).save(path)
    code, _ = certify(tmp_path, path, "--env", f"native_kit:{native_kit.WALK}", "--unsafe-if", "fell", *SHORT)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"{path}: the agent observes Box(" in err and "(4,), float32), but the env observes Dict(" in err, err


@pytest.mark.slow  # PyDSMC's and uqdrive's runs
def test_the_peer_bench_takes_an_agent_file_and_an_env_id(tmp_path, capsys):
    pytest.importorskip("pydsmc")
    agent = function_yaml(tmp_path, "native_kit.push")
    argv = ["bench", "peer", "--policy", str(agent), "--env", "CartPole-v1", "--terminated", "unsafe"]
    assert main([*argv, "--eta", "0.5", "--theta", "0.2", "--horizon", "40"]) == 0
    out = capsys.readouterr().out
    assert "RESULT peer episodes_ratio=" in out and "uqdrive_verdict=refuted" in out, out
