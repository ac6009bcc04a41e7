"""Label tools on a real tiny render (configs/dataset/tiny.yaml through Blender, generated once per
test session): fusion, consistency, validate (clean and corrupted), resume, inspect, stats."""

import json
import shutil
import subprocess
import sys

import pytest

from dataset_tools.qa.consistency import dataset_consistency
from dataset_tools.format.reader import DatasetIndex, read_frame

PY = sys.executable


def run(*args, timeout=600):
    return subprocess.run([PY, "-m", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="session")
def tiny(tiny_dataset):
    """The tiny preset rendered and fused (conftest; read-only for the tests: copy before changing)."""
    return tiny_dataset


def copy(tiny, tmp_path):
    dst = tmp_path / "ds"
    shutil.copytree(tiny, dst)
    return dst


def test_real_labels_read_back_and_agree_with_the_cameras(tiny):
    idx = DatasetIndex(tiny)
    frames = idx.frames("train")
    assert len(frames) == len((tiny / "manifest.jsonl").read_text().splitlines()) >= 2
    for ref in frames:
        f = read_frame(ref)
        assert f["semantic"].shape == f["visibility"].shape == idx.grid.shape
        assert f["semantic"].max() < len(idx.class_names)
        assert 0.0 <= f["visibility"].min() and f["visibility"].max() <= 1.0
        assert set(f["images"]) == set(idx.rig.names)
        assert (f["semantic"] == 3).any() and (f["visibility"] >= 0.5).mean() > 0.05
    r = dataset_consistency(tiny, progress=False)
    print("consistency per class:", {k: (None if v is None else round(v, 4)) for k, v in r["scores"].items()})
    assert r["scores"]["street"] >= 0.97
    assert r["scores"]["background"] >= 0.9 and r["scores"]["vehicle"] >= 0.8


def test_consistency_catches_wrong_labels(tiny, tmp_path):
    ds = copy(tiny, tmp_path)
    import cv2

    for ref in DatasetIndex(ds).all_frames():  # labels flipped left-right: a geometry bug
        p = ref.dir / "labels" / "semantic.png"
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_UNCHANGED)[:, ::-1])
    r = dataset_consistency(ds, progress=False)
    assert r["scores"]["vehicle"] < 0.8 and len(r["below_threshold"]) > 0


def test_validate_passes_on_the_render_and_names_corrupted_files(tiny, tmp_path):
    r = run("dataset_tools", "validate", str(tiny))
    assert r.returncode == 0, r.stdout + r.stderr
    ds = copy(tiny, tmp_path)
    frames = DatasetIndex(ds).all_frames()
    exr = frames[0].dir / "cam_front.exr"
    exr.write_bytes(exr.read_bytes()[: exr.stat().st_size // 2])
    label = frames[1].dir / "labels" / "visibility.png"
    label.unlink()
    r = run("dataset_tools", "validate", str(ds))
    assert r.returncode == 1
    assert f"{exr}: not a readable EXR" in r.stdout
    assert f"{label}: missing" in r.stdout
    assert "Traceback" not in r.stdout + r.stderr
    assert len(r.stdout.strip().splitlines()) == 2


def test_fuse_resumes_and_refuses_bad_frames_cleanly(tiny, tmp_path):
    ds = copy(tiny, tmp_path)
    frames = DatasetIndex(ds).all_frames()
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in ds.glob("*/*/labels/*.png")}
    redo = frames[0].dir / "labels"
    shutil.rmtree(redo)
    r = run("dataset_tools", "fuse", str(ds))
    assert r.returncode == 0, r.stderr
    for p, (mtime, data) in before.items():
        assert p.read_bytes() == data  # the redone frame is identical, deterministic
        if p.parent != redo:
            assert p.stat().st_mtime_ns == mtime  # finished frames were skipped
    bad = frames[1].dir
    shutil.rmtree(bad / "labels")
    (bad / "topdown.exr").write_bytes((bad / "topdown.exr").read_bytes()[:500])
    r = run("dataset_tools", "fuse", str(ds))
    assert r.returncode == 1
    assert r.stderr.strip().splitlines()[-1].startswith(f"error: {bad / 'topdown.exr'}: not a readable EXR")
    assert "Traceback" not in r.stderr
    assert not (bad / "labels").exists()  # nothing half-written


def test_inspect_writes_every_picture(tiny, tmp_path):
    frame = DatasetIndex(tiny).frames("train")[0].dir
    r = run("dataset_tools", "inspect", str(frame), "--out", str(tmp_path / "pics"))
    assert r.returncode == 0, r.stderr
    assert "layer all: height, instance, semantic" in r.stdout and "layer ground:" in r.stdout
    names = {p.name for p in (tmp_path / "pics").glob("*.png")}
    for n in ("cam_front_semantic", "cam_front_instance", "cam_front_distance", "cam_front_position", "cam_front_rgb",
              "topdown_ground_semantic", "topdown_all_semantic", "labels_semantic", "labels_visibility",
              "labels_over_topdown", "camera_footprints"):
        assert n + ".png" in names
    r = run("dataset_tools", "inspect", str(frame / "cam_left.exr"), "--out", str(tmp_path / "one"))
    assert r.returncode == 0 and "distance" in r.stdout
    assert {p.name for p in (tmp_path / "one").glob("*.png")} >= {"semantic.png", "distance.png"}


def test_stats_table_and_plots(tiny, tmp_path):
    r = run("dataset_tools", "stats", str(tiny), "--out", str(tmp_path / "st"))
    assert r.returncode == 0, r.stderr
    st = json.loads((tmp_path / "st" / "stats.json").read_text())
    cls = st["splits"]["train"]["classes"]
    assert abs(sum(cls.values()) - 1) < 1e-6 and cls["street"] > 0.05
    near, far = st["coverage_by_distance"]["0-5 m"], st["coverage_by_distance"]["25-36 m"]
    assert near > far
    assert set(st["coverage_by_camera"]) == {"front", "left", "rear", "right"}
    assert abs(sum(st["visibility_hist"]["fraction"]) - 1) < 1e-6
    for n in ("class_frequencies", "visibility_histogram", "coverage_by_distance", "coverage_by_camera"):
        assert (tmp_path / "st" / f"{n}.png").stat().st_size > 1000
    assert "street" in r.stdout


def test_bad_dataset_gets_one_line(tmp_path):
    r = run("dataset_tools", "fuse", str(tmp_path / "nothing"))
    assert r.returncode == 2 and r.stderr.strip() == f"error: dataset: {tmp_path / 'nothing' / 'manifest.jsonl'}: missing (not a generated data set)"
    (tmp_path / "cfg.yaml").write_text("labels: {tau: -1}\n")
    r = run("dataset_tools", "fuse", str(tmp_path), "--config", str(tmp_path / "cfg.yaml"))
    assert r.returncode == 2 and "labels.tau: must be a number > 0" in r.stderr
    assert "Traceback" not in r.stderr


def test_bad_manifest_lines_are_named(tmp_path):
    """index stops at the first bad line; validate lists every one; both name line and problem."""
    from dataset_tools.format.layout import DatasetError, Manifest
    from dataset_tools.qa.validate import check_manifest

    (tmp_path / "manifest.jsonl").write_text('{"scene": "a", "frame": 0, "split": "train"}\n\n{oops\n7\n')
    path = tmp_path / "manifest.jsonl"
    with pytest.raises(DatasetError, match=rf"^{path}: line 1: missing field 'dir'$"):
        Manifest(tmp_path).entries()
    problems = []
    assert check_manifest(tmp_path, problems) == []
    assert problems == [f"{path}: line 1: missing field 'dir'",
                        f"{path}: line 3: not valid JSON (Expecting property name enclosed in double quotes)",
                        f"{path}: line 4: not a JSON object"]
