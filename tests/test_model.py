"""Model pieces: lift vs geometry, camera-moving augmentation, pooling, losses, metrics,
config validation and checkpoints."""

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from geometry.bev import BevGrid
from geometry.rig import RigCamera, load_rig, rot_z
from model import CheckpointError, build_model, load_checkpoint, save_checkpoint
from model.augment import ColorJitter, ViewTransform, adjust_hue, base_transform, can_rotate, transform_camera, warp_image
from model.config import ConfigError, validate
from model.frustum import camera_point_cells, depth_bins, feature_camera
from model.losses import class_weights, occlusion_loss, semantic_loss
from model.metrics import BevMetrics, confusion
from model.inference import decode
from model.splat import splat

GRID = BevGrid(res=0.25)


@pytest.mark.parametrize("rig_path", ["configs/rigs/default.yaml", "configs/rigs/mixed.yaml"])
def test_lift_agrees_with_geometry(rig_path):
    """A point placed at a bin's distance along a pixel's ray (unprojected from the full-resolution
    image pixel the feature pixel covers) falls in the BEV cell the splat uses, and projects back
    onto that image pixel."""
    rig = load_rig(rig_path)
    stride, size = 8, (192, 120)
    bins = depth_bins(1.0, 37.0, 36)
    checked = 0
    for rc in rig:
        rc_in = transform_camera(rc, base_transform(rc.camera, size))
        pc = camera_point_cells(rc_in, stride, size, bins, GRID, (-10, 10))
        fcam = feature_camera(rc_in.camera, stride, size)
        assert pc.shape == (len(bins), fcam.height, fcam.width)
        rng = np.random.default_rng(0)
        for _ in range(60):
            k, i, j = rng.integers(len(bins)), rng.integers(fcam.height), rng.integers(fcam.width)
            uv = np.array([stride * j + (stride - 1) / 2, stride * i + (stride - 1) / 2])
            origin, ray, valid = rc_in.rays_ego(uv)
            p = origin + bins[k] * ray
            row, col, inside = GRID.cell_of(p)
            on_image = uv[0] <= size[0] - 0.5 and uv[1] <= size[1] - 0.5
            expect = int(row * GRID.cols + col) if (inside and valid and on_image and -10 <= p[2] <= 10) else -1
            assert pc[k, i, j] == expect
            if expect >= 0:
                checked += 1
                uv_back, ok = rc_in.project_ego(p)
                assert ok and np.abs(uv_back - uv).max() < 1e-6
                # and the same point seen from the native camera lands on the native pixel
                uv_native, _ = rc.project_ego(p)
                s = base_transform(rc.camera, size).scale
                assert np.abs(s * (uv_native + 0.5) - 0.5 - base_offset(rc.camera, size) - uv).max() < 1e-6
    assert checked > 50


def base_offset(camera, size):
    t = base_transform(camera, size)
    return np.array([t.x0, t.y0])


def blob_image(cam, uv, sigma=2.5):
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    g = np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma**2))
    return np.repeat((g * 255).astype(np.uint8)[..., None], 3, -1)


def centroid(img):
    w = img[..., 0].astype(np.float64)
    w = np.where(w > 20, w, 0)
    v, u = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    return np.array([(u * w).sum() / w.sum(), (v * w).sum() / w.sum()])


@pytest.mark.parametrize("t", [
    ViewTransform(0.4, 0.0, 0, 0, (192, 120)),
    ViewTransform(0.45, 0.0, 13, 9, (192, 120)),
    ViewTransform(0.42, 8.0, 5, 3, (192, 120)),
    ViewTransform(1.1, -6.0, 40, 20, (400, 260)),
])
def test_augmentation_moves_camera_with_image(t):
    """Warp an image of a bright spot where a 3D point projects; the spot lands where the
    transformed camera projects the point."""
    rc = load_rig("configs/rigs/default.yaml")["left"]
    rc2 = transform_camera(rc, t)
    checked = 0
    for p in ([4.0, 5.0, 0.0], [0.0, 3.0, 0.5], [6.0, 2.5, 1.0], [2.0, 4.0, 0.0]):
        uv, ok = rc.project_ego(np.array(p))
        uv2, ok2 = rc2.project_ego(np.array(p))
        assert ok and ok2
        if not (12 < uv2[0] < t.size[0] - 12 and 12 < uv2[1] < t.size[1] - 12):
            continue
        out = warp_image(blob_image(rc.camera, uv, sigma=4.0), rc.camera, t)
        assert out.shape == (t.size[1], t.size[0], 3)
        assert np.abs(centroid(out) - uv2).max() < 0.25, (p, centroid(out), uv2)
        checked += 1
    assert checked >= 2


@pytest.mark.parametrize("kind", ["adam", "adamw"])
def test_weight_decay_of_each_optimizer(kind):
    """train.optimizer: with no gradient, adamw's decoupled decay shrinks every weight by lr x
    weight_decay in a step, exactly; adam's L2 term goes through the moment estimates, which turn it
    into a step of lr against each weight's sign."""
    from model.training import make_optimizer

    layer = torch.nn.Linear(3, 2)
    w0 = layer.weight.detach().clone()
    opt = make_optimizer({"train": {"optimizer": kind, "lr": 0.01, "weight_decay": 0.5, "decay_vectors": True}}, layer)
    for p in layer.parameters():
        p.grad = torch.zeros_like(p)
    opt.step()
    want = w0 * (1 - 0.01 * 0.5) if kind == "adamw" else w0 - 0.01 * torch.sign(w0)
    assert torch.allclose(layer.weight.detach(), want, atol=1e-6)


def test_decay_vectors_false_leaves_biases_and_norms_alone():
    """train.decay_vectors false: adamw still shrinks the matrices and kernels, but the biases and
    BatchNorm's scale and shift (weights of one dimension) keep their values when there is no
    gradient; a resume puts each group's decay back from the config (decay_of_groups)."""
    from model.training import decay_of_groups, make_optimizer

    net = torch.nn.Sequential(torch.nn.Conv2d(2, 3, 3), torch.nn.BatchNorm2d(3))
    with torch.no_grad():
        net[1].weight.fill_(2.0), net[1].bias.fill_(1.0)
    before = {k: v.detach().clone() for k, v in net.named_parameters()}
    t = {"optimizer": "adamw", "lr": 0.01, "weight_decay": 0.5, "decay_vectors": False}
    opt = make_optimizer({"train": t}, net)
    assert [g["weight_decay"] for g in opt.param_groups] == decay_of_groups(t) == [0.5, 0.0]
    for p in net.parameters():
        p.grad = torch.zeros_like(p)
    opt.step()
    after = dict(net.named_parameters())
    assert torch.allclose(after["0.weight"], before["0.weight"] * (1 - 0.01 * 0.5), atol=1e-7)
    for name in ("0.bias", "1.weight", "1.bias"):
        assert torch.equal(after[name].detach(), before[name]), name


def test_turned_labels_are_the_grid_rotated():
    """BevGrid.turned: the world turned a quarter turn to the left puts what was ahead (up in the
    BEV image) on the left: the image rotated counter-clockwise, exactly; yaw 0 changes nothing;
    an eighth of a turn leaves the corners without a label (`fill`)."""
    g = BevGrid(res=2.5)  # 20 x 20 cells
    labels = np.arange(g.rows * g.cols).reshape(g.shape)
    two = np.stack([labels, -labels], -1)
    assert np.array_equal(g.turned(0.0, labels)[0], labels)
    quarter, quarter2 = g.turned(math.pi / 2, labels, two)
    assert np.array_equal(quarter, np.rot90(labels)) and np.array_equal(quarter2, np.rot90(two))
    eighth = g.turned(math.pi / 4, labels, fill=-1)[0]
    assert eighth[0, 0] == eighth[-1, -1] == -1 and (eighth >= 0).mean() > 0.75
    assert eighth[g.rows // 2, g.cols // 2] == labels[g.rows // 2, g.cols // 2]
    with pytest.raises(ValueError, match="not this grid's"):
        g.turned(0.1, labels[:5])


@pytest.mark.parametrize("yaw_deg", [7.0, -25.0, 90.0])
def test_turned_geometry_lands_where_the_turned_labels_are(yaw_deg):
    """augment.bev_rotation_deg: a camera of the rig turned with the world (Rig.turned) lifts each
    feature pixel's point into the cell whose turned label (BevGrid.turned) is the label the point
    had before the turn: the lift and the labels move together (nearest-cell resampling may move
    a point by one cell)."""
    yaw = math.radians(yaw_deg)
    stride, size, bins = 8, (192, 120), depth_bins(1.0, 37.0, 36)
    cell_id = np.arange(GRID.rows * GRID.cols).reshape(GRID.shape)
    turned_id = GRID.turned(yaw, cell_id, fill=-1)[0].reshape(-1)
    for rig in (load_rig("configs/rigs/default.yaml"), load_rig("configs/rigs/mixed.yaml")):
        for rc, tc in zip(rig, rig.turned(yaw)):
            assert np.allclose(tc.cam_to_ego[:3, 3], rot_z(yaw) @ rc.cam_to_ego[:3, 3])
            seen, seen_turned = (transform_camera(c, base_transform(c.camera, size)) for c in (rc, tc))
            before = camera_point_cells(seen, stride, size, bins, GRID, (-10, 10))
            after = camera_point_cells(seen_turned, stride, size, bins, GRID, (-10, 10))
            both = (before >= 0) & (after >= 0)
            assert both.mean() > 0.2
            came_from = turned_id[after[both]]
            labelled = came_from >= 0  # a point in an edge cell whose centre turns back outside the grid: none
            assert labelled.mean() > 0.99
            came_from, before = came_from[labelled], before[both][labelled]
            r0, c0 = np.divmod(before, GRID.cols)
            r1, c1 = np.divmod(came_from, GRID.cols)
            assert (came_from == before).mean() > 0.4  # a point uniform in its cell: about half
            assert np.maximum(abs(r1 - r0), abs(c1 - c0)).max() <= 1


@pytest.mark.parametrize("t", [ViewTransform(0.4, 0.0, 0, 0, (192, 120)), ViewTransform(0.42, 8.0, 13, 9, (192, 120))])
def test_mirrored_geometry_is_the_geometry_of_mirrored_cameras(t):
    """The images flipped left-right are what mirrored cameras see of the world mirrored about the
    ego x axis: for each camera (at a view transform that puts the principal point off centre),
    its point cells and intrinsics descriptor mirrored (model.frustum) equal those of that camera
    built explicitly: the same lens with cx -> W - 1 - cx, its pose reflected (y -> -y) with its
    image x axis reversed."""
    from geometry.cameras import camera_from_dict
    from model.frustum import intrinsics_descriptor, mirrored_cells

    stride, size, bins = 8, t.size, depth_bins(1.0, 37.0, 36)
    reflect, flip_x = np.diag([1.0, -1.0, 1.0, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0])
    for rc in [*load_rig("configs/rigs/default.yaml"), *load_rig("configs/rigs/mixed.yaml")]:
        seen = transform_camera(rc, t if can_rotate(rc.camera) else ViewTransform(t.scale, 0.0, t.x0, t.y0, t.size))
        d = seen.camera.to_dict()
        twin = RigCamera(rc.name, camera_from_dict({**d, "cx": d["width"] - 1 - d["cx"]}), reflect @ seen.cam_to_ego @ flip_x)
        want = camera_point_cells(twin, stride, size, bins, GRID, (-10, 10))
        got = mirrored_cells(camera_point_cells(seen, stride, size, bins, GRID, (-10, 10)), GRID)
        assert (want >= 0).mean() > 0.3
        assert (got == want).mean() > 0.999  # only points on a cell boundary may round to the other side
        assert np.abs(intrinsics_descriptor(seen.camera, mirrored=True) - intrinsics_descriptor(twin.camera)).max() < 1e-6
    with pytest.raises(ValueError, match="not symmetric"):
        mirrored_cells(np.zeros((1, 2, 2), np.int64), BevGrid(y_min=-20.0, y_max=25.0, res=0.25))


def test_rotation_only_for_square_radial_models():
    rig = load_rig("configs/rigs/mixed.yaml")
    assert all(can_rotate(rc.camera) for rc in rig)
    from geometry.cameras import camera_from_dict

    cyl = camera_from_dict({"model": "cylindrical", "width": 100, "height": 80, "fx": 30, "fy": 30, "cx": 49.5, "cy": 39.5})
    squashed = rig["front"].camera.replace(fy=rig["front"].camera.fy * 1.2)
    assert not can_rotate(cyl) and not can_rotate(squashed)
    with pytest.raises(ValueError, match="cannot be rotated"):
        transform_camera(RigCamera("c", cyl, np.eye(4)), ViewTransform(1.0, 5.0, 0, 0, (100, 80)))


def test_hue_through_opencv_equals_kornias():
    """adjust_hue (OpenCV's HSV) turns hues as kornia's adjust_hue does, grey and black pixels and
    turns past 0 / 360 degrees included, and the jitter uses it (the pinned kornia has the hook)."""
    from kornia.enhance import adjust_hue as kornia_hue

    g = torch.Generator().manual_seed(0)
    x = torch.rand(3, 3, 30, 40, generator=g)
    x[:, :, :5] = 0.5  # grey: no hue
    x[:, :, 5:8] = 0.0
    x[0, 0], x[0, 1:] = 1.0, 0.0  # pure red: hue 0, turned below 0
    turns = torch.tensor([-0.05, 0.03, 0.5]) * 2 * np.pi
    out = adjust_hue(x, turns)
    assert out.shape == x.shape and out.dtype == x.dtype
    assert (out - kornia_hue(x, turns)).abs().max() < 1e-5
    assert (out[1:] - x[1:]).abs().max() > 0.05  # it does turn
    assert torch.equal(adjust_hue(x.double(), turns), kornia_hue(x.double(), turns))  # not float32: kornia's
    assert ColorJitter().op._hue_fn is adjust_hue


def test_jitter_of_a_batch_from_draws_equals_each_samples_own():
    """ColorJitter.apply: samples with their own draws (orders differing) jittered in one call come
    out as each sample's jitter under its seed."""
    jitter = ColorJitter()
    x = torch.rand(3, 4, 3, 20, 30, generator=torch.Generator().manual_seed(1))
    seeds = [s for s in range(40) if jitter.draw(4, s)[1][0] != jitter.draw(4, 0)[1][0]][:2] + [0]
    draws = [jitter.draw(4, s) for s in seeds]
    assert len({tuple(o.tolist()) for _, o in draws}) > 1
    out = jitter.apply(x, torch.stack([f for f, _ in draws]), torch.stack([o for _, o in draws]))
    for i, s in enumerate(seeds):
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(s)
            own = jitter(x[i])
        assert (out[i] - own).abs().max() < 1e-6
    assert (out - x).abs().max() > 0.05


def small_cfg(**model):
    m = {"encoder": {"widths": [8, 16, 16], "blocks": [1, 1]}, "stride": 4, "context_channels": 8,
         "depth": {"min": 1.0, "max": 30.0, "bins": 8}, "bev_encoder": {"widths": [8, 16, 16], "blocks": [1, 1]}}
    m.update(model)
    return validate({"data": {"input_size": [64, 40], "grid": {"bound": 12.0, "res": 0.5}}, "model": m})


@pytest.mark.parametrize("pooling", ["sum", "max", "weighted_sum", "sensors_per_cell", "intrinsics_embedding"])
def test_model_forward_backward_every_pooling(pooling):
    torch.manual_seed(0)
    cfg = small_cfg(pooling=pooling)
    model = build_model(cfg, load_rig("configs/rigs/mixed.yaml"))
    x = torch.rand(2, 5, 3, 40, 64)
    out = model(x)
    assert out["semantic"].shape == (2, 4, 48, 48) and out["occlusion"].shape == (2, 48, 48)
    (out["semantic"].sum() + out["occlusion"].sum()).backward()
    grads = [p.grad for p in model.encoder.parameters()]
    assert all(g is not None for g in grads) and sum(float(g.abs().sum()) for g in grads) > 0
    # explicit nominal geometry gives the same output as the cached one
    pc = model.nominal_point_cell[None].expand(2, -1, -1, -1, -1).contiguous()
    assert torch.allclose(model(x, pc)["semantic"], out["semantic"], atol=1e-6)


def test_pooling_definitions():
    torch.manual_seed(0)
    rig = load_rig("configs/rigs/default.yaml")
    per_cam = {}
    for pooling in ("sum", "max", "sensors_per_cell", "weighted_sum", "intrinsics_embedding"):
        torch.manual_seed(0)
        model = build_model(small_cfg(pooling=pooling), rig)
        per_cam[pooling] = model
    x = torch.rand(1, 4, 3, 40, 64)
    m = per_cam["max"]
    depth, ctx = m.lift(x)
    feats = splat(depth, ctx, m._index(None, 1)).view(1, 4, 48, 48, -1)  # (B, N, X, Y, C)
    assert torch.allclose(per_cam["sum"].pool(feats.sum(1)), feats.sum(1).permute(0, 3, 1, 2))
    assert torch.allclose(m.pool(feats), feats.amax(1).permute(0, 3, 1, 2))
    # weighted sum starts as the sum; sensors-per-cell starts as the mean over the cameras seeing a cell
    assert torch.allclose(per_cam["weighted_sum"].pool(feats), feats.sum(1).permute(0, 3, 1, 2), atol=1e-5)
    w = per_cam["sensors_per_cell"].pool.weight.detach()
    seen = (m.nominal_point_cell >= 0)
    n_cams = torch.zeros(48 * 48)
    for k in range(4):
        n_cams += torch.bincount(m.nominal_point_cell[k][seen[k]], minlength=48 * 48).clamp(max=1).float()
    n_cams = n_cams.view(48, 48)
    assert (n_cams >= 2).any()
    assert torch.allclose(w.sum(0)[n_cams > 0], torch.ones(int((n_cams > 0).sum())))
    assert torch.allclose(w[0][n_cams > 0] * n_cams[n_cams > 0], (w[0][n_cams > 0] > 0).float())
    # intrinsics embedding starts as the sum of the mean-removed features over covered cells
    cover = (torch.stack([torch.bincount(m.nominal_point_cell[k][seen[k]], minlength=48 * 48) for k in range(4)]) > 0).view(1, 4, 48, 48)
    mask = cover[..., None].float()
    mu = (feats * mask).sum((2, 3), keepdim=True) / mask.sum((2, 3), keepdim=True)
    expect = ((feats - mu) * mask).sum(1).permute(0, 3, 1, 2)
    got = per_cam["intrinsics_embedding"].pool(feats, cover.float(), m.nominal_intrinsics[None])
    assert torch.allclose(got, expect, atol=1e-5)


def test_semantic_loss_eq5():
    logits = torch.randn(1, 4, 3, 3)
    target = torch.tensor([[[1, 2, 3], [4, 0, 1], [3, 3, 2]]])
    vis = torch.rand(1, 3, 3)
    alpha = class_weights("paper")
    logp = logits.log_softmax(1)
    num = den = 0.0
    for i in range(3):
        for j in range(3):
            y = int(target[0, i, j])
            if y == 0:
                continue
            w = float(vis[0, i, j]) * float(alpha[y - 1])
            num += -w * float(logp[0, y - 1, i, j])
            den += w
    assert math.isclose(float(semantic_loss(logits, target, vis, alpha)), num / den, rel_tol=1e-5)
    # invisible cells carry no loss; with weighting off they do
    vis0 = vis.clone()
    vis0[0, 0, 0] = 0
    l1 = semantic_loss(logits, target, vis0, alpha)
    logits2 = logits.clone()
    logits2[0, :, 0, 0] = torch.tensor([-9.0, 5.0, 0.0, 1.0])
    assert torch.isclose(semantic_loss(logits2, target, vis0, alpha), l1)
    assert not torch.isclose(semantic_loss(logits2, target, vis0, alpha, use_visibility=False),
                             semantic_loss(logits, target, vis0, alpha, use_visibility=False))
    t = torch.tensor([[[0.0, 1.0], [0.3, 0.9]]])
    lo = torch.tensor([[[0.5, -1.0], [2.0, 0.0]]])
    ref = -(t * torch.log(torch.sigmoid(lo)) + (1 - t) * torch.log(1 - torch.sigmoid(lo))).mean()
    assert torch.isclose(occlusion_loss(lo, t), ref)
    # a turned sample's cells without a label (bev_known 0) are left out of the mean
    known = torch.tensor([[[1.0, 0.0], [1.0, 1.0]]])
    keep = known.bool()
    ref_known = -(t * torch.log(torch.sigmoid(lo)) + (1 - t) * torch.log(1 - torch.sigmoid(lo)))[keep].mean()
    assert torch.isclose(occlusion_loss(lo, t, known=known), ref_known)
    assert torch.isclose(occlusion_loss(lo, t, known=torch.ones_like(t)), ref)
    assert class_weights("uniform").tolist() == [1, 1, 1, 1]


def test_metrics_confusion_and_iou():
    g = torch.Generator().manual_seed(0)
    pred = torch.randint(0, 5, (2, 20, 20), generator=g)
    true = torch.randint(0, 5, (2, 20, 20), generator=g)
    vis = torch.rand(2, 20, 20, generator=g)
    cm = confusion(pred, true, vis)
    ref = torch.zeros(5, 5, dtype=torch.int64)
    for t, p, v in zip(true.flatten().tolist(), pred.flatten().tolist(), vis.flatten().tolist()):
        if t > 0 and v >= 0.5:
            ref[t, p] += 1
    assert torch.equal(cm, ref)
    m = BevMetrics(["invalid", "vehicle", "lane_marking", "street", "background"])
    logits = torch.nn.functional.one_hot(true.clamp(min=1) - 1, 4).permute(0, 3, 1, 2).float()
    occ = torch.where(vis >= 0.5, 3.0, -3.0)
    m.update(decode({"semantic": logits, "occlusion": occ}), {"semantic": true, "visibility": vis})
    res = m.compute()
    assert res["miou"] == 1.0 and res["iou/vehicle"] == 1.0 and res["iou/occlusion"] == 1.0
    m.reset()
    m.update(decode({"semantic": logits.roll(1, 1), "occlusion": -occ}), {"semantic": true, "visibility": vis})
    assert m.compute()["miou"] == 0.0


def test_config_validation_and_train_cli_exit_code(tmp_path):
    with pytest.raises(ConfigError, match=r"model\.pooling: must be one of"):
        validate({"model": {"pooling": "mean"}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"train\.lrate: unknown field"):
        validate({"train": {"lrate": 1}}, "x.yaml")
    with pytest.raises(ConfigError, match=r"data\.input_size"):
        validate({"data": {"input_size": [192]}}, "x.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("_base: " + str((__import__("pathlib").Path("configs/train/cpu_default.yaml")).resolve()) + "\ntrain:\n  batch_size: many\n")
    r = subprocess.run([sys.executable, "train.py", "--config", str(bad), "--out", str(tmp_path / "run")], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "train.batch_size" in r.stderr and str(bad) in r.stderr
    assert "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "train.py", "--bogus"], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == "error: train.py: unrecognized arguments: --bogus (see --help)", r.stderr


def test_every_shipped_config_validates():
    from model.config import load_config

    names = sorted(p.stem for p in Path("configs/train").glob("*.yaml"))
    assert {"cpu_default", "cpu_medium", "demo", "paper", "mixed_rig", "pool_sum"} <= set(names)
    for n in names:
        cfg = load_config(f"configs/train/{n}.yaml")
        if n.startswith("pool_"):
            assert cfg["model"]["pooling"] == n[5:]
    assert load_config("configs/train/paper.yaml")["data"]["input_size"] == [480, 302]
    assert load_config("configs/train/paper.yaml")["train"]["batch_size"] == 64


def test_the_makefiles_default_chain_agrees_with_itself():
    """`make dataset` writes data/$(PRESET); `make train`'s default config must train on that folder
    and validate on a split the preset has."""
    from dataset_tools.generation.dataset_config import load_config as load_dataset_config
    from model.config import load_config

    make = Path("Makefile").read_text()
    preset = re.search(r"^PRESET \?= (\S+)$", make, re.M).group(1)
    config = re.search(r"^CONFIG \?= (\S+)$", make, re.M).group(1)
    assert config == __import__("train").DEFAULT_CONFIG, "one default training config: train.py's is the Makefile's"
    cfg = load_config(config)
    assert cfg["data"]["root"] == f"data/{preset}", (config, cfg["data"]["root"], preset)
    splits = {s["split"] for s in load_dataset_config(f"configs/dataset/{preset}.yaml")["scenes"]}
    assert cfg["data"]["train_split"] in splits and cfg["data"]["val_split"] in splits, splits


def test_checkpoint_roundtrip_and_refuses_other_config(tmp_path):
    torch.manual_seed(0)
    rig = load_rig("configs/rigs/default.yaml")
    cfg = small_cfg(pooling="weighted_sum")
    model = build_model(cfg, rig)
    with torch.no_grad():
        model.pool.weight.mul_(1.5)
    path = tmp_path / "c.pt"
    save_checkpoint(path, {"config": cfg, "rig": rig.to_dict(), "model": model.state_dict()})
    loaded, cfg2, _ = load_checkpoint(path, expect_config=cfg)
    x = torch.rand(1, 4, 3, 40, 64)
    model.eval(), loaded.eval()
    assert torch.equal(model(x)["semantic"], loaded(x)["semantic"])
    with pytest.raises(CheckpointError, match="another config"):
        load_checkpoint(path, expect_config=small_cfg(pooling="sum"))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")


def test_an_older_checkpoint_is_upgraded_in_one_place(tmp_path):
    """A checkpoint written before model.trunk, data.rectify and num_classes existed loads (the
    reader fills their defaults), predicts the same, and is not taken for another config."""
    from model import NUM_CLASSES, read_checkpoint
    from model.checkpoint import upgrade_checkpoint

    torch.manual_seed(0)
    rig = load_rig("configs/rigs/default.yaml")
    cfg = small_cfg()
    model = build_model(cfg, rig)
    old = {k: {f: v for f, v in sec.items() if (k, f) not in (("model", "trunk"), ("data", "rectify"))} for k, sec in cfg.items()}
    assert "trunk" not in old["model"] and "rectify" not in old["data"]
    path = tmp_path / "old.pt"
    save_checkpoint(path, {"config": old, "rig": rig.to_dict(), "model": model.state_dict()})
    loaded, cfg2, ck = load_checkpoint(path, expect_config=cfg)
    assert cfg2["model"]["trunk"] == "scratch" and cfg2["data"]["rectify"] == "none" and ck["num_classes"] == NUM_CLASSES == 5
    assert ck["class_names"] == ["invalid", "vehicle", "lane_marking", "street", "background"], "old: the default classes"
    mine = ["invalid", "ground", "paint", "car", "other"]
    save_checkpoint(tmp_path / "new.pt", {"config": cfg, "rig": rig.to_dict(), "model": model.state_dict(), "class_names": mine})
    assert load_checkpoint(tmp_path / "new.pt")[2]["class_names"] == mine, "a checkpoint carries its class names"
    save_checkpoint(tmp_path / "bad.pt", {"config": cfg, "rig": rig.to_dict(), "model": model.state_dict(), "class_names": mine[:3]})
    with pytest.raises(CheckpointError, match=r"bad.pt: class_names: must be a list of 5 names"):
        load_checkpoint(tmp_path / "bad.pt")
    x = torch.rand(1, 4, 3, 40, 64)
    model.eval(), loaded.eval()
    assert torch.equal(model(x)["semantic"], loaded(x)["semantic"])
    with pytest.raises(CheckpointError, match=r"x.pt: config\.model\.pooling: must be one of"):
        upgrade_checkpoint({"config": {"model": {"pooling": "mean"}}}, "x.pt")
    # resuming needs the training state too, and says how to start afresh
    with pytest.raises(CheckpointError, match=r"old.pt: not a checkpoint of train.py \(missing 'optimizer'\); move it away"):
        read_checkpoint(path, resume=True)
    with pytest.raises(CheckpointError, match="old.pt: checkpoint is from another rig"):
        read_checkpoint(path, expect_rig=load_rig("configs/rigs/mixed.yaml"))


def test_zero_intervals_are_valid_and_cross_field_checks_remain():
    """The schema holds the bounds (0 = at epoch ends only / no per-step scalars); only what the
    schema cannot say is checked after it."""
    cfg = validate({"train": {"checkpoint_every": 0, "log_every": 0}}, "c.yaml")
    assert cfg["train"]["checkpoint_every"] == 0 and cfg["train"]["log_every"] == 0
    with pytest.raises(ConfigError, match=r"train\.batch_size: must be a whole number in \[1, 4096\], got 0"):
        validate({"train": {"batch_size": 0}}, "c.yaml")
    with pytest.raises(ConfigError, match=r"model\.depth: need min < max"):
        validate({"model": {"depth": {"min": 5.0, "max": 2.0}}}, "c.yaml")
    with pytest.raises(ConfigError, match=r"model\.stride: must be a power of 2"):
        validate({"model": {"stride": 6}}, "c.yaml")
    assert validate({"augment": {"mirror": 0.5}}, "c.yaml")["augment"]["mirror"] == 0.5
    assert validate({"augment": {"bev_rotation_deg": 22.5}}, "c.yaml")["augment"]["bev_rotation_deg"] == 22.5
    with pytest.raises(ConfigError, match=r"c\.yaml: augment\.bev_rotation_deg"):
        validate({"augment": {"bev_rotation_deg": 200}}, "c.yaml")
    with pytest.raises(ConfigError, match=r"c\.yaml: augment\.mirror: needs a pooling that treats every camera alike"):
        validate({"augment": {"mirror": 0.5}, "model": {"pooling": "weighted_sum"}}, "c.yaml")
    with pytest.raises(ConfigError, match=r"augment\.mirror: the input width 190 must be a multiple of model\.stride 8"):
        validate({"augment": {"mirror": 0.5}, "data": {"input_size": [190, 120]}}, "c.yaml")
    with pytest.raises(ConfigError, match=r"augment\.mirror: data\.grid's y range \[-20, 25\] must be symmetric"):
        validate({"augment": {"mirror": 0.5}, "data": {"grid": {"x_min": -25, "x_max": 25, "y_min": -20, "y_max": 25, "res": 0.25}}}, "c.yaml")


def test_predict_gives_class_ids_and_visibility():
    from model import Prediction, predict

    torch.manual_seed(0)
    model = build_model(small_cfg(), load_rig("configs/rigs/default.yaml")).eval()
    batch = {"images": torch.rand(2, 4, 3, 40, 64)}
    with torch.no_grad():
        out, pred = model(batch["images"]), predict(model, batch)
    assert isinstance(pred, Prediction) and pred.classes.shape == out["occlusion"].shape == (2, *model.grid.shape)
    assert torch.equal(pred.classes, out["semantic"].argmax(1) + 1) and pred.classes.min() >= 1 and pred.classes.max() <= 4
    assert torch.equal(pred.visibility, torch.sigmoid(out["occlusion"]))


@pytest.mark.parametrize("stride", [4, 8])
def test_encoder_feature_pixels_are_centred_where_the_lift_assumes(stride):
    """With symmetric (constant) kernels the encoder is a linear, mirror-symmetric filter, so the
    centroid of a feature pixel's input gradient is the image point it is centred on: it must be
    (s j + (s - 1) / 2, s i + (s - 1) / 2), the pixel grid of camera.resized(W/s, H/s)."""
    from model.encoder import ImageEncoder

    enc = ImageEncoder((4, 4, 4, 4), (1, 1, 1), stride=stride, depth_bins=2, context_channels=2, norm="batch").eval()
    with torch.no_grad():
        for m in enc.modules():
            if isinstance(m, torch.nn.Conv2d):
                m.weight.fill_(1.0 / m.weight[0].numel())
                if m.bias is not None:
                    m.bias.zero_()
    n = 256
    x = torch.ones(1, 3, n, n, requires_grad=True)
    depth, _ = enc(x)
    assert depth.shape[-2:] == (n // stride, n // stride)
    c = n // stride // 2
    for i, j in [(c, c), (c - 1, c + 2), (c + 2, c - 1)]:
        (g,) = torch.autograd.grad(depth[0, 0, i, j], x, retain_graph=True)
        w = g[0].abs().sum(0)
        v, u = torch.meshgrid(torch.arange(float(n)), torch.arange(float(n)), indexing="ij")
        cu, cv = float((u * w).sum() / w.sum()), float((v * w).sum() / w.sum())
        # (zero padding at the far image borders still pulls the deepest level by a hair)
        assert abs(cu - (stride * j + (stride - 1) / 2)) < 0.02 and abs(cv - (stride * i + (stride - 1) / 2)) < 0.02, (cu, cv)


@pytest.mark.parametrize("stride", [8, 16])
def test_pretrained_trunk_feature_pixels_are_centred_where_the_lift_assumes(stride):
    """The same for the EfficientNet-Lite0 trunk (stride-2 kernels widened and padded
    symmetrically): constant kernels, identity batch norms, an input small enough that ReLU6 stays
    linear. Its receptive field reaches the borders, which pull a centroid towards the image
    centre, so the check uses the two feature pixels either side of the centre: mirror images of
    each other, their centroids must sum to (n - 1) exactly when a pixel sits at s j + (s - 1) / 2
    (half a pixel off per stride-2 level, as "SAME" padding is, would add 2 x 3.5 px at stride 8)."""
    from model.efficientnet import EfficientNetLite0Encoder

    enc = EfficientNetLite0Encoder(stride, depth_bins=2, context_channels=2, width=8, norm="batch").eval()
    with torch.no_grad():
        for m in enc.modules():
            if isinstance(m, torch.nn.Conv2d):
                assert m.kernel_size[0] % 2 == (0 if m.stride[0] == 2 else 1)
                m.weight.fill_(1.0 / m.weight[0].numel())
                if m.bias is not None:
                    m.bias.zero_()
            elif isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.zero_(), m.running_var.fill_(1.0), m.weight.fill_(1.0), m.bias.zero_()
    n = 256
    x = torch.full((1, 3, n, n), 1e-3, requires_grad=True)
    depth, _ = enc(x)
    assert depth.shape[-2:] == (n // stride, n // stride)
    c = n // stride // 2
    v, u = torch.meshgrid(torch.arange(float(n)), torch.arange(float(n)), indexing="ij")
    cents = {}
    for i, j in [(c - 1, c - 1), (c, c)]:
        (g,) = torch.autograd.grad(depth[0, 0, i, j], x, retain_graph=True)
        w = g[0].abs().sum(0)
        cents[j] = float((u * w).sum() / w.sum()), float((v * w).sum() / w.sum())
    for k in (0, 1):
        assert abs(cents[c - 1][k] + cents[c][k] - (n - 1)) < 0.02, cents
        assert abs(cents[c][k] - cents[c - 1][k] - stride) < 0.5 * stride, cents


def test_pretrained_trunk_without_its_package_is_a_one_line_config_error(monkeypatch):
    import sys

    from common.errors import ConfigError
    from model.efficientnet import EfficientNetLite0Encoder

    monkeypatch.setitem(sys.modules, "efficientnet_lite_pytorch", None)  # import fails as if not installed
    with pytest.raises(ConfigError, match="model.trunk: efficientnet_lite0 needs the packages"):
        EfficientNetLite0Encoder(8)
