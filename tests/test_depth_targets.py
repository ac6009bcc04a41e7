"""Camera-view targets: the depth bin and the training class of what each feature
pixel's ray hits, on a real tiny Blender render, through the view transforms and the rectification;
the targets file; the losses (both weights 0 = today's loss, exactly)."""

import shutil

import numpy as np
import pytest
import torch

from dataset_tools.format.camera_targets import (CAMERA_TARGETS, camera_targets, decode_distance, derive_camera_targets,
                                                write_camera_targets)
from dataset_tools.format.exr import read_exr
from dataset_tools.format.layout import DatasetError, FrameFiles
from dataset_tools.format.reader import DatasetIndex
from dataset_tools.labels.classes import CLASS_IDS, class_lut
from geometry.cameras import camera_from_dict
from geometry.rig import Rig, RigCamera
from model.augment import ViewTransform, base_transform, transform_camera, warp_image
from model.feature_targets import EGO, camera_targets as feature_targets, distance_bin, feature_passes, source_pixels
from model.config import validate
from model.frustum import Frustum, feature_camera

STRIDE = 4
INPUT = [64, 40]


def config(root, **loss):
    grid = DatasetIndex(root).grid
    return validate({"data": {"root": str(root), "val_split": "", "input_size": INPUT, "num_workers": 0,
                              "grid": {"x_min": grid.x_min, "x_max": grid.x_max, "y_min": grid.y_min, "y_max": grid.y_max, "res": grid.res * 2}},
                     "model": {"encoder": {"widths": [16, 32, 32], "blocks": [1, 1]}, "stride": STRIDE, "context_channels": 16,
                               "depth": {"min": 1.0, "max": 37.0, "bins": 24}, "bev_encoder": {"widths": [16, 32, 32], "blocks": [1, 1]}},
                     "loss": loss, "train": {"batch_size": 2}})


def frame_of(root):
    idx = DatasetIndex(root)
    return idx, idx.frames("train")[0]


def exr_passes(ref, name):
    ch = read_exr(FrameFiles(ref.dir).camera_exr(name))
    return ch["distance"].astype(np.float64), ch["semantic"].astype(np.int64)


def rotatable(rig: Rig) -> Rig:
    """The rig with fy = fx: the tiny 64x40 render rounds the 480x302 calibration to slightly
    non-square pixels, so augmentation would leave it unrotated; the image warp and the target do
    not depend on fx, fy (only on the principal point), and the reference below uses the same cameras."""
    return Rig([RigCamera(rc.name, camera_from_dict({**rc.camera.to_dict(), "fy": rc.camera.to_dict()["fx"]}), rc.cam_to_ego)
                for rc in rig], rig.name)


def geometric_source(rc: RigCamera, t: ViewTransform, frustum) -> tuple[np.ndarray, np.ndarray]:
    """Where each feature pixel's ray, as the lift casts it for the transformed camera, meets the
    rendered image (continuous (h, w, 2) pixel position, and whether it does): an independent
    path through geometry (transform_camera, feature_camera, unproject, project) instead of the
    image-space affine map the targets use."""
    tc = transform_camera(rc, t)
    fcam = feature_camera(tc.camera, STRIDE, tuple(INPUT))
    rays, ok = fcam.unproject(fcam.pixel_grid().numpy())
    rays = np.asarray(rays) @ tc.cam_to_ego[:3, :3].T @ rc.cam_to_ego[:3, :3]  # transformed camera -> rendered camera frame
    uv, ok2 = rc.camera.project(rays)
    uv = np.asarray(uv)
    uv_in = fcam.pixel_grid().numpy() * STRIDE + (STRIDE - 1) / 2
    on_input = (uv_in[..., 0] <= INPUT[0] - 0.5) & (uv_in[..., 1] <= INPUT[1] - 0.5)
    return uv, np.asarray(ok) & np.asarray(ok2) & np.asarray(rc.camera.inside(uv)) & on_input


def off_border(uv, camera, margin=1e-3):
    """Positions not within `margin` px of the image's outer edge (where inside/outside is unambiguous)."""
    u, v = np.nan_to_num(uv[..., 0], nan=-9), np.nan_to_num(uv[..., 1], nan=-9)
    return ((np.abs(u + 0.5) > margin) & (np.abs(u - camera.width + 0.5) > margin)
            & (np.abs(v + 0.5) > margin) & (np.abs(v - camera.height + 0.5) > margin))


def nearest_pixel(row, col, uv, tol=1e-3):
    """(row, col) is a nearest pixel of uv (a tie on a pixel edge may go either way)."""
    return (np.abs(col - uv[..., 0]) <= 0.5 + tol) & (np.abs(row - uv[..., 1]) <= 0.5 + tol)


def far_from_pixel_edges(uv, margin=0.05):
    """Positions at least `margin` px from a pixel edge (where rounding to the nearest pixel is unambiguous)."""
    f = np.nan_to_num((uv + 0.5) % 1.0)
    return np.all(np.minimum(f, 1 - f) > margin, -1)


TRANSFORMS = {
    "nominal": None,
    "scale_crop": dict(scale=1.23, angle=0.0, dx=5, dy=-3),
    "shrink_crop": dict(scale=0.81, angle=0.0, dx=-4, dy=2),
    "rotate_scale_crop": dict(scale=1.12, angle=8.5, dx=3, dy=4),
}


def make_transform(camera, spec):
    base = base_transform(camera, tuple(INPUT))
    if spec is None:
        return base
    s = base.scale * spec["scale"]
    x0 = int(np.floor((camera.width * s - INPUT[0]) / 2)) + spec["dx"]
    y0 = int(np.floor((camera.height * s - INPUT[1]) / 2)) + spec["dy"]
    return ViewTransform(s, spec["angle"], x0, y0, tuple(INPUT))


@pytest.mark.parametrize("kind", list(TRANSFORMS))
def test_depth_target_is_the_distance_pass_where_the_feature_pixel_ray_meets_the_image(tiny_dataset, kind):
    idx, ref = frame_of(tiny_dataset)
    cfg = config(tiny_dataset)
    frustum = Frustum(rotatable(idx.rig), cfg)
    table = derive_camera_targets(ref.dir, idx.rig.names)
    transforms = [make_transform(rc.camera, TRANSFORMS[kind]) for rc in frustum.rig]
    passes = {n: (table[f"distance_{n}"], table[f"semantic_{n}"]) for n in frustum.rig.names}
    depth, _ = feature_targets(frustum, transforms, passes, class_lut())
    checked = 0
    for k, (rc, t) in enumerate(zip(frustum.rig, transforms)):
        dist, sem = exr_passes(ref, rc.name)
        d, fine = feature_passes(frustum, rc, t, (table[f"distance_{rc.name}"], table[f"semantic_{rc.name}"]))
        uv, ok = geometric_source(rc, t, frustum)
        row, col, valid = source_pixels(frustum, rc, t)
        clear = off_border(uv, rc.camera)
        assert np.array_equal(valid[clear], ok[clear]), "targets are defined exactly where the ray meets the image"
        sure = valid & ok
        assert nearest_pixel(row, col, uv)[sure].all(), "the pixel the feature pixel's centre ray meets"
        truth = dist[row[sure], col[sure]]
        hit = truth < 600
        assert np.all(np.abs(d[sure][hit] - truth[hit]) <= 0.005 + 1e-6), "distance at the feature pixel's centre, to the cm"
        assert np.all(np.isnan(d[sure][~hit])), "sky: no target"
        assert np.array_equal(fine[sure], sem[row[sure], col[sure]])
        expect = np.where(sem[row[sure], col[sure]] == EGO, -1, distance_bin(np.where(hit, truth, np.nan), frustum.edges))
        agree = depth[k][sure] == expect
        # a distance within 5 mm (the cm rounding) of a bin edge may fall either side
        edge = np.min(np.abs(truth[:, None] - frustum.edges[None]), 1) < 0.006
        assert np.all(agree | edge)
        checked += int(sure.sum())
        if kind == "rotate_scale_crop":
            # the same positions from the RGB warp itself: warp an image of its own pixel coordinates
            # (bilinear, so exact for this linear image) and read it at each feature pixel's centre,
            # (4j + 1.5, 4i + 1.5): the mean of the four image pixels around it
            v, u = np.mgrid[: rc.camera.height, : rc.camera.width].astype(np.float32)
            coords = warp_image(np.dstack([u, v, np.ones_like(u)]), rc.camera, t)
            cu, cv = STRIDE * np.arange(valid.shape[1]) + 1, STRIDE * np.arange(valid.shape[0]) + 1
            cu, cv = cu[cu + 1 < INPUT[0]], cv[cv + 1 < INPUT[1]]
            quad = [coords[cv + a][:, cu + b] for a in (0, 1) for b in (0, 1)]
            src = sum(quad) / 4
            inner = np.all([q[..., 2] > 0.999 for q in quad], 0) & far_from_pixel_edges(src[..., :2], 0.1)
            assert inner.sum() > 20
            sub = (slice(0, len(cv)), slice(0, len(cu)))
            assert np.array_equal(np.floor(src[..., 0] + 0.5).astype(int)[inner], col[sub][inner])
            assert np.array_equal(np.floor(src[..., 1] + 0.5).astype(int)[inner], row[sub][inner])
            assert valid[sub][inner].all()
    assert checked > 200, "the test compared enough feature pixels"


def test_rectified_targets_come_through_the_rectification_maps(tiny_dataset):
    from model.rectified import rectifier

    idx, ref = frame_of(tiny_dataset)
    cfg = config(tiny_dataset)
    cfg["data"]["rectify"] = "cylindrical"
    rect = rectifier(idx.rig, cfg)
    frustum = Frustum(rect.rig, cfg)
    table = derive_camera_targets(ref.dir, idx.rig.names)
    checked = 0
    for rc in frustum.rig:
        fish = idx.rig[rc.name]
        t = make_transform(rc.camera, TRANSFORMS["scale_crop"])
        uv, ok = geometric_source(rc, t, frustum)  # on the cylinder's image
        cyl_uv = np.floor(uv + 0.5).astype(int)
        rays, ok_r = rc.camera.unproject(cyl_uv.astype(np.float64))  # the nearest cylinder pixel's ray...
        fuv, ok_f = fish.camera.project(np.asarray(rays))  # ...on the fisheye (same centre and axes)
        fuv = np.asarray(fuv)
        row, col, valid = source_pixels(frustum, rc, t, rect)
        # the cylinder pixel is the nearest one (ties either way), its fisheye position as exact as
        # the rectifier's 1/32-pixel tables
        sure = ok & np.asarray(ok_r) & np.asarray(ok_f) & np.asarray(fish.camera.inside(fuv)) & off_border(fuv, fish.camera, 0.05) & off_border(uv, rc.camera) & far_from_pixel_edges(uv)
        assert valid[sure].all()
        assert nearest_pixel(row, col, fuv, 1 / 32 + 1e-3)[sure].all()
        dist, _ = exr_passes(ref, rc.name)
        d, _ = feature_passes(frustum, rc, t, (table[f"distance_{rc.name}"], table[f"semantic_{rc.name}"]), rect)
        truth = dist[row[sure], col[sure]]
        hit = truth < 600
        assert np.all(np.abs(d[sure][hit] - truth[hit]) <= 0.005 + 1e-6)
        checked += int(sure.sum())
    assert checked > 200


def test_camera_semantic_target_is_the_semantic_pass_in_the_papers_classes(tiny_dataset):
    idx, ref = frame_of(tiny_dataset)
    cfg = config(tiny_dataset)
    frustum = Frustum(idx.rig, cfg)
    table = derive_camera_targets(ref.dir, idx.rig.names)
    passes = {n: (table[f"distance_{n}"], table[f"semantic_{n}"]) for n in idx.rig.names}
    transforms = frustum.nominal_transforms()
    depth, semantic = feature_targets(frustum, transforms, passes, class_lut())
    lut, ego_seen, classes = class_lut(), 0, set()
    for k, rc in enumerate(frustum.rig):
        _, sem = exr_passes(ref, rc.name)
        row, col, valid = source_pixels(frustum, rc, transforms[k])
        fine = sem[row, col]
        assert np.array_equal(semantic[k][valid], lut[fine[valid]])
        assert np.all(semantic[k][~valid] == 0)
        ego = valid & (fine == CLASS_IDS["ego"])
        assert np.all(semantic[k][ego] == 0) and np.all(depth[k][ego] == -1), "the ego body is masked"
        ego_seen += int(ego.sum())
        classes |= set(np.unique(semantic[k][valid]).tolist())
    assert ego_seen > 0, "the tiny rig sees its own body"
    assert {3, 4} <= classes, "street and background are seen"


def test_targets_file_is_written_by_fuse_and_read_back(tiny_dataset, tmp_path):
    _, ref = frame_of(tiny_dataset)
    assert (ref.dir / CAMERA_TARGETS).is_file(), "the fuse stage writes every frame's targets"
    frame = tmp_path / "frame"
    shutil.copytree(ref.dir, frame)
    path = frame / CAMERA_TARGETS
    path.unlink()
    names = ["front", "rear"]
    got = camera_targets(frame, names)
    assert not path.exists(), "a reader derives in memory and writes nothing"
    write_camera_targets(frame, derive_camera_targets(frame, names))
    for n in names:
        dist, sem = exr_passes(ref, n)
        d = decode_distance(got[n][0])
        hit = dist < 600
        assert np.all(np.abs(d[hit] - dist[hit]) <= 0.005 + 1e-6) and np.all(np.isnan(d[~hit]))
        assert np.array_equal(got[n][1], sem)
    FrameFiles(frame).camera_exr("front").unlink()  # from now on only the file can answer
    again = camera_targets(frame, names)
    assert all(np.array_equal(again[n][0], got[n][0]) and np.array_equal(again[n][1], got[n][1]) for n in names)
    with pytest.raises(DatasetError, match="cam_front.exr: missing"):
        camera_targets(frame, ["front", "left"])  # a camera the file lacks: derived again, from the EXR
    path.write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(DatasetError, match=r"camera_targets\.npy: not a readable camera targets file"):
        camera_targets(frame, names)


def test_dataset_carries_targets_only_for_training_with_a_weight(tiny_dataset, tmp_path):
    from model.data import BevDataset

    root = tmp_path / "ds"
    shutil.copytree(tiny_dataset, root)
    off = BevDataset(root, "train", config(root), train=True)[0]
    assert "depth_target" not in off and "camera_semantic" not in off
    for f in root.glob(f"*/*/{CAMERA_TARGETS}"):
        f.unlink()  # a data set fused before the fuse stage wrote them: the loader derives them in memory
    cfg = config(root, depth_weight=1.0)
    assert "depth_target" not in BevDataset(root, "train", cfg, train=False)[0], "not for validation / eval"
    ds = BevDataset(root, "train", cfg, train=True)
    s = ds[0]
    h, w = -(-INPUT[1] // STRIDE), -(-INPUT[0] // STRIDE)
    assert s["depth_target"].shape == (4, h, w) and s["camera_semantic"].shape == (4, h, w)
    assert s["depth_target"].dtype == torch.int64 and (s["depth_target"] >= 0).float().mean() > 0.3
    assert int(s["depth_target"].max()) < 24
    assert not list(root.glob(f"*/*/{CAMERA_TARGETS}")), "the loader writes nothing into the data set"


def _batch_and_models(root, **loss):
    from model import build_model
    from model.data import BevDataset

    cfg = config(root, **loss)
    ds = BevDataset(root, "train", cfg, train=True)
    batch = torch.utils.data.default_collate([ds[0], ds[1]])
    torch.manual_seed(0)
    model = build_model(cfg, ds.index.rig)
    return cfg, batch, model


def test_both_weights_zero_is_todays_loss_exactly(tiny_dataset, tmp_path):
    from model.losses import class_weights, occlusion_loss, semantic_loss, total_loss

    root = tmp_path / "ds"
    shutil.copytree(tiny_dataset, root)
    cfg, batch, plain = _batch_and_models(root)
    _, batch_t, headed = _batch_and_models(root, depth_weight=1.0, camera_seg_weight=0.5)
    assert plain.camera_head is None and headed.camera_head is not None
    assert set(headed.state_dict()) - set(plain.state_dict()) == {"camera_head.weight", "camera_head.bias"}
    for k, v in plain.state_dict().items():  # the head is built last: every other weight draws the same
        assert torch.equal(v, headed.state_dict()[k]), k
    alpha = class_weights("uniform")
    out = plain(batch["images"], batch.get("point_cell"), batch.get("intrinsics"))
    today = semantic_loss(out["semantic"], batch["semantic"], batch["visibility"], alpha) + occlusion_loss(out["occlusion"], batch["visibility"])
    loss, parts = total_loss(out, batch, alpha, 1.0, True, "soft", 0.0, 0.0)
    assert torch.equal(loss, today) and set(parts) == {"semantic", "occlusion"}
    out_h = headed(batch_t["images"], batch_t.get("point_cell"), batch_t.get("intrinsics"))
    assert torch.equal(out_h["semantic"], out["semantic"]), "the head does not change the BEV path"
    loss_h, parts_h = total_loss(out_h, batch_t, alpha, 1.0, True, "soft", 0.0, 0.0)
    assert torch.equal(loss_h, today)
    on, parts_on = total_loss(out_h, batch_t, alpha, 1.0, True, "soft", 1.0, 0.5)
    assert torch.allclose(on, today + parts_on["depth"] + 0.5 * parts_on["camera_semantic"])
    assert 0 < float(parts_on["depth"]) and 0 < float(parts_on["camera_semantic"])
    headed.eval()
    assert set(headed(batch_t["images"])) == {"semantic", "occlusion"}, "no camera head nor depth logits at inference"


def test_camera_losses_are_the_masked_cross_entropies():
    from model.losses import camera_semantic_loss, depth_loss

    g = torch.Generator().manual_seed(0)
    logits = torch.randn(2, 3, 5, 4, 6, generator=g)
    target = torch.randint(-1, 5, (2, 3, 4, 6), generator=g)
    target[1] = -1  # a sample with no valid pixel adds 0
    ce0 = torch.nn.functional.cross_entropy(logits[0].permute(1, 0, 2, 3).reshape(5, -1).T, target[0].reshape(-1), ignore_index=-1)
    assert torch.allclose(depth_loss(logits, target), ce0 / 2)
    sem = torch.where(target >= 0, target, 0)  # classes 1..4 in 0..4, 0 invalid
    ce = torch.nn.functional.cross_entropy(logits[0, :, :4].permute(1, 0, 2, 3).reshape(4, -1).T, sem[0].reshape(-1) - 1, ignore_index=-1)
    assert torch.allclose(camera_semantic_loss(logits[:, :, :4], sem), ce / 2)


def test_training_with_both_weights_runs_and_its_checkpoint_loads(tiny_dataset, tmp_path):
    import subprocess
    import sys

    import yaml

    from model import load_checkpoint

    root = tmp_path / "ds"
    shutil.copytree(tiny_dataset, root)
    before = {p: p.stat().st_mtime_ns for p in root.rglob("*")}
    cfg = config(root, depth_weight=1.0, camera_seg_weight=0.5)
    cfg["train"].update({"max_steps": 2, "threads": 1, "image_every": 0, "log_every": 1})
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    r = subprocess.run([sys.executable, "train.py", "--config", str(path), "--out", str(tmp_path / "run"), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    model, loaded, ckpt = load_checkpoint(tmp_path / "run" / "latest.pt")
    assert ckpt["step"] == 2 and loaded["loss"]["depth_weight"] == 1.0 and model.camera_head is not None
    assert {p: p.stat().st_mtime_ns for p in root.rglob("*") if p.name != ".lock"} == \
        {p: t for p, t in before.items() if p.name != ".lock"}, "training leaves the data set as it was"
