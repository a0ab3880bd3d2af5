"""Hydra/OmegaConf glue, as resolvers the stage configs use:

- `${params:KEY,ROOT}` reads a knob from the project's params.yaml. DVC cannot template a list into a
  command line, so stages that take the pipeline's lists (e.g. which scenarios to preprocess) read them
  from params.yaml, the single source of truth; a Hydra CLI override (`scenarios=[straight]`) still wins.
- `${posteriors:ROOT}` is every trained posterior: `mcd` (the trunk every head sits on) and params.yaml's `heads`.
- `${noise_label:NOISE}` is the one text of a noise level in cell names and paths: `noise=0` and
  `noise=0.0` are one cell.
- `${world_locations:WORLD,AXIS}` is every location a Gymnasium world's safety sweep drives: ``<world>-<label>`` per
  value of its condition axis (``sweep.world_axis``), or the world alone (AXIS null).
- `${world_unknown:AXIS,NOISES}` is a Gymnasium world's unknown conditions for the avoid stage: the axis' other
  values and the noisier frames (conf/gym_avoid.yaml).
- `${world_axis:WORLD}` is a Gymnasium world's condition axis, as its own config has it (conf/gym_world/<world>.yaml's
  ``axis``; null: none), for a config that names the world without composing it (conf/gym_findings.yaml).
- `${driver:POLICY,MODEL}` names what drives a cell: a user's policy file's stem (`safety.policy`), else the model.
- `${output_root:ROOT,OUTPUTS}` is where a run writes: the project's pipeline folders when asked
  (`outputs=pipeline`, what `dvc.yaml`'s commands pass), else the run's own Hydra folder (`outputs/<date>/<time>`,
  or the sweep's folder for a multirun), so an ad-hoc run or sweep never overwrites a tracked pipeline output.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import OmegaConf

# The `outputs` key: auto = the run's (or the sweep's) own Hydra folder; pipeline = the project's folders.
OUTPUTS = ("auto", "pipeline")


def read_param(key: str, root: str) -> object:
    path = Path(root) / "params.yaml"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: pass {key}=... on the command line or run from the project root")
    params = yaml.safe_load(path.read_text()) or {}
    if key not in params:
        raise KeyError(f"{path} has no key {key!r}; it has {sorted(params)}")
    return params[key]


def posteriors(root: str) -> list:
    return ["mcd", *read_param("heads", root)]


def controllers(root: str) -> int:
    """The controllers the pipeline drives in closed loop: params.yaml's methods × replicates."""
    return len(read_param("methods", root)) * len(read_param("replicates", root))  # type: ignore[arg-type]


def noise_label(noise: object) -> str:
    """A noise sigma as DVC renders a float of params.yaml (0 and 0.0 → "0.0", 0.05 → "0.05"); a value that
    is not a number is left for the stage's check to reject."""
    if type(noise) not in (int, float):
        return str(noise)
    return repr(float(noise))


def condition_label(location: str, weather: str, noise: object) -> str:
    """location-weather-noise<σ>: a condition in cell names, file names and runs (`uqdrive.sim.condition`)."""
    return f"{location}-{weather}-noise{noise_label(noise)}"


def world_location(world: str, label: str) -> str:
    """The location of a Gymnasium world at its condition axis' value ``label``."""
    return f"{world}-{label}"


def world_locations(world: str, axis: object) -> list[str]:
    """Every location of a Gymnasium world's sweep over ``axis`` (``{key, values: {label: value}}``; None: none)."""
    return [world] if axis is None else [world_location(world, label) for label in axis["values"]]  # type: ignore[index]


def world_unknown(axis: object, noises: object) -> list[dict]:
    """A Gymnasium world's unknown conditions for the avoid stage: each value of ``axis`` but the first (the one
    collected in), and each noise σ > 0 of ``noises`` (`UnknownCondition`s)."""
    values = list(axis["values"].items())[1:] if axis is not None else []  # type: ignore[index]
    changed = [{"name": label, "world": {axis["key"]: value}} for label, value in values]  # type: ignore[index]
    noisier = [{"name": f"noise{noise_label(n)}", "noise": n} for n in noises if float(n) > 0]  # type: ignore[attr-defined]
    return changed + noisier


def find_conf(start: Path | None = None) -> Path:
    """The repo's ``conf/`` directory: searched upwards from the working directory, then from this file."""
    for base in (start or Path.cwd(), Path(__file__).resolve()):
        for d in (base, *base.parents):
            if (d / "conf" / "weather").is_dir():
                return d / "conf"
    raise FileNotFoundError("no conf/weather directory above the working directory or this package")


def world_axis(world: str) -> object:
    """The condition axis of the Gymnasium world ``world`` (its conf/gym_world/<world>.yaml's ``axis``: ``{key,
    values: {label: value}}``), or None where it has none."""
    path = find_conf() / "gym_world" / f"{world}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"world={world!r}: no {path}; choose one of conf/gym_world/")
    return (yaml.safe_load(path.read_text()) or {}).get("axis")


def driver(policy: object, model: str) -> str:
    """A cell's driver in its name: ``steer`` for ``policy=path/steer.onnx``, else the trained model's name."""
    return model if policy in (None, "") else Path(str(policy)).stem


def output_root(root: str, outputs: str) -> str:
    """``root`` with ``outputs=pipeline`` or outside a Hydra job (a config composed in code); else the job's own
    folder: hydra.run.dir for a single run, hydra.sweep.dir for a multirun."""
    if outputs not in OUTPUTS:
        from uqdrive.schema import ConfigError  # here, not at the top: a command's argument path imports this module

        raise ConfigError(f"outputs={outputs!r} is not known; choose one of {list(OUTPUTS)}")
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if outputs == "pipeline" or not HydraConfig.initialized():
        return root
    hydra = HydraConfig.get()
    return str(Path(root) / (hydra.sweep.dir if hydra.mode == RunMode.MULTIRUN else hydra.run.dir))


def register_resolvers() -> None:
    for name, resolver in (
        ("params", read_param),
        ("posteriors", posteriors),
        ("controllers", controllers),
        ("noise_label", noise_label),
        ("world_locations", world_locations),
        ("world_unknown", world_unknown),
        ("world_axis", world_axis),
        ("driver", driver),
        ("output_root", output_root),
    ):
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, resolver)
