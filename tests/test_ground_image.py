"""The ground image (model.ground_channels): where each BEV cell's ground point lies in each input
image (model.frustum.Frustum.ground_grid), what the model reads there (model.ground), and that an
untrained one changes nothing."""

import math

import numpy as np
import pytest
import torch

from geometry.rig import load_rig
from model import build_model
from model.augment import random_transform, warp_image
from model.config import ConfigError, validate
from model.frustum import GROUND_OFF, Frustum, ground_projection
from model.ground import ground_colours, sample_ground


def cfg_of(ground: int = 6, size=(96, 60), bound: float = 12.0, res: float = 0.5, **model):
    m = {"encoder": {"widths": [8, 16, 16], "blocks": [1, 1]}, "stride": 4, "context_channels": 8,
         "depth": {"min": 1.0, "max": 30.0, "bins": 8}, "bev_encoder": {"widths": [8, 16, 16], "blocks": [1, 1]},
         "ground_channels": ground, **model}
    return validate({"data": {"input_size": list(size), "grid": {"bound": bound, "res": res}}, "model": m})


def pixels(grid: np.ndarray, size) -> np.ndarray:
    """grid_sample positions -> input pixel positions (u, v)."""
    w, h = size
    return np.stack([(grid[..., 0] + 1) / 2 * w - 0.5, (grid[..., 1] + 1) / 2 * h - 0.5], -1)


@pytest.mark.parametrize("rig_path", ["configs/rigs/default.yaml", "configs/rigs/mixed.yaml"])
def test_ground_grid_is_the_projection_through_the_input_cameras(rig_path):
    """The native projection moved by each view transform's pixel map equals the ground points
    projected through the transformed cameras themselves (geometry's camera models), to 1e-4 px;
    a cell is seen only where the warped image has the camera's pixels, not the crop's padding."""
    cfg = cfg_of(size=(128, 80), bound=25.0, res=0.25)
    rig = load_rig(rig_path)
    fr = Frustum(rig, cfg)
    size = fr.input_size
    rng = np.random.default_rng(3)
    for _ in range(4):
        ts = [random_transform(rc.camera, size, rng, [0.8, 1.2], 10.0, True) for rc in rig]
        got = fr.ground_grid(ts).numpy()
        seen = (got != GROUND_OFF).all(-1)
        uv, on = ground_projection(fr.input_rig(ts), fr.grid)
        both = seen & on
        assert both.mean() > 0.2
        assert np.abs(pixels(got, size)[both] - uv[both]).max() < 1e-4
        assert not (seen & ~on).any()
        for i, (rc, t) in enumerate(zip(rig, ts)):  # where the transformed camera says "on" and we do not: padding
            white = warp_image(np.full((rc.camera.height, rc.camera.width, 3), 255, np.uint8), rc.camera, t)
            u = np.clip(np.round(uv[i][..., 0]).astype(int), 0, size[0] - 1)
            v = np.clip(np.round(uv[i][..., 1]).astype(int), 0, size[1] - 1)
            content = on[i] & (white[v, u, 0] == 255)
            assert seen[i][content].mean() > 0.995
            off = on[i] & ~seen[i]
            assert not off.any() or (white[v, u, 0][off] < 255).mean() > 0.9


def test_turned_ground_grid_is_the_grid_turned():
    """A world turned by 90 degrees (augment.bev_rotation_deg) puts cell p's ground point where the
    unturned world has that of rot_z(-90) p: on a square grid, the grid rotated by a quarter turn."""
    cfg = cfg_of()
    rig = load_rig("configs/rigs/default.yaml")
    fr = Frustum(rig, cfg)
    ts = fr.nominal_transforms()
    flat, turned = fr.ground_grid(ts).numpy(), fr.ground_grid(ts, yaw=math.pi / 2).numpy()
    # row i is x = x_max - (i + 0.5) res, column j y = y_max - (j + 0.5) res; the turned world's cell
    # (x, y) shows the ground point (y, -x) of the unturned one: turned[i, j] = flat[j, rows - 1 - i]
    want = np.rot90(flat, k=1, axes=(1, 2))
    seen = (turned != GROUND_OFF).all(-1) & (want != GROUND_OFF).all(-1)
    assert seen.mean() > 0.3
    assert np.abs(turned - want)[seen].max() < 1e-5
    assert ((turned != GROUND_OFF).all(-1) == (want != GROUND_OFF).all(-1)).mean() > 0.999
    # with view transforms too: the projection through the transformed cameras of the turned rig
    rng = np.random.default_rng(5)
    ts = [random_transform(rc.camera, fr.input_size, rng, [0.8, 1.2], 10.0, True) for rc in rig]
    got = fr.ground_grid(ts, yaw=0.3).numpy()
    uv, on = ground_projection(fr.input_rig(ts).turned(0.3), fr.grid)
    seen = (got != GROUND_OFF).all(-1)
    assert (seen & on).mean() > 0.2 and not (seen & ~on).any()
    assert np.abs(pixels(got, fr.input_size)[seen] - uv[seen]).max() < 1e-4


def test_ground_samples_read_each_image_at_the_ground_point():
    """An image whose channels are its own pixel coordinates, sampled at the ground grid, gives back
    the projected positions (grid_sample's pixel convention is the camera models'), and each
    camera's last channel says where it sees the cell."""
    cfg = cfg_of()
    rig = load_rig("configs/rigs/default.yaml")
    fr = Frustum(rig, cfg)
    w, h = fr.input_size
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    img = torch.from_numpy(np.stack([u, v, np.ones_like(u)]))[None, None].expand(1, len(rig), 3, h, w)
    grid = fr.nominal_ground
    got = sample_ground(img, grid[None])[0].view(len(rig), 4, *fr.grid.shape).numpy()
    uv = pixels(grid.numpy(), (w, h))
    seen = (grid.numpy() != GROUND_OFF).all(-1)
    inner = seen & (uv[..., 0] > 0) & (uv[..., 0] < w - 1) & (uv[..., 1] > 0) & (uv[..., 1] < h - 1)
    assert inner.mean() > 0.2
    assert np.abs(got[:, 0][inner] - uv[..., 0][inner]).max() < 1e-3
    assert np.abs(got[:, 1][inner] - uv[..., 1][inner]).max() < 1e-3
    assert (got[:, 3] == seen).all()
    assert (got[:, :3][np.broadcast_to(~seen[:, None], got[:, :3].shape)] == 0).all()


def test_an_untrained_ground_image_changes_nothing_and_learns():
    """Built last with its output maps at zero: the same initial weights and outputs as the model
    without it; after one step its maps have moved, and the outputs differ."""
    rig = load_rig("configs/rigs/default.yaml")
    torch.manual_seed(0)
    plain = build_model(cfg_of(ground=0), rig)
    torch.manual_seed(0)
    model = build_model(cfg_of(ground=6), rig)
    for name, p in plain.state_dict().items():
        assert torch.equal(model.state_dict()[name], p), name
    x = torch.rand(2, 4, 3, 60, 96)
    out, base = model(x), plain(x)
    assert torch.equal(out["semantic"], base["semantic"]) and torch.equal(out["occlusion"], base["occlusion"])
    (out["semantic"].square().mean() + out["occlusion"].square().mean()).backward()
    assert model.ground.to_head.weight.grad.abs().sum() > 0 and model.ground.to_bev.weight.grad.abs().sum() > 0
    torch.optim.SGD(model.parameters(), lr=0.1).step()
    model.eval()
    with torch.no_grad():
        assert not torch.equal(model(x)["semantic"], plain.eval()(x)["semantic"])
        # the cached nominal grid and the same grid handed in give one answer
        g = model.nominal_ground[None].expand(2, -1, -1, -1, -1)
        assert torch.allclose(model(x, ground_grid=g)["semantic"], model(x)["semantic"], atol=1e-6)


def test_the_mirror_is_refused_with_a_ground_image():
    with pytest.raises(ConfigError, match=r"augment\.mirror: the ground image"):
        validate({"augment": {"mirror": 0.5}, "model": {"ground_channels": 8}}, "c.yaml")


def test_ground_image_of_a_real_render_shows_the_paint_where_the_labels_have_it(tiny_dataset):
    """The tiny preset's frames (real Blender renders, fused labels), read as training reads them
    with a ground image: the colours sampled at cells labelled lane marking are brighter than those
    at cells labelled street, as white paint on asphalt is, and much less so with the labels moved
    sideways by a few metres (the paint is where the labels have it, not only somewhere)."""
    from model.data import BevDataset

    root = tiny_dataset
    cfg = validate({"data": {"root": str(root), "input_size": [64, 40], "grid": {"bound": 25.0, "res": 0.78125}},
                    "model": {"ground_channels": 8}})
    ds = BevDataset(root, "train", cfg)
    names = ds.class_names
    c = (np.arange(ds.grid.rows) - ds.grid.rows / 2 + 0.5) * ds.grid.res
    near = torch.from_numpy(np.hypot(c[:, None], c[None, :]) < 12)  # where 64 x 40 images still resolve paint
    diffs = {}
    for shift in (0, 3, 5):  # the labels moved sideways by 2.3 and 3.9 m: the paint no longer where they say
        paint, road = [], []
        for i in range(len(ds)):
            s = ds[i]
            grid = s.get("ground_grid", ds.frustum.nominal_ground)
            lum = ground_colours(s["images"], grid).mean(0)
            sem = torch.roll(s["semantic"], shift, 1)
            ok = (grid != GROUND_OFF).all(-1).any(0) & near
            paint.append(lum[(sem == names.index("lane_marking")) & ok])
            road.append(lum[(sem == names.index("street")) & ok])
        paint, road = torch.cat(paint), torch.cat(road)
        assert len(paint) > 50 and len(road) > 500
        diffs[shift] = float(paint.mean() - road.mean())
    assert diffs[0] > 0.02 and diffs[0] > 2 * max(diffs[3], diffs[5]), diffs
