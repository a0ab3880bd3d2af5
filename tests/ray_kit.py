"""A real Ray cluster on loopback for the tests, started as a user would (`ray start --head`, then `ray start
--address` for each further node), always stopped: only this cluster's processes are ended."""

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _end_processes_of(session_dir: str) -> None:
    """End this cluster's processes (every one names its temp dir on its command line), by pid: `ray stop`
    would end every Ray process of the user on this machine, other people's clusters too."""

    def ours() -> list[int]:
        pids = []
        for proc in Path("/proc").iterdir():
            try:
                if proc.name.isdigit() and session_dir.encode() in (proc / "cmdline").read_bytes():
                    pids.append(int(proc.name))
            except OSError:
                continue
        return pids

    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in ours():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + 5
        while ours() and time.monotonic() < deadline:
            time.sleep(0.2)


def _environment(address: str) -> dict:
    # RAY_ADDRESS: `address=auto` reads it first (else the shared /tmp/ray/ray_current_cluster, maybe someone else's).
    # RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0: a driver keeps 127.0.0.1 as is; Ray otherwise swaps a loopback
    # address for the machine's outward IP, where a loopback-only cluster does not listen.
    return {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])),
        "RAY_ADDRESS": address,
        "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
        "RAY_AUTH_MODE": "disabled",
    }  # loopback only; else a token in ~/.ray turns auth on for the head alone


@contextlib.contextmanager
def ray_cluster() -> Iterator[tuple[dict, Path]]:
    """A one-node cluster of 2 CPUs on 127.0.0.1, started as a user would (`ray start --head`); yields the
    environment a driver joins it with (``RAY_ADDRESS``) and the cluster's temp dir."""
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths live under it
    address = f"127.0.0.1:{free_port()}"
    env = _environment(address)
    try:
        subprocess.run(
            [
                str(Path(sys.executable).parent / "ray"),
                "start",
                "--head",
                "--node-ip-address=127.0.0.1",
                f"--port={address.rsplit(':', 1)[1]}",
                "--num-cpus=2",
                "--include-dashboard=false",
                "--disable-usage-stats",
                f"--temp-dir={temp_dir}",
            ],
            env=env,
            check=True,
            capture_output=True,
            text=True,
            timeout=180,
        )
        yield env, Path(temp_dir)
    finally:
        _end_processes_of(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)


@contextlib.contextmanager
def ray_nodes(cpus: tuple[int, ...]) -> Iterator[dict]:
    """A cluster of ``len(cpus)`` nodes on 127.0.0.1, node i with ``cpus[i]`` CPUs: Ray's own multi-node test
    cluster (`ray.cluster_utils.Cluster`: a raylet per node; a second `ray start --address` on one host is refused
    or hangs). Yields the environment a driver joins it with; every node is stopped after."""
    from ray.cluster_utils import Cluster

    before = {k: v for k, v in os.environ.items() if k.startswith("RAY_")}  # the cluster sets RAY_ADDRESS here
    os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # as its drivers join it (`_environment`): a fresh HOME turns a token on
    head, *others = cpus
    common = {"node_ip_address": "127.0.0.1"}
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": head, "include_dashboard": False, **common})
    try:
        for n in others:
            cluster.add_node(num_cpus=n, **common)
        cluster.wait_for_nodes(timeout=120)
        yield _environment(cluster.address)
    finally:
        cluster.shutdown()
        for key in [k for k in os.environ if k.startswith("RAY_")]:  # a later local Ray must not join a dead cluster
            del os.environ[key]
        os.environ.update(before)


def run_stage(env: dict, cwd: Path, script: str, *args: str) -> None:
    """``python stages/<script> <args> outputs=pipeline`` in ``cwd`` as a driver of the cluster ``env`` names; fails
    the test with the stage's own error output."""
    run = subprocess.run(
        [sys.executable, str(ROOT / "stages" / script), *args, "outputs=pipeline"],
        cwd=cwd,
        env={**env, "PYTHONWARNINGS": "ignore"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
