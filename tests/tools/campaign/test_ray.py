"""Ray: the shipped smoke campaign gives the pool's results.csv on a local Ray (``--ray auto``)
and on a two-node cluster (``ray start --head`` and a second ``ray start --address``, one CPU
each). Every Ray process lives in a network namespace of its own with only loopback up
(``unshare -n``), and in its own PID namespace, so nothing is left running after the test."""
from __future__ import annotations

import importlib.util
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import campaign_cmd


def _why_not() -> str | None:
    if importlib.util.find_spec("ray") is None:
        return 'Ray is not installed (pip install "swerve[cluster]")'
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs unshare and ip (util-linux, iproute2) to keep Ray on a private loopback"
    if os.geteuid() != 0:
        return "needs root for unshare -n (a private network namespace for Ray)"
    probe = subprocess.run(["unshare", "-n", "-p", "-f", "--mount-proc", "sh", "-c", "ip link set lo up"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        return f"unshare -n -p is not permitted here: {probe.stderr.strip()}"
    return None


pytestmark = [pytest.mark.slow, pytest.mark.skipif(_why_not() is not None, reason=_why_not() or "")]
RAY = str(Path(sys.executable).with_name("ray"))


def in_namespace(script: str, timeout: float = 540) -> subprocess.CompletedProcess:
    """Run ``script`` (sh) with loopback up in fresh network and PID namespaces."""
    env = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}
    return subprocess.run(["unshare", "-n", "-p", "-f", "--mount-proc", "sh", "-c",
                           "set -e; ip link set lo up; " + script],
                          capture_output=True, text=True, timeout=timeout, env=env)


def sh(argv: list[str]) -> str:
    return shlex.join(argv)


def test_local_ray_gives_the_pools_results(smoke_pool, tmp_path):
    out = tmp_path / "ray"
    proc = in_namespace(sh(campaign_cmd("run", "smoke", "--out", str(out), "--ray", "auto", "--workers", "2",
                                        "--no-plots")))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "results.csv").read_bytes() == (smoke_pool / "results.csv").read_bytes()


def test_two_node_cluster_gives_the_pools_results(smoke_pool, tmp_path):
    out = tmp_path / "cluster"
    port = 6391
    nodes = (f"import ray; ray.init(address='127.0.0.1:{port}', log_to_driver=False); "
             f"print('alive nodes', sum(n['Alive'] for n in ray.nodes()))")
    script = "; ".join([
        f"trap '{RAY} stop --force >/dev/null 2>&1' EXIT",
        f"{RAY} start --head --port {port} --node-ip-address 127.0.0.1 --num-cpus 1 --include-dashboard false "
        f"--disable-usage-stats >{tmp_path}/head.log 2>&1",
        f"{RAY} start --address 127.0.0.1:{port} --node-ip-address 127.0.0.1 --num-cpus 1 --disable-usage-stats "
        f">{tmp_path}/node.log 2>&1",
        sh([sys.executable, "-c", nodes]),
        sh(campaign_cmd("run", "smoke", "--out", str(out), "--ray", f"127.0.0.1:{port}", "--no-plots")),
    ])
    proc = in_namespace(script)
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-1000:]
    assert "alive nodes 2" in proc.stdout
    assert (out / "results.csv").read_bytes() == (smoke_pool / "results.csv").read_bytes()


def test_ray_missing_is_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    (tmp_path / "ray.py").write_text("raise ImportError('no ray here')\n")
    proc = subprocess.run(campaign_cmd("run", "smoke", "--out", str(tmp_path / "out"), "--ray", "auto"),
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0
    assert 'pip install "swerve[cluster]"' in proc.stderr
