"""The frame layout and the manifest: one reader for every tool; a line torn by a kill is ignored
and cut off on resume, so index and fuse never stop on it."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from dataset_tools.format.layout import DatasetError, FrameFiles, Manifest, frame_dir_name

ROOT = Path(__file__).resolve().parents[1]


def entry(scene, frame, split="train"):
    return {"scene": scene, "frame": frame, "split": split, "dir": frame_dir_name(scene, frame)}


def test_torn_last_line_is_ignored_and_cut_on_append(tmp_path):
    m = Manifest(tmp_path)
    m.append(entry("a", 0))
    m.append(entry("a", 1))
    whole = m.path.read_bytes()
    m.path.write_bytes(whole + b'{"scene": "a", "frame": 2, "spl')  # killed mid-line
    assert [e["frame"] for e in m.entries()] == [0, 1]
    assert m.done() == {("a", 0), ("a", 1)}
    m.append(entry("a", 2))
    assert m.path.read_bytes() == whole + (json.dumps(entry("a", 2), sort_keys=True) + "\n").encode()
    assert [e["frame"] for e in m.entries()] == [0, 1, 2]


def test_bad_lines_are_named_and_paths_stay_inside(tmp_path):
    m = Manifest(tmp_path)
    m.path.write_text(json.dumps({**entry("a", 0), "dir": "../../etc"}) + "\n" + json.dumps({**entry("a", 1), "frame": "x"}) + "\n")
    assert [p for _, _, p in m.lines()] == ["field 'dir' must be a relative path inside the data set",
                                           "field 'frame' must be a whole number >= 0"]
    with pytest.raises(DatasetError, match=r"manifest.jsonl: line 1: field 'dir'"):
        m.entries()


def test_frame_files_name_every_file(tmp_path):
    f = FrameFiles(tmp_path / frame_dir_name("s", 3))
    assert f.dir.name == "000003"
    assert [p.name for p in (f.meta, f.topdown, f.camera_exr("front"), f.camera_png("front"), f.camera_ego_mask("front"))] == \
        ["meta.json", "topdown.exr", "cam_front.exr", "cam_front.png", "cam_front_ego.png"]
    assert [p.name for p in f.label_paths()] == ["semantic.png", "instance.png", "visibility.png"]
    f.dir.mkdir(parents=True)
    for n in ("cam_front.png", "cam_left.png", "cam_front_ego.png"):
        (f.dir / n).write_bytes(b"")
    assert f.camera_names() == ["front", "left"]


def run(*args):
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_resume_after_a_torn_manifest_line(tiny_rendered, tmp_path):
    """A generate run killed while writing its last manifest line: the rerun redoes that frame,
    and index and fuse read the manifest without a complaint."""
    out = tmp_path / "ds"
    shutil.copytree(tiny_rendered, out)
    lines = (out / "manifest.jsonl").read_text().splitlines(keepends=True)
    last = json.loads(lines[-1])
    shutil.rmtree(out / last["dir"])
    (out / "manifest.jsonl").write_text("".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2])
    r = run("dataset_tools", "generate", "--config", "configs/dataset/tiny.yaml", "--out", str(out), "--no-progress", "--workers", "1")
    assert r.returncode == 0, r.stderr[-2000:]
    assert (out / "manifest.jsonl").read_text().splitlines(keepends=True)[:-1] == lines[:-1]
    assert (FrameFiles(out / last["dir"]).meta).is_file()
    assert [(e["scene"], e["frame"]) for e in Manifest(out).entries()] == sorted((json.loads(x)["scene"], json.loads(x)["frame"]) for x in lines)
    r = run("dataset_tools", "index", str(out))
    assert r.returncode == 0 and "not valid JSON" not in r.stderr, r.stderr


def test_drop_removes_a_scene_s_lines_and_keeps_the_rest(tmp_path):
    m = Manifest(tmp_path)
    for e in (entry("a", 0), entry("b", 0), entry("a", 1)):
        m.append(e)
    with open(m.path, "a") as f:
        f.write("not json\n")
    m.drop({"a"})
    assert m.done() == {("b", 0)}
    assert m.path.read_text().splitlines()[-1] == "not json"  # a bad line is not this function's to judge


def test_a_scene_whose_recipe_changed_is_refused_then_rendered_again_on_request(tiny_rendered, tmp_path):
    """The config says another recipe for a scene already rendered (here: the stored recipe edited,
    as if the config had changed since): generate refuses with one line and writes nothing; with
    --rerender-changed it renders that scene again and leaves the others as they were."""
    out = tmp_path / "ds"
    shutil.copytree(tiny_rendered, out)
    stored = out / "recipes" / "roundabout.yaml"
    stored.write_text(stored.read_text().replace("preset:", "preset:  ", 1))  # not the config's text any more
    before = {p: p.stat().st_mtime_ns for p in out.glob("*/*/meta.json")}
    manifest = (out / "manifest.jsonl").read_bytes()
    cmd = ("dataset_tools", "generate", "--config", "configs/dataset/tiny.yaml", "--out", str(out), "--no-progress", "--workers", "1")
    r = run(*cmd)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "roundabout" in r.stderr and "--rerender-changed" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert (out / "manifest.jsonl").read_bytes() == manifest and "preset:  " in stored.read_text()
    (out / ".s1_0007.123.stale" / "000000").mkdir(parents=True)  # left by a run killed while forgetting a scene
    r = run(*cmd, "--rerender-changed")
    assert r.returncode == 0, r.stderr[-2000:]
    assert not list(out.glob(".*.stale"))
    assert "rendering 1 changed scene(s) again (roundabout)" in r.stdout + r.stderr
    after = {p: p.stat().st_mtime_ns for p in out.glob("*/*/meta.json")}
    assert set(after) == set(before)
    assert [p.parts[-3] for p in after if after[p] != before[p]] == ["roundabout"] * 2
    assert "preset:  " not in stored.read_text() and not list(out.glob(".roundabout.*"))
    assert sorted(Manifest(out).done()) == sorted((json.loads(x)["scene"], json.loads(x)["frame"]) for x in manifest.splitlines())
