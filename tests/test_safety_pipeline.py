"""The `safety` stage on the tiny profile: outputs, MLflow run, reuse of finished cells, clear errors, summary."""

import csv
import json
import shutil

import pytest
from conftest import ALL_TENTHS
from mlflow.tracking import MlflowClient

import uqdrive.safety.runner as runner
from uqdrive.models import save_posterior
from uqdrive.models.checkpoint import load_posterior
from uqdrive.pipeline.safety_stage import run_safety
from uqdrive.pipeline.safety_summary_stage import run_safety_summary
from uqdrive.records import as_dict
from uqdrive.tracking import store_uris


@pytest.fixture
def safety_config(stage_config, random_models):
    def make(*overrides: str):
        folder = random_models["mcd"].parent
        return stage_config("safety", f"safety.model_path={folder}/${{model.name}}.pt", *ALL_TENTHS, *overrides)

    return make


def runs(root):
    client = MlflowClient(store_uris(root)[0])
    experiment = client.get_experiment_by_name("uqdrive/safety")
    return client, (client.search_runs([experiment.experiment_id]) if experiment else [])


def test_cell_writes_its_result_logs_one_run_and_is_reused(safety_config, tmp_path):
    cfg = safety_config("model=hmc", "weather=afternoon", "noise=0.05")
    result = run_safety(cfg)
    assert not result.reused and result.cell.estimate.n == 4 == result.cell.rollouts  # chernoff_n(0.7, 0.05)
    assert result.cell.estimate.scheme == "chernoff" and result.cell.estimate.guaranteed
    assert result.cell.estimate.low <= result.cell.estimate.value <= result.cell.estimate.high
    out = tmp_path / "metrics/safety/hmc-seed0-roundabout-afternoon-noise0.05.json"
    saved = json.loads(out.read_text())
    assert saved == as_dict(result.cell)
    assert (tmp_path / "data/safety/hmc-seed0-roundabout-afternoon-noise0.05.npz").exists()
    assert (tmp_path / "plots/safety/cells/hmc-seed0-roundabout-afternoon-noise0.05.png").stat().st_size > 5000

    client, logged = runs(tmp_path)
    (run,) = logged
    params = run.data.params
    keys = ("method", "experiment", "location", "weather", "noise", "cell_theta", "cell_gamma", "cell_scheme", "n")
    assert {k: params[k] for k in keys} == {
        "method": "hmc",
        "experiment": "offline",
        "location": "roundabout",
        "weather": "afternoon",
        "noise": "0.05",
        "cell_theta": "0.7",
        "cell_gamma": "0.05",
        "cell_scheme": "chernoff",
        "n": "4",
    }
    assert not {"safety.theta", "safety.gamma", "safety.scheme", "theta", "gamma"} & set(params)  # each key once
    assert params["frame_draws.scheme"] == "sequential" and not any(k.startswith("safety.draws") for k in params)
    c = result.cell.estimate
    eta1 = f"η1={c.value:.2f} [{c.low:.2f}, {c.high:.2f}]"
    assert run.info.run_name == f"adhoc · afternoon σ0.05 roundabout · hmc seed0 · {eta1}"
    assert params["safety.base_seed"] == "100000"
    for key in ("eta1", "eta1_low", "eta1_high", "collision_rate", "off_road_rate", "mean_lateral_deviation"):
        assert run.data.metrics[key] == pytest.approx(as_dict(result.cell)[key])
    assert {a.path for a in client.list_artifacts(run.info.run_id)} == {"paths.png", "rollouts.csv"}  # every cell's
    assert run.data.tags["cell"] == "hmc-seed0-roundabout-afternoon-noise0.05"

    # same config, other worker count: reused, nothing rerun; a run tagged reused lists the cell
    stamp = out.stat().st_mtime_ns
    again = run_safety(safety_config("model=hmc", "weather=afternoon", "noise=0.05", "executor.workers=2"))
    assert again.reused and again.cell.estimate.value == result.cell.estimate.value and out.stat().st_mtime_ns == stamp
    first, reused = sorted(runs(tmp_path)[1], key=lambda r: r.info.start_time)
    assert (first.data.tags["reused"], reused.data.tags["reused"]) == ("false", "true")
    assert reused.data.metrics["eta1"] == result.cell.estimate.value and reused.data.params["n"] == "4"
    # another seed is another cell config: recomputed
    assert not run_safety(safety_config("model=hmc", "weather=afternoon", "noise=0.05", "safety.base_seed=7")).reused


def test_a_cell_reruns_when_a_file_its_rollouts_run_changes(safety_config, tmp_path, monkeypatch):
    """The identity covers the posterior's module, which no static import reaches (it is loaded by the name the
    model file records): an edit to how VI draws reruns a VI cell, and leaves an MCD cell reused."""
    src = tmp_path / "src"
    shutil.copytree(runner.SRC / "uqdrive", src / "uqdrive", ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(runner, "SRC", src)
    vi, mcd = safety_config("model=vi"), safety_config("model=mcd")
    assert not run_safety(vi).reused and not run_safety(mcd).reused
    assert run_safety(vi).reused and run_safety(mcd).reused
    with (src / "uqdrive/models/vi.py").open("a") as f:
        f.write("# how a VI head draws changed\n")
    assert not run_safety(vi).reused and run_safety(mcd).reused
    with (src / "uqdrive/uq/estimators.py").open("a") as f:  # the runner's own closure: every cell
        f.write("# an estimator changed\n")
    assert not run_safety(mcd).reused


def test_interrupted_sweep_reruns_only_unfinished_cells(safety_config, tmp_path, monkeypatch):
    cells = [("mcd", "clear_noon"), ("vi", "clear_noon"), ("vi", "rain")]
    configs = [safety_config(f"model={m}", f"weather={w}") for m, w in cells]
    real = runner.make_executor

    def interrupted(*args, **kwargs):
        if interrupted.calls == 1:
            raise KeyboardInterrupt  # Ctrl-C as the second cell's rollouts start
        interrupted.calls += 1
        return real(*args, **kwargs)

    interrupted.calls = 0
    monkeypatch.setattr(runner, "make_executor", interrupted)
    with pytest.raises(KeyboardInterrupt):
        for cfg in configs:
            run_safety(cfg)
    monkeypatch.setattr(runner, "make_executor", real)
    assert not (tmp_path / "metrics/safety/vi-seed0-roundabout-clear_noon-noise0.0.json").exists()
    assert [run_safety(cfg).reused for cfg in configs] == [True, False, False]
    assert sorted(r.data.tags["reused"] for r in runs(tmp_path)[1]) == ["false", "false", "false", "true"]


def test_a_cell_interrupted_mid_way_keeps_its_finished_rollouts(safety_config, tmp_path, monkeypatch):
    cfg = safety_config("model=vi")  # chernoff_n(0.7, 0.05) = 4 rollouts
    real = runner.make_executor
    ran: list[int] = []

    class Interrupting:
        def __init__(self, inner, stop_after):
            self.inner, self.stop_after = inner, stop_after

        def run(self, indices):
            for result in self.inner.run(indices):
                if len(ran) == self.stop_after:
                    raise KeyboardInterrupt
                ran.append(result.seed)
                yield result

        def close(self):
            self.inner.close()

    monkeypatch.setattr(runner, "make_executor", lambda *a, **k: Interrupting(real(*a, **k), 2))
    with pytest.raises(KeyboardInterrupt):
        run_safety(cfg)
    monkeypatch.setattr(runner, "make_executor", lambda *a, **k: Interrupting(real(*a, **k), None))
    result = run_safety(cfg)
    assert ran == [100000, 100001, 100002, 100003] and result.cell.estimate.n == 4  # the first two were not rerun
    rows = (tmp_path / "plots/safety/cells/vi-seed0-roundabout-clear_noon-noise0.0.csv").read_text().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == [100000, 100001, 100002, 100003]


def test_sequential_scheme_uses_consecutive_seeds(safety_config, tmp_path):
    result = run_safety(safety_config("model=vi", "safety.scheme=sequential", "safety.theta=0.45"))
    assert result.cell.estimate.scheme == "sequential" and result.cell.estimate.guaranteed
    rows = (tmp_path / "plots/safety/cells/vi-seed0-roundabout-clear_noon-noise0.0.csv").read_text().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == list(range(100000, 100000 + result.cell.estimate.n))


@pytest.mark.parametrize(
    ("overrides", "error", "match"),
    [
        (("model.name=lasso",), ValueError, r"model.name='lasso' does not match model._target_ VIPosterior"),
        (
            ("safety.model_path=/nonexistent/vi.pt",),
            ValueError,
            r"^safety.model_path=/nonexistent/vi.pt does not exist; train it first: dvc repro train@offline-vi$",
        ),
        (("safety.theta=1.5",), ValueError, r"safety.theta=1.5: input should be less than 1"),
        (("safety.gamma=0",), ValueError, r"safety.gamma=0: input should be greater than 0"),
        (
            ("safety.scheme=bootstrap",),
            ValueError,
            r"safety.scheme='bootstrap': input should be 'chernoff'",
        ),
        (("safety.speed=50",), ValueError, r"safety.speed=50.0 must be <= vehicle.max_speed=20.0"),
        (("safety.samples=0",), ValueError, r"safety.samples=0: input should be greater than or equal to 1"),
        (("safety.half_width=0",), ValueError, r"safety.half_width=0: input should be greater than 0"),
        (("executor.workers=0",), ValueError, r"executor.workers=0: input should be greater than or equal to 1"),
        (("noise=-0.1",), ValueError, r"noise=-0.1: input should be greater than or equal to 0"),
        (("safety.horizon_s=0",), ValueError, r"safety.horizon_s=0: input should be greater than 0"),
    ],
)
def test_bad_input_fails_before_any_rollout(safety_config, tmp_path, monkeypatch, overrides, error, match):
    def no_rollouts(*args, **kwargs):
        raise AssertionError("rollouts started")

    monkeypatch.setattr(runner, "make_executor", no_rollouts)
    with pytest.raises(error, match=match):
        run_safety(safety_config("model=vi", *overrides))
    assert not (tmp_path / "metrics").exists() and not (tmp_path / "mlflow.db").exists()


def test_model_of_another_method_is_refused(safety_config, random_models):
    with pytest.raises(ValueError, match="holds a 'mcd' model, expected 'vi'"):
        run_safety(safety_config("model=vi", f"safety.model_path={random_models['mcd']}"))


@pytest.mark.slow
def test_summary_answers_per_method_over_replicates_and_draws_one_grid_per_location_and_noise(
    safety_config, stage_config, tmp_path
):
    for method in ("mcd", "vi"):
        for location in ("roundabout", "roundabout_town"):
            for seed in (0, 1):  # a second replicate (here the same network: plumbing), on the same rollout seeds
                run_safety(safety_config(f"model={method}", "noise=0", f"scenario={location}", f"seed={seed}"))
    summary = run_safety_summary(
        stage_config(
            "safety_summary",
            "methods=[mcd,vi]",
            "replicates=[0,1]",
            "weathers=[clear_noon]",
            "noises=[0]",
            "locations=[roundabout,roundabout_town]",
        )
    )
    assert json.loads((tmp_path / "metrics/safety.json").read_text()) == as_dict(summary)
    answer = summary.answer("vi", "roundabout_town", "clear_noon", 0)  # noise=0 and 0.0 are one cell
    cells = [
        json.loads((tmp_path / f"metrics/safety/vi-seed{r}-roundabout_town-clear_noon-noise0.0.json").read_text())
        for r in (0, 1)
    ]
    assert answer.replicates == [0, 1] and answer.rollouts == 4 == cells[0]["n"]
    assert answer.estimates == [c["eta1"] for c in cells] and answer.value == pytest.approx(sum(answer.estimates) / 2)
    assert 0 <= answer.low <= answer.value <= answer.high <= 1 and "hoeffding" in answer.interval
    assert summary.family_size == 1 and summary.cell_gamma == 0.05
    for location in ("roundabout", "roundabout_town"):
        assert (tmp_path / f"plots/safety/summary/hexbin_{location}_noise0.0.png").stat().st_size > 5000
    with (tmp_path / "plots/safety/failure_modes.csv").open() as f:  # `dvc plots`: a bar per mode of method × weather
        modes = list(csv.DictReader(f))
    failing = sum(
        json.loads(p.read_text())["outcomes"].count("0") for p in (tmp_path / "metrics/safety").glob("*-clear_noon-*")
    )
    assert sum(int(m["count"]) for m in modes) == failing and {m["group"] for m in modes} <= {
        "mcd clear_noon",
        "vi clear_noon",
    }
    with pytest.raises(FileNotFoundError, match="hmc-seed0-roundabout-clear_noon-noise0.0.json is missing"):
        run_safety_summary(
            stage_config(
                "safety_summary",
                "methods=[hmc]",
                "replicates=[0]",
                "weathers=[clear_noon]",
                "noises=[0]",
                "locations=[roundabout]",
            )
        )


USER_POSTERIOR = """from uqdrive.models.mcd import MCDPosterior


class UserMCD(MCDPosterior):
    method = "user_mcd"
"""


def test_a_cell_reruns_when_a_user_posteriors_package_changes(safety_config, random_models, tmp_path, monkeypatch):
    """A posterior of the user's, loaded by ``_target_`` from a package outside uqdrive: editing its module, or
    another file of its package that it might import, is a new cell (its cached outcomes are not replayed)."""
    package = tmp_path / "site" / "h68_user_posterior"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "heads.py").write_text(USER_POSTERIOR)
    monkeypatch.syspath_prepend(str(package.parent))
    from h68_user_posterior.heads import UserMCD

    mcd = load_posterior(random_models["mcd"])
    model = UserMCD(mcd.arch, mcd.bins)
    model.load_state_dict(mcd.state_dict())
    path = save_posterior(model.eval(), tmp_path / "models/user_mcd.pt")
    conf = tmp_path / "user_conf/model"
    conf.mkdir(parents=True)
    (conf / "user_mcd.yaml").write_text(
        "defaults: [mcd, _self_]\nname: user_mcd\n_target_: h68_user_posterior.heads.UserMCD\n"
    )
    cfg = safety_config(
        "model=user_mcd", f"safety.model_path={path}", f"hydra.searchpath=[file://{conf.parent}]", "safety.clips=0"
    )
    assert not run_safety(cfg).reused and run_safety(cfg).reused
    (package / "heads.py").write_text(USER_POSTERIOR + "# its steering changed\n")
    assert not run_safety(cfg).reused
    (package / "helpers.py").write_text("GAIN = 2.0\n")  # a module of its package, which it might import
    assert not run_safety(cfg).reused and run_safety(cfg).reused
