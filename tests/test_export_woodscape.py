"""export-woodscape on the real tiny renders, read back by tests/woodscape_reader.py (written from
WoodScape's published format): same pixels, classes and boxes; the exported calibration through
WoodScape's documented projection agrees with our cameras."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

import woodscape_reader as ws

ROOT = Path(__file__).resolve().parents[1]
CAMS = {"FV": "front", "RV": "rear", "MVL": "left", "MVR": "right"}
# fine class name -> WoodScape class index, written out again here from docs/geometry.md's table
EXPECT = {"road": 1, "parking": 1, "lane_marking": 2, "crosswalk": 2, "stop_line": 2, "curb": 3, "pedestrian": 4, "vehicle": 6,
          "bicycle": 7, "motorcycle": 8}


def test_export_woodscape_reads_back(tiny_dataset, tmp_path):
    from dataset_tools.format.layout import FrameFiles
    from dataset_tools.format.meta import read_meta
    from dataset_tools.format.passes import read_camera_passes
    from dataset_tools.format.png import read_png
    from dataset_tools.format.reader import DatasetIndex
    from dataset_tools.labels.classes import CLASS_IDS
    from geometry.rig import load_rig

    out = tmp_path / "ws"
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "export-woodscape", str(tiny_dataset), str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((out / "export.json").read_text())
    refs = DatasetIndex(tiny_dataset).all_frames()
    assert ws.frame_ids(out) == sorted((f"{n:05d}", c) for n in range(len(refs)) for c in CAMS)
    rng = np.random.default_rng(0)
    vehicles_seen = 0
    for n, ref in enumerate(refs):
        fid = f"{n:05d}"
        files = FrameFiles(ref.dir)
        rig = read_meta(ref.dir).camera_rig()
        for cam, name in CAMS.items():
            np.testing.assert_array_equal(ws.rgb(out, fid, cam), read_png(files.camera_png(name), np.uint8, 3))
            p = read_camera_passes(files.camera_exr(name))
            want = np.zeros_like(p["semantic"])
            for fine, k in EXPECT.items():
                want[p["semantic"] == CLASS_IDS[fine]] = k
            np.testing.assert_array_equal(ws.gt_labels(out, fid, cam), want)
            # boxes: one per vehicle instance seen, its pixels' bounding box
            vehicle = (p["semantic"] == CLASS_IDS["vehicle"]) & (p["instance"] > 0)
            expect_boxes = []
            for iid in np.unique(p["instance"][vehicle]):
                ys, xs = np.nonzero(vehicle & (p["instance"] == iid))
                expect_boxes.append(("vehicles", 0, xs.min(), ys.min(), xs.max(), ys.max()))
            assert sorted(ws.boxes(out, fid, cam)) == sorted(expect_boxes)
            vehicles_seen += len(expect_boxes)
            # polygons filled as WoodScape's semantic_map_generator fills them cover every vehicle pixel
            entry = ws.instances(out, fid, cam)
            assert (entry["image_height"], entry["image_width"]) == vehicle.shape
            filled = ws.polygon_mask(entry, "car")
            assert (filled | ~vehicle).all() and filled.sum() <= vehicle.sum() * 1.5 + 4 * len(expect_boxes)
            # calibration: WoodScape's formula on random points in view vs our camera of the frame
            calib = ws.calibration(out, fid, cam)
            assert calib["name"] == cam
            rc = rig[name]
            d = rng.normal(size=(500, 3))
            d[:, 2] = np.abs(d[:, 2]) + 0.3
            pts_cam = d / np.linalg.norm(d, axis=-1, keepdims=True) * rng.uniform(1, 20, (500, 1))
            uv, ok = rc.camera.project(pts_cam)
            pts = pts_cam @ rc.cam_to_ego[:3, :3].T + rc.cam_to_ego[:3, 3]
            theirs = ws.project(calib, pts)
            fit = summary["frames"][fid]["fit_residual_px"][cam]
            assert np.abs(theirs[ok] - uv[ok]).max() <= fit + 1e-6
            # and the exported file read as our radial_poly camera is WoodScape's formula to <= 1e-3 px
            (tmp_path / "c.json").write_text(json.dumps(calib))
            back = next(iter(load_rig(tmp_path / "c.json")))
            ours, ok2 = back.project_ego(pts)
            assert np.abs(theirs[ok2] - ours[ok2]).max() <= 1e-3
    assert vehicles_seen > 0
    assert 0 < max(summary["max_fit_residual_px"].values()) < 0.05  # opencv_fisheye -> radial_poly at 64x40


def test_export_replaces_an_earlier_export_and_a_bad_frame_leaves_it_whole(tiny_dataset, tmp_path):
    """Exporting into an earlier, larger export left its stale frames beside the new ones;
    a missing camera PNG exited 1 with a partial export; a 0-byte one was copied and exit 0."""
    import json as _json
    import shutil

    from test_robustness import mini_frames_copy, run_in_process

    small = mini_frames_copy(tiny_dataset, tmp_path / "small", frames=1)
    out = tmp_path / "ws"
    (out / "rgb_images").mkdir(parents=True)
    (out / "rgb_images" / "00099_FV.png").write_bytes(b"stale")  # an earlier, larger export
    (out / "export.json").write_text(_json.dumps({"frames": {"00099": {}}}))
    code, err = run_in_process("export-woodscape", [str(small), str(out)])
    assert code == 0, err
    assert sorted(p.name for p in (out / "rgb_images").iterdir()) == ["00000_FV.png", "00000_MVL.png", "00000_MVR.png", "00000_RV.png"]
    assert list(_json.loads((out / "export.json").read_text())["frames"]) == ["00000"]
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    frame = small / _json.loads((small / "manifest.jsonl").read_text().splitlines()[0])["dir"]
    for damage, needle in (("missing", "missing"), ("empty", "0 bytes")):
        png = frame / "cam_rear.png"
        whole = png.read_bytes()
        png.unlink() if damage == "missing" else png.write_bytes(b"")
        code, err = run_in_process("export-woodscape", [str(small), str(out)])
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert code == 2 and len(lines) == 1 and "cam_rear.png" in lines[0] and needle in lines[0], err
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing half written
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp folder left
        png.write_bytes(whole)
    # a folder of other files is not an export: refused, left alone
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    code, err = run_in_process("export-woodscape", [str(small), str(other)])
    assert code == 2 and "export.json" in err and (other / "notes.txt").read_text() == "mine"
    shutil.rmtree(small)
