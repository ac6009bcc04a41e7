"""Rendering and fusion on a real two-node Ray cluster (ray.cluster_utils.Cluster on loopback,
one CPU per node) equal the local pool's output file by file; a Ray worker killed mid-run and a
killed driver cost nothing but a reschedule; `merge` of two shard folders equals one run (and goes on
to fuse, audit and report it, as `python -m dataset_tools dataset` does after rendering)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from dataset_tools.format.layout import Manifest
from test_scenes import _same_frame

ROOT = Path(__file__).resolve().parents[1]
TINY = "configs/dataset/tiny.yaml"
LOOPBACK = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}


@pytest.fixture(scope="module")
def ray_cluster():
    """Two Ray nodes with one CPU each, every address on 127.0.0.1, no dashboard."""
    os.environ.update(LOOPBACK)
    from ray.cluster_utils import Cluster

    try:
        cluster = Cluster(initialize_head=True, head_node_args={
            "num_cpus": 1, "include_dashboard": False, "node_ip_address": "127.0.0.1"})
        cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
    except Exception as exc:  # noqa: BLE001 - Ray genuinely cannot start here
        pytest.skip(f"Ray cannot start a local cluster: {exc}")
    try:
        yield cluster.address
    finally:
        cluster.shutdown()


def _generate(address, out, *extra):
    return subprocess.Popen([sys.executable, "-m", "dataset_tools", "generate", "--config", TINY, "--out", str(out),
                             "--backend", "ray", "--address", address, "--no-progress", *extra],
                            cwd=ROOT, env=dict(os.environ, **LOOPBACK), stderr=subprocess.PIPE, text=True)


def _wait_for_frames(out, n, proc, timeout=300):
    t0 = time.time()
    while len(Manifest(out).done()) < n:
        assert proc.poll() is None, f"generate ended before {n} frames: {proc.stderr.read()[-2000:]}"
        assert time.time() - t0 < timeout
        time.sleep(0.1)


def _render_actor_pids() -> list[int]:
    """The Ray actor processes that own a Blender worker (their process title is ray::RenderActor...)."""
    pids = []
    for d in Path("/proc").iterdir():
        try:
            if d.name.isdigit() and (d / "cmdline").read_bytes().startswith(b"ray::RenderActor"):
                pids.append(int(d.name))
        except OSError:
            pass
    return pids


@pytest.fixture(scope="module")
def ray_shards(ray_cluster, tmp_path_factory):
    """Shard 0/2 of tiny rendered on Ray with one actor SIGKILLed mid-run; shard 1/2 with the
    driver SIGKILLed mid-run and run again."""
    base = tmp_path_factory.mktemp("ray_shards")
    a, b = base / "a", base / "b"
    proc = _generate(ray_cluster, a, "--shard", "0/2")
    _wait_for_frames(a, 1, proc)
    victims = _render_actor_pids()
    assert victims, "no Ray render actor running"
    os.kill(victims[0], signal.SIGKILL)
    _, err_a = proc.communicate(timeout=600)
    rc_a = proc.returncode
    proc = _generate(ray_cluster, b, "--shard", "1/2")
    _wait_for_frames(b, 1, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = len(Manifest(b).done())
    proc = _generate(ray_cluster, b, "--shard", "1/2")
    _, err_b = proc.communicate(timeout=600)
    return {"a": a, "b": b, "rc": (rc_a, proc.returncode), "err": (err_a, err_b), "killed_at": killed_at}


def _frame_keys(root):
    return [(e["scene"], e["frame"]) for e in Manifest(root).entries()]


def test_killed_actor_and_driver_still_give_every_frame_once(ray_shards):
    assert ray_shards["rc"] == (0, 0), ray_shards["err"]
    assert "rescheduled" in ray_shards["err"][0]  # the killed actor's task went to another worker
    for part in ("a", "b"):
        lines = [json.loads(l) for l in (ray_shards[part] / "manifest.jsonl").read_text().splitlines()]
        keys = [(e["scene"], e["frame"]) for e in lines]
        assert len(keys) == 7 and len(set(keys)) == 7, keys
    # the rerun after the driver's death rendered only what was missing
    assert 1 <= ray_shards["killed_at"] < 7
    assert not list(ray_shards["a"].rglob(".*.tmp*")) and not list(ray_shards["b"].rglob(".*.tmp*"))
    assert not _render_actor_pids()  # every actor (and its Blender) is gone


def test_ray_frames_equal_the_local_pool(ray_shards, tiny_rendered):
    local = {(e["scene"], e["frame"]): e for e in Manifest(tiny_rendered).entries()}
    seen = 0
    for part in ("a", "b"):
        for e in Manifest(ray_shards[part]).entries():
            ref = local[(e["scene"], e["frame"])]
            assert e == ref
            _same_frame(ray_shards[part] / e["dir"], tiny_rendered / ref["dir"])
            seen += 1
    assert seen == len(local) == 14


def _tree(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def merged(ray_shards, tmp_path_factory):
    out = tmp_path_factory.mktemp("merged") / "ds"
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "merge", str(out), str(ray_shards["a"]),
                        str(ray_shards["b"]), "--config", TINY, "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out


LATER_STAGES = ("index.json", "audit.json", "report/", "README.md")  # and each frame's labels/ and camera targets: fuse, audit, report, the card


def test_merge_of_two_shards_equals_one_run(merged, tiny_rendered, tiny_dataset):
    rendered = [p for p in _tree(merged) if not p.startswith(LATER_STAGES) and "/labels/" not in p
                and not p.endswith("/camera_targets.npy")]
    assert rendered == _tree(tiny_rendered)
    assert (merged / "audit.json").is_file() and (merged / "report" / "index.html").is_file()
    for f in sorted(tiny_dataset.glob("*/*/labels/*.png")):  # fused after merging, as the local pipeline does
        assert (merged / f.relative_to(tiny_dataset)).read_bytes() == f.read_bytes(), f
    assert Manifest(merged).entries() == Manifest(tiny_rendered).entries()
    for e in Manifest(merged).entries():
        _same_frame(merged / e["dir"], tiny_dataset / e["dir"])
    for sheet in merged.glob("*/contact_sheet.png"):
        assert np.array_equal(cv2.imread(str(sheet)), cv2.imread(str(tiny_rendered / sheet.relative_to(merged))))
    index = json.loads((merged / "index.json").read_text())
    assert sum(len(v) for v in index["splits"].values()) == 14


def test_merge_refuses_duplicates_and_missing_frames(ray_shards, tmp_path):
    a = ray_shards["a"]
    cases = [([a, a], "in both"), ([a], "missing from every part")]
    for parts, what in cases:
        out = tmp_path / "out"
        r = subprocess.run([sys.executable, "-m", "dataset_tools", "merge", str(out), *map(str, parts), "--config", TINY],
                           cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 1 and what in r.stderr and "Traceback" not in r.stderr, r.stderr  # EXIT_PROBLEMS
        assert not out.exists()  # nothing written


def test_fusion_on_ray_equals_the_local_pool(ray_cluster, merged, tiny_dataset, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(merged, out)
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "fuse", str(out), "--config", TINY, "--backend", "ray",
                        "--address", ray_cluster, "--no-progress", "--force"],  # merge fused it locally
                       cwd=ROOT, env=dict(os.environ, **LOOPBACK), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "index.json").read_text()) == json.loads((tiny_dataset / "index.json").read_text())
    n = 0
    for f in sorted(tiny_dataset.glob("*/*/labels/*.png")):
        mine = out / f.relative_to(tiny_dataset)
        assert np.array_equal(cv2.imread(str(mine), cv2.IMREAD_UNCHANGED), cv2.imread(str(f), cv2.IMREAD_UNCHANGED)), f
        n += 1
    assert n == 14 * 3


def test_the_local_pool_needs_no_ray():
    code = ("import sys, dataset_tools.__main__, dataset_tools.pipeline, dataset_tools.generate, dataset_tools.fuse, "
            "dataset_tools.merge, common.backend; "
            "assert not [m for m in sys.modules if m == 'ray' or m.startswith('ray.')]")
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_local_backend_maps_in_processes_as_in_this_one():
    """common.backend's local pool: fn(job, shared) in spawned processes, results in job order."""
    import operator

    from common.backend import make_backend

    jobs = list(range(9))
    inline = list(make_backend("local", workers=1).map(operator.pow, jobs, shared=2))
    assert inline == [j ** 2 for j in jobs]
    assert list(make_backend("local", workers=2).map(operator.pow, jobs, shared=2)) == inline
