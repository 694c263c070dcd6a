"""A real Ray cluster on this machine (``ray start``: a head without CPUs and two worker nodes of one CPU,
each on its own ports, loopback only, token authentication as a cluster has it): ``raico exp run
--executor ray --address`` runs an experiment across it into one artifacts folder while a worker node is
killed mid-run; the runs table equals a serial run's value by value. A node started with other code is
then refused in one line that names it. Every process the test started is killed by the end (found by a
mark in their environment, never by name)."""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow,   # the processes are found in /proc
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds its processes in /proc")]

ROOT = Path(__file__).resolve().parents[2]
MARK = "RAICO_TEST_CLUSTER"
EXPERIMENT = '''
name = "cluster"
stages = ["plan"]
seeds = "range(2)"
[base]
plant = "pendulum"
task = "swing-up"
dynamics = "analytic"
solver = "raico"
iterations = 30                # runs of about 0.2 s: the node is killed while runs are in flight
q0_std = 0.05
[grid]
alpha = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
'''


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Cluster:
    """Ray nodes started with ``ray start`` on 127.0.0.1, each process marked ``MARK=<token>-<node>``."""

    def __init__(self, tmp: Path) -> None:
        self.token = secrets.token_hex(4)
        self.auth = tmp / "ray_token"
        self.auth.write_text(secrets.token_hex(32))
        # a short root of Ray's session folders (its sockets' paths are limited to 107 characters)
        self.temp = Path(f"/tmp/raico-rc-{self.token}")
        self.port = _free_port()
        self.env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN_PATH": str(self.auth),
                    "PYTHONPATH": str(ROOT), "RAY_health_check_period_ms": "500",
                    "RAY_health_check_failure_threshold": "4", "RAY_health_check_initial_delay_ms": "0"}

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def start(self, node: str, cpus: int, pythonpath: Path = ROOT) -> None:
        args = [str(Path(sys.executable).parent / "ray"), "start", "--node-ip-address", "127.0.0.1",
                "--num-cpus", str(cpus), "--disable-usage-stats", "--object-store-memory", str(80 * 2**20)]
        for flag in ("--node-manager-port", "--object-manager-port", "--dashboard-agent-listen-port",
                     "--dashboard-agent-grpc-port", "--runtime-env-agent-port", "--metrics-export-port"):
            args += [flag, str(_free_port())]
        args += (["--head", "--port", str(self.port), "--include-dashboard", "false", "--temp-dir", str(self.temp)]
                 if node == "head" else ["--address", self.address])
        env = {**self.env, MARK: f"{self.token}-{node}", "PYTHONPATH": str(pythonpath)}
        res = subprocess.run(args, env=env, capture_output=True, text=True, timeout=90)
        assert res.returncode == 0, res.stderr[-2000:]

    def pids(self, node: str = "") -> list[int]:
        """Processes marked as this cluster's (``node``: only that node's)."""
        mark = f"{MARK}={self.token}-{node}".encode()
        out = []
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            except OSError:
                continue
            if any(e.startswith(mark) for e in env):
                out.append(int(pid))
        return out

    def kill(self, node: str = "") -> None:
        for _ in range(3):   # a raylet may start a worker while its siblings die
            for pid in self.pids(node):
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            time.sleep(0.2)


@pytest.fixture
def cluster(tmp_path):
    pytest.importorskip("ray")
    c = Cluster(tmp_path)
    try:
        yield c
    finally:
        c.kill()
        shutil.rmtree(c.temp, ignore_errors=True)
        assert not c.pids(), "Ray processes of the test cluster are left"


def test_an_experiment_across_a_cluster_survives_a_killed_node_and_equals_a_serial_run(cluster, tmp_path):
    from raico.pipeline.engine.cache import Cache
    from raico.pipeline.engine.executors import make_executor
    from raico.pipeline.experiments import expfile

    t0 = time.monotonic()
    cluster.start("head", 0)
    cluster.start("w1", 1)
    cluster.start("w2", 1)
    exp_file = tmp_path / "cluster.toml"
    exp_file.write_text(EXPERIMENT)
    arts = tmp_path / "arts"
    cmd = [str(Path(sys.executable).parent / "raico"), "exp", "run", str(exp_file), "--executor", "ray",
           "--address", cluster.address, "--artifacts", str(arts), "--json"]
    env = {**cluster.env, MARK: f"{cluster.token}-driver"}
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:   # kill node w1 once 4 runs are done
            if (arts / "plan").is_dir() and sum(1 for p in (arts / "plan").iterdir() if not p.name.startswith(".")) >= 4:
                cluster.kill("w1")
                break
            time.sleep(0.05)
        killed_at = len(list((arts / "plan").iterdir()))
        out, err = proc.communicate(timeout=max(5.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert killed_at < 16, "the experiment ended before the node was killed"
    summary = json.loads(out.splitlines()[-1])
    assert (summary["runs"], summary["errors"]) == (16, 0)
    df, _ = expfile.read_table(Cache(arts), "cluster")
    serial = expfile.run(Cache(tmp_path / "serial"), expfile.load(exp_file), make_executor("serial", 1))
    columns = ["variant", "alpha", "seed", "plan.key", "status", "plan.final_cost", "plan.cost.first",
               "plan.cost.min", "plan.iterations", "plan.code_version"]
    assert df[columns].to_dict("records") == [{c: r[c] for c in columns} for r in serial]

    # a node whose code differs (a comment added to one file of a copy) is refused in one line naming it
    other = tmp_path / "other"
    shutil.copytree(ROOT / "raico", other / "raico", ignore=shutil.ignore_patterns("__pycache__"))
    with open(other / "raico" / "planning" / "__init__.py", "a") as f:
        f.write("# another version\n")
    cluster.start("w3", 1, pythonpath=other)
    res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=90)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 1 and len(lines) == 1, res.stderr[-3000:]
    assert re.fullmatch(r"raico: error: node \S+ \(Ray node [0-9a-f]{12}\) runs code version raico\+[0-9a-f]{12}, "
                        r"this head raico\+[0-9a-f]{12}: its results are refused \(.*\)", lines[0]), lines[0]
    assert time.monotonic() - t0 < 150
