"""A stable-baselines3 agent file (``model.save(path)``: a ``.zip``) as a `Policy` (`pip install
'uqdrive[sb3]'`): its policy network rebuilt from the file alone (no algorithm, no env), asked for its deterministic
action every frame.

Its observation space must be a frame uqdrive delivers: grey uint8 [48, 64] as uqdrive's Gymnasium env observes
(`uqdrive.sim.gym_env`, where to train it), [1, 48, 64] or [48, 64, 1]; or RGB [H, W, 3] at the rendered size. Its
action space: [steer] or [steer, speed (m/s)] (a Box), or Discrete(C) over the configured steering classes. It
gives no draws: no η2.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH, preprocess_frame
from uqdrive.policy.interface import Action
from uqdrive.policy.slots import PolicyFailure
from uqdrive.policy.tensor_policies import first_line

SB3_MISSING = "a stable-baselines3 agent needs stable-baselines3, which is not installed: pip install 'uqdrive[sb3]'"
GREY = {(INPUT_HEIGHT, INPUT_WIDTH): (), (1, INPUT_HEIGHT, INPUT_WIDTH): (0,), (INPUT_HEIGHT, INPUT_WIDTH, 1): (2,)}


class SB3Policy:
    """One slot's view of a loaded agent (the slots of a worker share its network: it keeps no state)."""

    needs_camera = True

    def __init__(self, path: str, centres: np.ndarray, policy: Any):
        self.path, self.centres, self.policy = str(path), np.asarray(centres, dtype=np.float64), policy
        space, actions = policy.observation_space, policy.action_space
        shape = tuple(getattr(space, "shape", None) or ())
        if getattr(space, "dtype", None) != np.uint8 or not (shape in GREY or (len(shape) == 3 and shape[2] == 3)):
            raise PolicyFailure(
                f"{path}: expected an agent observing uqdrive's frame (uint8 grey [48, 64], [1, 48, 64], [48, 64, 1] "
                f"or RGB [H, W, 3]), got observation space {space} (an agent of an env's own observation: certify it "
                "in that env, --env ID)"
            )
        discrete = getattr(actions, "n", None)
        box = discrete is None and getattr(actions, "shape", None) in ((1,), (2,))
        if not (box or discrete == len(self.centres)):
            raise PolicyFailure(
                f"{path}: expected an action space [steer], [steer, speed] or Discrete({len(self.centres)}) over the "
                f"steering classes, got {actions}"
            )
        self.shape, self.discrete = shape, discrete is not None

    @classmethod
    def loader(cls, path: str, centres: np.ndarray) -> Callable[[], SB3Policy]:
        """Slot instances sharing one load of ``path`` (its spaces checked here, before any rollout)."""
        policy = load_sb3(path)
        cls(path, centres, policy)
        return lambda: cls(path, centres, policy)

    def reset(self, seed: int) -> None:
        """Deterministic: nothing to seed."""

    def act(self, frame: np.ndarray | None, info: dict) -> Action:
        action, _ = self.policy.predict(self.observation(frame), deterministic=True)
        action = np.asarray(action).reshape(-1)
        if self.discrete:
            return Action(float(self.centres[int(action[0])]))
        return Action(float(action[0]), float(action[1]) if action.size > 1 else None)

    def observation(self, frame: np.ndarray | None) -> np.ndarray:
        """The frame in the agent's observation space."""
        if frame is None:
            raise PolicyFailure(f"{self.path}: an agent needs the camera frame (render=True)")
        if self.shape in GREY:
            return np.expand_dims(preprocess_frame(frame), GREY[self.shape])
        if frame.shape != self.shape:
            raise PolicyFailure(f"{self.path}: expected RGB frames of shape {self.shape}, got {frame.shape}")
        return frame


def _no_learning(_progress: float) -> float:
    """The learning-rate schedule a policy's constructor asks for: it is never trained here."""
    return 0.0


def load_sb3(path: str | Path) -> Any:
    """The agent's policy network in evaluation mode, or one line naming the file and what it is instead."""
    try:
        from stable_baselines3.common.save_util import load_from_zip_file
    except ImportError:
        raise PolicyFailure(SB3_MISSING) from None
    try:
        data, params, _ = load_from_zip_file(str(path), device="cpu", print_system_info=False)
        spaces = data["observation_space"], data["action_space"]
        policy = data["policy_class"](*spaces, _no_learning, **data.get("policy_kwargs", {}))
        policy.load_state_dict(params["policy"])
    except Exception as err:  # a zip of something else: KeyError, ValueError, zipfile's or torch's errors
        raise PolicyFailure(f"{path}: expected a stable-baselines3 agent (model.save), got {first_line(err)}") from None
    policy.set_training_mode(False)
    return policy
