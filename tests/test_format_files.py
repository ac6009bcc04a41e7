"""The format package owns every persisted file: meta.json, the label PNGs, index.json and
audit.json each have one writer and one reader that refuses a bad file with one line naming the
file and the field; format/ imports nothing of the project but common and geometry."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.format.audit_file import audit_metric, read_audit, write_audit
from dataset_tools.format.index import INDEX_VERSION, build_index, read_index, write_index
from dataset_tools.format.labels import label_problems, read_labels, write_labels
from dataset_tools.format.layout import DatasetError, FrameFiles, Manifest
from dataset_tools.format.meta import FrameMeta, read_meta, write_meta
from geometry.bev import BevGrid
from geometry.rig import load_rig

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def meta():
    rig = load_rig(ROOT / "configs/rigs/default.yaml")
    return FrameMeta(scene="s", frame=0, split="train", weather={"preset": "low_sun"}, rig=rig.to_dict(),
                     ego={"box": [-1.0, 3.7, -0.9, 0.9], "kind": "car", "instance": 9},
                     topdown={"grid": BevGrid(-4, 4, -4, 4, 0.5).to_dict(), "height_m": 60.0})


def test_meta_round_trips_in_field_order(tmp_path, meta):
    path = write_meta(tmp_path, meta)
    text = path.read_text()
    assert list(json.loads(text)) == ["scene", "frame", "split", "weather", "rig", "ego", "topdown"]
    back = read_meta(tmp_path)
    assert back == meta and back.path == path
    write_meta(tmp_path, back)
    assert path.read_text() == text
    assert back.weather_preset == "low_sun" and back.ego_box == (-1.0, 3.7, -0.9, 0.9)
    assert back.grid() == BevGrid(-4, 4, -4, 4, 0.5) and back.camera_rig().names == ["front", "left", "rear", "right"]
    assert back.nominal_rig == back.rig  # no rig_nominal: the frame's own


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("rig"), "missing field 'rig'"),
    (lambda d: d.update(frame="3"), "field 'frame' must be a whole number"),
    (lambda d: d.update(colour=1), "unknown field 'colour'"),
    (lambda d: d.update(topdown={"height_m": 60.0}), "field 'topdown.grid'"),
    (lambda d: d.update(ego={"box": [1, 2]}), "field 'ego.box'"),
    (lambda d: d.update(rig={"name": "x"}), "field 'rig' must have a 'cameras' mapping"),
])
def test_meta_reader_names_file_and_field(tmp_path, meta, edit, message):
    d = meta.to_dict()
    edit(d)
    FrameFiles(tmp_path).meta.write_text(json.dumps(d))
    with pytest.raises(DatasetError, match=rf"^{re.escape(str(tmp_path / 'meta.json'))}: {re.escape(message)}"):
        read_meta(tmp_path)


def test_labels_round_trip_and_one_check(tmp_path):
    rng = np.random.default_rng(0)
    lab = {"semantic": rng.integers(0, 5, (6, 8)).astype(np.uint8), "instance": rng.integers(0, 9, (6, 8)).astype(np.uint16),
           "visibility": rng.random((6, 8)).astype(np.float32)}
    write_labels(tmp_path, lab)
    back = read_labels(tmp_path, num_classes=5, shape=(6, 8))
    assert np.array_equal(back["semantic"], lab["semantic"]) and np.array_equal(back["instance"], lab["instance"])
    assert np.abs(back["visibility"] - lab["visibility"]).max() <= 0.5 / 65535 + 1e-7
    assert label_problems(tmp_path, (6, 8), 5) == []
    files = FrameFiles(tmp_path)
    assert label_problems(tmp_path, (6, 8), 3) == [f"{files.semantic}: class id 4, beyond the 3 classes of the data set"]
    assert label_problems(tmp_path, (8, 8)) == [f"{p}: (6, 8) pixels, the label grid is (8, 8)"
                                                for p in (files.semantic, files.instance, files.visibility)]
    files.instance.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    assert label_problems(tmp_path, (6, 8)) == [f"{files.instance}: not a readable PNG"]
    with pytest.raises(DatasetError, match="instance.png: not a readable PNG"):
        read_labels(tmp_path)


def test_index_has_one_writer_and_a_checked_version(tmp_path, meta):
    (tmp_path / "s/000000").mkdir(parents=True)
    write_meta(tmp_path / "s/000000", meta)
    Manifest(tmp_path).append({"scene": "s", "frame": 0, "split": "train", "dir": "s/000000"})
    path = write_index(tmp_path, build_index(tmp_path))
    idx = read_index(tmp_path)
    assert idx["version"] == INDEX_VERSION and idx["rig"] == meta.rig and idx["grid"] == meta.topdown["grid"]
    assert idx["splits"]["train"] == [{"dir": "s/000000", "scene": "s", "frame": 0, "weather": "low_sun"}]
    path.write_text(json.dumps(dict(idx, version=INDEX_VERSION + 1)))
    with pytest.raises(DatasetError, match=r"index.json: field 'version' is 2, this code reads version 1"):
        read_index(tmp_path)


def test_audit_reader_checks_the_shape(tmp_path):
    assert read_audit(tmp_path, missing_ok=True) is None
    with pytest.raises(DatasetError, match="audit.json: missing"):
        read_audit(tmp_path)
    write_audit(tmp_path, {"frames": {"s/000000": {"unexplained": 0.0}}, "overall": {"unexplained": 0.0}, "threshold": 0.5,
                           "metric": "unexplained"})
    a = read_audit(tmp_path)
    assert audit_metric(a) == "unexplained" and audit_metric({}) == "visible_no_los"
    (tmp_path / "audit.json").write_text(json.dumps({"frames": {"s/000000": 3}}))
    with pytest.raises(DatasetError, match=r"audit.json: frames.s/000000: must be a mapping"):
        read_audit(tmp_path)


def test_format_imports_only_common_geometry_and_itself():
    bad = []
    for path in sorted((ROOT / "dataset_tools/format").glob("*.py")):
        for line in path.read_text().splitlines():
            m = re.match(r"\s*(?:from|import) ([.\w]+)", line)
            if m and (m.group(1).startswith("..") or m.group(1).split(".")[0] in ("dataset_tools", "blender_scripts", "model", "testing")):
                bad.append(f"{path.name}: {line.strip()}")
    assert bad == []
