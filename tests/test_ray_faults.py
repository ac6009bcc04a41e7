"""Ray faults. A killed `fuse --backend ray` leaves no process of its Ray instance behind;
a cluster whose every node is gone stops the run within a bounded time (common.backend's node
timeout, docs/scaling.md) with one line, and the same command resumes once a node is back."""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from test_robustness import descendants, error_lines, survivors_of_kill_9, wait_until

ROOT = Path(__file__).resolve().parents[1]
LOOPBACK = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
NODE_TIMEOUT_S = 3
# how fast Ray's control store declares a killed node dead (its default is about 15 s)
FAST_HEALTH_CHECKS = {"health_check_initial_delay_ms": 0, "health_check_period_ms": 500, "health_check_failure_threshold": 2}


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    return dict(env, PYTHONPATH=str(ROOT), **LOOPBACK, **extra)


def _unfused(tiny_dataset, tmp_path) -> Path:
    ds = tmp_path / "ds"
    shutil.copytree(tiny_dataset, ds)
    for d in ds.glob("*/*/labels"):
        shutil.rmtree(d)
    return ds


def _fused(ds) -> int:
    return len(list(ds.glob("*/*/labels/visibility.png")))


def test_kill_9_of_fuse_on_its_own_ray_leaves_no_process(tiny_dataset, tmp_path):
    ds = _unfused(tiny_dataset, tmp_path)
    p = subprocess.Popen([sys.executable, "-m", "dataset_tools", "fuse", str(ds), "--backend", "ray", "--workers", "1",
                          "--no-progress"], cwd=ROOT, env=_env(), stderr=subprocess.PIPE)
    # Ray's raylet, its agents and a worker running fusion: then kill the command alone
    wait_until(lambda: _fused(ds) >= 1 and len(descendants(p.pid)) >= 4, p, timeout=180, what="Ray fused a frame")
    # Ray's agents are children of its raylet, started after it: the guard finds them by walking the
    # whole tree every 0.2 s and kills them (1-2 s with both cores busy; the bound leaves room, docs/errors.md)
    assert not survivors_of_kill_9(p, after_s=10.0), "a process of fuse's Ray instance outlived it by 10 s"


@pytest.fixture
def one_node_cluster():
    """A head with no CPU and one node with one CPU: the node is all the cluster has to run on."""
    os.environ.update(LOOPBACK)
    from ray.cluster_utils import Cluster

    try:
        cluster = Cluster(initialize_head=True, head_node_args={
            "num_cpus": 0, "include_dashboard": False, "node_ip_address": "127.0.0.1", "_system_config": FAST_HEALTH_CHECKS})
        node = cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
    except Exception as exc:  # noqa: BLE001 - Ray genuinely cannot start here
        pytest.skip(f"Ray cannot start a local cluster: {exc}")
    try:
        yield cluster, node
    finally:
        cluster.shutdown()


def test_every_node_gone_stops_within_the_node_timeout_and_resumes(one_node_cluster, tiny_dataset, tmp_path):
    cluster, node = one_node_cluster
    ds = _unfused(tiny_dataset, tmp_path)
    argv = [sys.executable, "-m", "dataset_tools", "fuse", str(ds), "--backend", "ray", "--address", cluster.address,
            "--workers", "1", "--no-progress"]
    env = _env(FISHEYE_BEV_RAY_NODE_TIMEOUT_S=str(NODE_TIMEOUT_S))
    p = subprocess.Popen(argv, cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: _fused(ds) >= 1, p, timeout=180, what="a frame fused")
    cluster.remove_node(node, allow_graceful=False)  # every node with a CPU killed mid-run
    t0 = time.monotonic()
    _, err = p.communicate(timeout=120)
    waited = time.monotonic() - t0
    assert p.returncode == 1 and "Traceback" not in err, err
    assert error_lines(err) == [
        f"error: --backend ray: no live Ray node with a CPU for {NODE_TIMEOUT_S} s; finished work is kept: "
        "run the same command again when the cluster is back"], err
    assert waited < NODE_TIMEOUT_S + 20, f"took {waited:.0f} s"  # detection (fast health checks here) + the timeout
    done = _fused(ds)
    assert 1 <= done < 14
    # resumable: with a node back, the same command fuses only what is missing, and equals the local run
    cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
    r = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    import cv2

    for f in sorted(tiny_dataset.glob("*/*/labels/*.png")):
        mine = ds / f.relative_to(tiny_dataset)
        assert np.array_equal(cv2.imread(str(mine), cv2.IMREAD_UNCHANGED), cv2.imread(str(f), cv2.IMREAD_UNCHANGED)), f


def test_fuse_workers_caps_the_ray_batches(monkeypatch):
    """`fuse --workers N --backend ray` is used: at most N batches are submitted at once."""
    from common import backend

    class FakeRay:
        def __init__(self):
            self.pending, self.most = set(), 0

        def cluster_resources(self):
            return {"CPU": 8}

        def remote(self, **kw):
            ray = self

            class Task:
                @staticmethod
                def remote(fn, jobs, shared):
                    ref = (id(jobs), tuple(fn(j, shared) for j in jobs))
                    ray.pending.add(ref)
                    ray.most = max(ray.most, len(ray.pending))
                    return ref
            return lambda fn: Task

        def put(self, x):
            return x

        def wait(self, refs, num_returns=1, timeout=None):
            self.pending.discard(refs[0])
            return refs[:1], refs[1:]

        def get(self, ref):
            return list(ref[1])

        def nodes(self):
            return [{"Alive": True, "Resources": {"CPU": 8}}]

    b = backend.RayBackend.__new__(backend.RayBackend)
    b.ray, b.workers = FakeRay(), 2
    assert sorted(b.map(lambda j, s: j * s, list(range(40)), shared=3, batch=4)) == [j * 3 for j in range(40)]
    assert b.ray.most == 2
