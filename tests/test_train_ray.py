"""Training replicates on Ray (``executor=ray``): a replicate's model is the one the process pool trains, on one
machine; a tiny study (trunk, heads, safety cells) runs on a two-node Ray cluster on loopback with the same stages;
an address nobody answers at stops the stage before any training."""

import json

import pytest
import ray_kit
import torch
from hydra import compose, initialize_config_dir
from test_train import CONF, write_processed

from uqdrive.pipeline.train_stage import run_train_replicates
from uqdrive.records import as_dict
from uqdrive.schema import ConfigError

ROOT = ray_kit.ROOT
STUDY = ["profile=tiny", "progress=false", "experiment=joint", "train.workers=2"]


def train_here(root, method: str, *overrides: str):
    args = [f"paths.root={root}", *STUDY, f"model={method}", *overrides]
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return run_train_replicates(compose("train_replicates", [*args, "replicates=[0,1]"]), args)


def stage(env, root, script: str, *args: str) -> None:
    ray_kit.run_stage(env, root, script, f"paths.root={root}", *args)


def states(root, method: str) -> list[dict]:
    return [torch.load(root / f"models/joint/{method}/seed{s}.pt")["state"] for s in (0, 1)]


def same_models(a, b, method: str) -> bool:
    return all(all(torch.equal(x[k], y[k]) for k in x) for x, y in zip(states(a, method), states(b, method)))


def frames(root) -> None:
    write_processed(root / "data/processed/joint/train.parquet", 160, seed=1)
    write_processed(root / "data/processed/joint/val.parquet", 80, seed=2)


def test_a_ray_address_that_does_not_answer_stops_the_stage_before_any_training(tmp_path):
    frames(tmp_path)
    address = f"ray://127.0.0.1:{ray_kit.free_port()}"
    pytest.importorskip("ray")
    with pytest.raises(ConfigError, match=rf"^executor.address='{address}': no Ray cluster answers there"):
        train_here(tmp_path, "mcd", "executor=ray", f"executor.address={address}")
    assert not (tmp_path / "models").exists()


@pytest.mark.slow
def test_a_tiny_study_on_a_two_node_ray_cluster_trains_the_models_the_process_pool_does(tmp_path):
    """Trunk, then heads, then a safety cell per replicate, each stage as `dvc repro` runs it with `executor=ray
    executor.address=auto`: two actors of one CPU each on two one-CPU nodes (so both nodes train), and every model
    bit for bit the process pool's on this machine."""
    pytest.importorskip("ray")
    local, cluster = tmp_path / "local", tmp_path / "cluster"
    for root in (local, cluster):
        frames(root)
    (cluster / "params.yaml").write_text("replicates: [0, 1]\n")  # what train_replicates reads, as under dvc repro
    here = {m: [as_dict(r) for r in train_here(local, m).replicates] for m in ("mcd", "vi")}
    ray_args = ["executor=ray", "executor.address=auto", "executor.workers=2"]
    with ray_kit.ray_nodes(cpus=(1, 1)) as env:
        for method in ("mcd", "vi"):
            stage(env, cluster, "train_replicates.py", *STUDY, f"model={method}", *ray_args)
        for seed in (0, 1):
            cell = ["profile=tiny", "progress=false", "experiment=joint", "model=vi", f"seed={seed}", *ray_args]
            stage(env, cluster, "safety.py", *cell, f"safety.model_path={cluster}/models/joint/vi/seed{seed}.pt")
    for method in ("mcd", "vi"):
        assert same_models(local, cluster, method)
        remote = [json.loads((cluster / f"metrics/joint/train/{method}/seed{s}.json").read_text()) for s in (0, 1)]
        assert [{k: v for k, v in r.items() if k != "train_seconds"} for r in remote] == [
            {k: v for k, v in r.items() if k != "train_seconds"} for r in here[method]
        ]
    assert len(list((cluster / "metrics/safety").glob("vi-seed*-roundabout-clear_noon-noise0.0.json"))) == 2
