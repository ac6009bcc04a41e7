"""train.py end to end: tiny overfit, DDP == single process, exact resume after a kill, mixed rig."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml


ROOT = Path(__file__).resolve().parents[1]

TINY_MODEL = {
    "encoder": {"widths": [16, 32, 32], "blocks": [1, 1]},
    "stride": 4,
    "context_channels": 16,
    "depth": {"min": 1.0, "max": 37.0, "bins": 24},
    "bev_encoder": {"widths": [16, 32, 32], "blocks": [1, 1]},
}


def write_config(path: Path, root, **sections) -> Path:
    cfg = {
        "_base": str(ROOT / "configs/train/cpu_default.yaml"),
        "data": {"root": str(root), "val_split": "", "input_size": [64, 40], "grid": {"bound": 25.0, "res": 0.5}, "num_workers": 0},
        "model": dict(TINY_MODEL),
        "train": {"epochs": 50, "batch_size": 2, "lr": 3e-3, "threads": 1, "checkpoint_every": 1000, "image_every": 0, "log_every": 5},
    }
    for k, v in sections.items():
        cfg.setdefault(k, {}).update(v)
    path.write_text(yaml.safe_dump(cfg))
    return path


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_train(config, out, *extra, nproc=1, check=True, popen=False):
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    if nproc > 1:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", str(nproc), "--master_port", str(free_port()),
               "train.py", "--config", str(config), "--out", str(out), "--quiet", *extra]
    else:
        cmd = [sys.executable, "train.py", "--config", str(config), "--out", str(out), "--quiet", *extra]
    if popen:
        return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    if check:
        assert r.returncode == 0, r.stderr[-3000:]
    return r


def params(path):
    ck = torch.load(path, map_location="cpu", weights_only=False)
    return ck, ck["model"]


def test_two_ddp_processes_give_the_same_update_as_one(real_tiny, tmp_path):
    from geometry.rig import rig_from_dict
    from model import build_model

    cfg = write_config(tmp_path / "c.yaml", real_tiny, train={"max_steps": 1, "batch_size": 4, "lr": 1e-3},
                       data={"grid": label_grid(real_tiny)})
    run_train(cfg, tmp_path / "one")
    run_train(cfg, tmp_path / "two", nproc=2)
    ck1, p1 = params(tmp_path / "one" / "latest.pt")
    ck2, p2 = params(tmp_path / "two" / "latest.pt")
    assert ck1["step"] == ck2["step"] == 1
    torch.manual_seed(ck1["config"]["train"]["seed"])
    model = build_model(ck1["config"], rig_from_dict(ck1["rig"]))
    names = [n for n, _ in model.named_parameters()]
    init = model.state_dict()
    s1, s2 = ck1["optimizer"]["state"], ck2["optimizer"]["state"]
    assert len(s1) == len(s2) == len(names)
    lr = ck1["config"]["train"]["lr"]
    checked = total = 0
    for i, name in enumerate(names):
        # the averaged gradient (Adam's first moment after one step is 0.1 g) agrees to rounding
        g1, g2 = s1[i]["exp_avg"] / 0.1, s2[i]["exp_avg"] / 0.1
        assert torch.allclose(g1, g2, atol=1e-5 * float(g1.abs().max()) + 1e-12, rtol=0), name
        # so does the update, wherever the gradient is well above Adam's eps (1e-8): the first Adam
        # step is lr * g / (|g| + eps), which rounding can move for gradients near eps
        d1, d2 = p1[name] - init[name], p2[name] - init[name]
        big = g1.abs() > 1e-6
        assert torch.allclose(d1[big], d2[big], atol=0.01 * lr, rtol=0), name
        assert (d1[big].abs() > 0.5 * lr).all()  # the step did move these weights
        checked += int(big.sum())
        total += big.numel()
    assert checked > 0.9 * total


def test_accumulated_micro_batches_give_the_update_of_one_batch(real_tiny, tmp_path):
    """train.accumulate: 2 micro-batches of 2 samples make the gradient of one batch of 4 (the same
    samples: the loader draws effective batches), and a step counts optimiser steps. No clipping:
    it would hide a gradient of the wrong scale."""
    grid = {"grid": label_grid(real_tiny)}
    whole = write_config(tmp_path / "a.yaml", real_tiny, train={"max_steps": 1, "batch_size": 4, "grad_clip": 0.0}, data=grid)
    split = write_config(tmp_path / "b.yaml", real_tiny, train={"max_steps": 1, "batch_size": 2, "accumulate": 2, "grad_clip": 0.0}, data=grid)
    run_train(whole, tmp_path / "whole")
    run_train(split, tmp_path / "split")
    ck1, _ = params(tmp_path / "whole" / "latest.pt")
    ck2, _ = params(tmp_path / "split" / "latest.pt")
    assert ck1["step"] == ck2["step"] == 1
    s1, s2 = ck1["optimizer"]["state"], ck2["optimizer"]["state"]
    assert len(s1) == len(s2) > 0
    for i in s1:
        g1, g2 = s1[i]["exp_avg"] / 0.1, s2[i]["exp_avg"] / 0.1  # Adam's first moment after one step: 0.1 g
        assert torch.allclose(g1, g2, atol=1e-5 * float(g1.abs().max()) + 1e-12, rtol=0), i
    assert any(float(s1[i]["exp_avg"].abs().max()) > 0 for i in s1)


def test_resumed_run_continues_exactly_after_a_kill(real_tiny, tmp_path):
    # 14 frames, batch 4: 3 steps per epoch, so 7 steps cross two epoch boundaries
    cfg = write_config(tmp_path / "c.yaml", real_tiny, train={"max_steps": 7, "checkpoint_every": 2, "batch_size": 4},
                       augment={"enabled": True}, model={**TINY_MODEL, "dropout": 0.2}, data={"grid": label_grid(real_tiny)})
    run_train(cfg, tmp_path / "straight")
    proc = run_train(cfg, tmp_path / "killed", popen=True)
    latest = tmp_path / "killed" / "latest.pt"
    t0 = time.time()
    while not latest.exists() and proc.poll() is None and time.time() - t0 < 240:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_step = torch.load(latest, weights_only=False)["step"]
    assert 0 < killed_step < 7, "the kill came too late to test a resume"
    run_train(cfg, tmp_path / "killed")
    a, pa = params(tmp_path / "straight" / "latest.pt")
    b, pb = params(tmp_path / "killed" / "latest.pt")
    assert a["step"] == b["step"] == 7
    for k in pa:
        assert torch.equal(pa[k], pb[k]), k
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
        assert torch.equal(sa["exp_avg"], sb["exp_avg"])

    # Ctrl-C: the run finishes its step, saves latest.pt and exits 130; the resume is exact too
    proc = run_train(cfg, tmp_path / "ctrl_c", popen=True)
    latest = tmp_path / "ctrl_c" / "latest.pt"
    while not latest.exists() and proc.poll() is None:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=120) == 130
    stopped = torch.load(latest, weights_only=False)["step"]
    assert 0 < stopped < 7
    run_train(cfg, tmp_path / "ctrl_c")
    c, pc = params(latest)
    assert c["step"] == 7 and all(torch.equal(pa[k], pc[k]) for k in pa)


def test_the_averaged_weights_are_what_the_checkpoint_serves_and_a_resume_continues_them(real_tiny, tmp_path):
    """train.ema: latest.pt's `model` is the moving average (eval and predict read it), `raw` the
    trained weights; a run stopped after each step and resumed ends bit-identical to a straight one,
    and its average is the formula's, step by step."""
    grid = {"grid": label_grid(real_tiny)}

    def cfg(steps):
        return write_config(tmp_path / f"c{steps}.yaml", real_tiny, train={"max_steps": steps, "batch_size": 4, "ema": 0.9},
                            data=grid)
    run_train(cfg(3), tmp_path / "straight")
    ema = None
    for step in (1, 2, 3):
        run_train(cfg(step), tmp_path / "stepped")
        ck = torch.load(tmp_path / "stepped" / "latest.pt", map_location="cpu", weights_only=False)
        assert ck["step"] == step
        if ema is None:
            ema = ck["model"]
            continue
        d = min(0.9, (1 + step) / (10 + step))
        ema = {k: d * ema[k] + (1 - d) * ck["raw"][k] if ema[k].dtype.is_floating_point else ck["raw"][k] for k in ema}
        for k in ema:
            assert torch.allclose(ck["model"][k], ema[k], rtol=1e-5, atol=1e-7), k
    a = torch.load(tmp_path / "straight" / "latest.pt", map_location="cpu", weights_only=False)
    for k in a["model"]:
        assert torch.equal(a["model"][k], ck["model"][k]) and torch.equal(a["raw"][k], ck["raw"][k]), k
    moved = [k for k in a["model"] if a["model"][k].dtype.is_floating_point and not torch.equal(a["model"][k], a["raw"][k])]
    assert moved, "the average must differ from the last weights"


def render_dataset(out: Path, dataset_config: Path) -> Path:
    """Real renders: generator (Blender) then label fusion."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for cmd in (["-m", "dataset_tools", "generate", "--config", str(dataset_config), "--out", str(out)],
                ["-m", "dataset_tools", "fuse", str(out)]):
        r = subprocess.run([sys.executable, *cmd], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-3000:]
    assert (out / "index.json").is_file()
    return out


@pytest.fixture(scope="session")
def real_tiny(tiny_dataset):
    """configs/dataset/tiny.yaml rendered by Blender and fused (conftest's shared session fixture:
    14 frames of 64x40, labels 64x64); read only here, runs write to their own folders."""
    return tiny_dataset


@pytest.fixture(scope="session")
def real_mixed(tmp_path_factory):
    """The tiny preset rendered with the mixed rig (four fisheye models + a pinhole), two scenes."""
    d = tmp_path_factory.mktemp("real_mixed")
    cfg = yaml.safe_load((ROOT / "configs/dataset/tiny.yaml").read_text())
    cfg["rig"] = str(ROOT / "configs/rigs/mixed.yaml")
    cfg["scenes"] = cfg["scenes"][:2]
    (d / "mixed.yaml").write_text(yaml.safe_dump(cfg))
    return render_dataset(d / "ds", d / "mixed.yaml")


def label_grid(root):
    from dataset_tools.format.reader import DatasetIndex

    g = DatasetIndex(root).grid
    return {"x_min": g.x_min, "x_max": g.x_max, "y_min": g.y_min, "y_max": g.y_max, "res": g.res}


def evaluate_checkpoint(model, cfg, root):
    from dataset_tools.format.reader import DatasetIndex
    from model.data import BevDataset
    from model.evaluation import validation_scores

    ds = BevDataset(DatasetIndex(root), "train", cfg, train=False)
    return validation_scores(model, ds, cfg, torch.device("cpu"), 0, 1)


def overfit(root, tmp_path, steps=60):
    from geometry.rig import rig_from_dict
    from model import build_model, load_checkpoint

    cfg_path = write_config(tmp_path / "c.yaml", root, train={"max_steps": steps}, augment={"enabled": False},
                            data={"grid": label_grid(root)})
    run_train(cfg_path, tmp_path / "run")
    model, cfg, ck = load_checkpoint(tmp_path / "run" / "latest.pt")
    torch.manual_seed(cfg["train"]["seed"])
    init = build_model(cfg, rig_from_dict(ck["rig"]))
    before, after = evaluate_checkpoint(init, cfg, root), evaluate_checkpoint(model, cfg, root)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ev = EventAccumulator(str(tmp_path / "run" / "tb"))
    ev.Reload()
    losses = [s.value for s in ev.Scalars("train/loss")]
    return losses, before, after


def test_tiny_overfit_on_real_renders_loss_falls_and_iou_rises(real_tiny, tmp_path):
    losses, before, after = overfit(real_tiny, tmp_path)
    print(f"\noverfit: loss {losses[0]:.3f} -> {losses[-1]:.3f}; mIoU {before['miou']:.3f} -> {after['miou']:.3f};",
          {k: round(v, 3) for k, v in after.items()})
    assert losses[-1] < 0.6 * losses[0], losses
    assert after["miou"] > before["miou"] + 0.1, (before, after)
    assert after["iou/background"] > 0.5


def test_mixed_rig_trains_on_real_renders(real_mixed, tmp_path):
    from model import load_checkpoint

    cfg_path = write_config(tmp_path / "c.yaml", real_mixed, train={"max_steps": 12, "log_every": 1},
                            data={"grid": label_grid(real_mixed)}, model={**TINY_MODEL, "pooling": "intrinsics_embedding"})
    run_train(cfg_path, tmp_path / "run")
    model, cfg, ck = load_checkpoint(tmp_path / "run" / "latest.pt")
    assert ck["step"] == 12 and model.camera_names == ["front", "left", "rear", "right", "front_pinhole"]
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ev = EventAccumulator(str(tmp_path / "run" / "tb"))
    ev.Reload()
    losses = [s.value for s in ev.Scalars("train/loss")]
    assert len(losses) == 12 and all(map(lambda v: v == v, losses))
    assert sum(losses[-3:]) / 3 < 0.85 * losses[0], losses
    # the five cameras' intrinsics descriptors differ (the pooling can tell the models apart)
    d = model.nominal_intrinsics
    assert torch.cdist(d, d).add(torch.eye(5) * 1e3).min() > 1e-3


def toy_rig_run(tmp_path, *extra, quiet=True):
    """A 1-step run on a 2-frame constructed data set (testing.toy_data: no Blender) of the default
    rig at 64x40. -> (data set root, run folder, train.py's CompletedProcess)."""
    from testing.toy_data import write_toy_dataset

    root = write_toy_dataset(tmp_path / "toy", frames=2, image_scale=64 / 480)
    cfg = write_config(tmp_path / "c.yaml", root, train={"max_steps": 1}, augment={"enabled": False})
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    cmd = [sys.executable, "train.py", "--config", str(cfg), "--out", str(tmp_path / "run"), *(["--quiet"] if quiet else []), *extra]
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    return root, tmp_path / "run", r


def rig_lines(stdout: str, source) -> list[str]:
    """The lines that say what each camera of a rig became (geometry.rig.Rig.describe), checked to
    name `source` and to come once per camera of the default rig, in its order."""
    lines = [ln for ln in stdout.splitlines() if ln.startswith("rig ")]
    assert [ln.split(": ")[1] for ln in lines] == ["front", "left", "rear", "right"], stdout
    assert all(ln.startswith(f"rig {source}: ") and "opencv_fisheye (exact" in ln for ln in lines), lines
    return lines


def test_train_says_once_what_each_camera_of_the_rig_is(tmp_path):
    """train.py prints, once at start, what each camera of the rig the model is built on became
    (the data set's rig, through Rig.describe as generate, stitch and predict.py print it)."""
    root, run, r = toy_rig_run(tmp_path, quiet=False)
    rig_lines(r.stdout, root)
    assert (run / "latest.pt").is_file()


def test_workers_building_parts_of_a_batch_give_the_run_of_one_loader(real_tiny, tmp_path):
    """data.num_workers 2 cuts each step's batch into 2 loader batches (model.training.Pieces), one
    per worker, and joins them: the same samples in the same order, so the same run, bit for bit,
    as the batch read whole in the main process (num_workers 0), augmentation on, across an epoch."""
    grid = {"grid": label_grid(real_tiny)}
    for name, workers in (("whole", 0), ("pieces", 2)):
        cfg = write_config(tmp_path / f"{name}.yaml", real_tiny, train={"max_steps": 4, "batch_size": 4},
                           augment={"enabled": True}, data={**grid, "num_workers": workers})
        run_train(cfg, tmp_path / name)
    a, pa = params(tmp_path / "whole" / "latest.pt")
    b, pb = params(tmp_path / "pieces" / "latest.pt")
    assert a["step"] == b["step"] == 4
    for k in pa:
        assert torch.equal(pa[k], pb[k]), k


def test_pieces_cover_each_batch_in_order():
    from model.training import EpochBatches, Pieces, join_pieces

    batches = EpochBatches(14, 5, seed=3, epoch=1, rank=0, world=1)
    pieces = Pieces(batches, 4, 5)
    parts = list(pieces)
    assert len(parts) == len(pieces) == 2 * 4 and all(parts)
    assert [i for p in parts[:4] for i in p] == list(batches)[0] and [i for p in parts[4:] for i in p] == list(batches)[1]
    assert Pieces(batches, 8, 5).per_step == 5 and Pieces(batches, 0, 5).per_step == 1
    joined = join_pieces([{"x": torch.arange(2), "n": 1}, {"x": torch.arange(2, 5), "n": 2}])
    assert torch.equal(joined["x"], torch.arange(5)) and joined["n"] == 1


def test_one_loader_for_the_run_gives_each_epochs_batches_and_augmentation():
    """RunBatches: the batches of each epoch in turn (the first from its resumed batch), each sample
    tagged with its epoch, which BevDataset augments as that epoch's (the run-long loader's samples
    are those of one loader per epoch: same run, bit for bit, in test_resumed_run... and
    test_workers_building_parts...)."""
    from model.training import EpochBatches, RunBatches

    run = RunBatches(14, 4, seed=3, epoch=1, epochs=4, rank=1, world=2, start=2)
    want = [[(e, i) for i in b] for e in (1, 2, 3) for b in EpochBatches(14, 4, 3, e, 1, 2, 2 if e == 1 else 0)]
    assert list(run) == want and len(run) == len(want) == 1 + 3 + 3
    assert all(len(b) == 2 for b in run)  # rank 1's share of each batch of 4
    assert len(RunBatches(14, 4, 3, epoch=4, epochs=4, rank=0, world=1)) == 0


def test_a_sample_keyed_by_epoch_is_that_epochs_sample(real_tiny, tmp_path):
    from model.config import load_config
    from model.data import BevDataset

    cfg = load_config(write_config(tmp_path / "c.yaml", real_tiny, augment={"enabled": True}, data={"grid": label_grid(real_tiny)}))
    ds = BevDataset(real_tiny, "train", cfg, train=True)
    ds.set_epoch(3)
    a, b, c = ds[1], ds[(3, 1)], ds[(4, 1)]
    assert torch.equal(a["images"], b["images"]) and torch.equal(a["point_cell"], b["point_cell"])
    assert not torch.equal(a["images"], c["images"])  # another epoch, another augmentation


def test_a_cached_frame_gives_the_samples_of_a_fresh_read(real_tiny, tmp_path):
    """data.cache_mb: frames decoded (labels pooled) once per loader process; a sample from the
    cache is the sample from the files, every key, and a cache too small keeps nothing."""
    from model.config import load_config
    from model.data import BevDataset

    cfg = load_config(write_config(tmp_path / "c.yaml", real_tiny, augment={"enabled": True}, data={"grid": label_grid(real_tiny)}))
    keys = [(2, 0), (2, 1), (5, 1), (5, 0)]
    none = BevDataset(real_tiny, "train", {**cfg, "data": {**cfg["data"], "cache_mb": 0}}, train=True)
    want = [none[k] for k in keys]
    assert not none.cache
    ds = BevDataset(real_tiny, "train", cfg, train=True)
    for _ in range(2):  # the first read fills the cache, the second reads from it
        got = [ds[k] for k in keys]
        assert sorted(ds.cache) == [0, 1]
        for g, w in zip(got, want):
            assert g.keys() == w.keys()
            assert all(torch.equal(g[k], w[k]) if torch.is_tensor(w[k]) else g[k] == w[k] for k in w)
    got[0]["visibility"] += 1  # a sample's labels are its own, not the cache's
    assert torch.equal(ds[keys[0]]["visibility"], want[0]["visibility"])


def test_a_loader_without_workers_gives_the_workers_samples_nchw(real_tiny, tmp_path):
    """data.num_workers 0 builds the samples in the training process: the same tensors as a worker's,
    and the images NCHW (kornia's colour jitter returns them NHWC, and an NHWC batch ran the trunk
    NHWC: another rounding, a run that differed from the same run with a worker from step 1)."""
    from torch.utils.data import DataLoader

    from model.config import load_config
    from model.data import BevDataset

    cfg = load_config(write_config(tmp_path / "c.yaml", real_tiny, augment={"enabled": True}, data={"grid": label_grid(real_tiny)}))
    ds = BevDataset(real_tiny, "train", cfg, train=True)
    keys = [[(2, 0), (2, 1)]]
    here, worker = (next(iter(DataLoader(ds, batch_sampler=keys, num_workers=n))) for n in (0, 1))
    assert here.keys() == worker.keys()
    for k, v in worker.items():
        assert torch.equal(here[k], v), k
    assert here["images"].is_contiguous() and worker["images"].is_contiguous()
    assert ds[(2, 0)]["images"].is_contiguous()


def test_a_mirrored_sample_is_the_sample_flipped_with_its_geometry_and_labels(real_tiny, tmp_path):
    """augment.mirror: a mirrored sample is the same epoch's unmirrored sample (same view transforms
    and colour draws) with every image, camera-view target and label flipped along y and the lift
    geometry mirrored (model.frustum.mirrored_cells); samples it leaves unmirrored are unchanged."""
    from model.config import load_config
    from model.data import BevDataset
    from model.frustum import mirrored_cells

    def dataset(p):
        cfg = load_config(write_config(tmp_path / f"c{p}.yaml", real_tiny, augment={"enabled": True, "mirror": p},
                                       loss={"depth_weight": 1.0, "camera_seg_weight": 0.5}, data={"grid": label_grid(real_tiny)}))
        return BevDataset(real_tiny, "train", cfg, train=True)

    plain, always, half = dataset(0.0), dataset(1.0), dataset(0.5)
    grid = plain.grid
    flipped = 0
    for key in [(2, i) for i in range(8)]:
        a, m, h = plain[key], always[key], half[key]
        assert (m["images"] - a["images"].flip(-1)).abs().max() < 1e-6  # the jitter's float steps, in another order
        for k in ("semantic", "visibility", "depth_target", "camera_semantic"):
            assert torch.equal(m[k], a[k].flip(-1)), k
        assert torch.equal(m["point_cell"], torch.from_numpy(mirrored_cells(a["point_cell"].numpy(), grid)))
        assert not torch.equal(m["semantic"], a["semantic"])  # these frames are not symmetric
        same = all(torch.equal(h[k], a[k]) for k in a if torch.is_tensor(a[k]))
        assert same or torch.equal(h["point_cell"], m["point_cell"])
        flipped += not same
    assert 0 < flipped < 8


def test_a_turned_sample_keeps_its_images_and_turns_its_geometry_with_its_labels(real_tiny, tmp_path):
    """augment.bev_rotation_deg: a turned sample has the same epoch's unturned images and camera-view
    targets (the yaw is drawn last), and its lift and labels turned together: a lifted point finds
    in the turned labels the class it found before the turn (up to nearest-cell resampling);
    cells turned in from outside the grid have no label and are marked unknown (`bev_known`)."""
    from model.config import load_config
    from model.data import BevDataset

    def dataset(deg):
        cfg = load_config(write_config(tmp_path / f"c{deg}.yaml", real_tiny, augment={"enabled": True, "bev_rotation_deg": deg},
                                       loss={"depth_weight": 1.0, "camera_seg_weight": 0.5}, data={"grid": label_grid(real_tiny)}))
        return BevDataset(real_tiny, "train", cfg, train=True)

    plain, turned = dataset(0.0), dataset(40.0)
    for key in [(3, i) for i in range(4)]:
        a, t = plain[key], turned[key]
        assert "bev_known" not in a
        for k in ("images", "depth_target", "camera_semantic"):
            assert torch.equal(t[k], a[k]), k
        known = t["bev_known"].bool()
        assert 0.6 < known.float().mean() < 1.0  # the corners are turned in from outside
        assert (t["semantic"][~known] == 0).all() and (t["visibility"][~known] == 0).all()
        pa, pt = a["point_cell"], t["point_cell"]
        both = (pa >= 0) & (pt >= 0)
        cls_before, cls_after = a["semantic"].reshape(-1)[pa[both]], t["semantic"].reshape(-1)[pt[both]]
        labelled = (cls_before > 0) & (cls_after > 0)
        assert labelled.sum() > 1000
        assert (cls_before[labelled] == cls_after[labelled]).float().mean() > 0.9
        assert not torch.equal(t["semantic"], a["semantic"])


def test_images_finished_on_the_device_are_the_workers_images(real_tiny, tmp_path):
    """device_images (a GPU run): samples leave the loader as uint8 with their jitter's draws, and
    `finish` on the batch gives the images the workers would have made (same draws, same steps)."""
    from torch.utils.data import default_collate

    from model.config import load_config
    from model.data import BevDataset

    cfg = load_config(write_config(tmp_path / "c.yaml", real_tiny, augment={"enabled": True}, data={"grid": label_grid(real_tiny)}))
    ref, dev = BevDataset(real_tiny, "train", cfg, train=True), BevDataset(real_tiny, "train", cfg, train=True, device_images=True)
    keys = [(2, 0), (2, 1), (5, 1)]
    raw = default_collate([dev[k] for k in keys])
    assert raw["images"].dtype == torch.uint8 and raw["jitter_order"].shape == (3, 4)
    done, want = dev.finish(raw), default_collate([ref[k] for k in keys])
    assert "jitter_factors" not in done and done.keys() == want.keys()
    assert (done["images"] - want["images"]).abs().max() < 1e-6
    assert torch.equal(done["point_cell"], want["point_cell"]) and torch.equal(done["semantic"], want["semantic"])
    plain = BevDataset(real_tiny, "train", cfg, train=False, device_images=True)
    assert torch.equal(plain.finish(default_collate([plain[0]]))["images"][0], BevDataset(real_tiny, "train", cfg)[0]["images"])


def test_sigterm_to_the_process_group_stops_a_run_with_loader_workers_gracefully(real_tiny, tmp_path):
    """`timeout`, a scheduler or Ctrl-C signal the whole process group: the loader workers leave the
    signal to train.py (common.lifetime.LoaderWorker), which finishes its step, saves latest.pt
    and exits 130, rather than dying of "DataLoader worker killed by signal: Terminated"."""
    cfg = write_config(tmp_path / "c.yaml", real_tiny, train={"max_steps": 100000, "epochs": 100000, "batch_size": 4,
                                                              "checkpoint_every": 1},
                       data={"grid": label_grid(real_tiny), "num_workers": 2})
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "train.py", "--config", str(cfg), "--out", str(tmp_path / "run"), "--quiet"],
                            cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True, start_new_session=True)
    latest = tmp_path / "run" / "latest.pt"
    t0 = time.time()
    while not latest.exists() and proc.poll() is None and time.time() - t0 < 240:
        time.sleep(0.05)
    time.sleep(0.5)  # a few steps on, workers busy building the next batches
    os.killpg(proc.pid, signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted;" in err and "killed by signal" not in err
    assert torch.load(latest, weights_only=False)["step"] > 0


def test_only_the_intrinsics_pooling_gets_the_samples_intrinsics_descriptors(real_tiny, tmp_path):
    """An augmented sample carries its cameras' intrinsics descriptors only where the pooling reads
    them (intrinsics_embedding; computing them for every pooling was a tenth of a sample's loading
    time): sum pooling's output is the same without them, the embedding's are the augmented cameras'."""
    from model import build_model
    from model.config import load_config
    from model.data import BevDataset

    def dataset(pooling):
        cfg = load_config(write_config(tmp_path / f"{pooling}.yaml", real_tiny, augment={"enabled": True},
                                       model={"pooling": pooling}, data={"grid": label_grid(real_tiny)}))
        return cfg, BevDataset(real_tiny, "train", cfg, train=True)

    cfg, plain = dataset("sum")
    _, embedded = dataset("intrinsics_embedding")
    s, e = plain[(2, 0)], embedded[(2, 0)]
    assert "intrinsics" not in s and torch.equal(s["point_cell"], e["point_cell"])
    assert e["intrinsics"].shape == embedded.frustum.nominal[1].shape
    assert not torch.equal(e["intrinsics"], embedded.frustum.nominal[1])  # the augmented cameras' own
    torch.manual_seed(0)
    model = build_model(cfg, plain.index.rig).eval()
    with torch.no_grad():
        without = model(s["images"][None], s["point_cell"][None])["semantic"]
        given = model(s["images"][None], s["point_cell"][None], e["intrinsics"][None])["semantic"]
    assert torch.equal(without, given)


FAKE_CLOCK = """import sys, model.minutes as m, model.training as tr
ticks = iter([0.0, 0.0, 10.0])  # train()'s start, this process's step 5, the decision step (15): 1 s a step
def clock():
    return next(ticks)
m.clock = tr.clock = clock
import train
sys.exit(train.main(sys.argv[1:]))
"""


def test_a_minutes_budget_decides_the_epochs_at_the_warm_ups_end_and_trains_as_a_run_given_them(real_tiny, tmp_path):
    """train.minutes: steps 5-15 timed (here a clock saying 1 s a step and 10 s spent), the run
    decides at the warm-up's end the whole epochs that fit (30 s: 35 steps -> 11 epochs of 3 steps,
    under train.epochs 12) and trains bit for bit as a run given train.epochs 11; the decision is in
    the checkpoints, a resume keeps it whatever train.minutes says now, and train.minutes 0 hands the
    run back to train.epochs."""
    # 14 frames, batch 4: 3 steps per epoch
    base = dict(batch_size=4, lr_schedule="cosine", warmup_steps=15, checkpoint_every=1000)
    budget = write_config(tmp_path / "m.yaml", real_tiny, train={**base, "epochs": 12, "minutes": 0.5}, data={"grid": label_grid(real_tiny)})
    given = write_config(tmp_path / "e.yaml", real_tiny, train={**base, "epochs": 11}, data={"grid": label_grid(real_tiny)})
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-c", FAKE_CLOCK, "--config", str(budget), "--out", str(tmp_path / "m")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "train.minutes 0.5: 11 epochs (33 steps), from 1.000 s a step over steps 5-15" in r.stderr
    run_train(given, tmp_path / "e")
    a, pa = params(tmp_path / "m" / "latest.pt")
    b, pb = params(tmp_path / "e" / "latest.pt")
    assert a["step"] == b["step"] == 33
    assert a["minutes"] == {"minutes": 0.5, "epochs": 11, "s_per_step": 1.0, "timed": [5, 15], "spent_s": 10.0}
    assert a["config"]["train"]["epochs"] == 11 and b["minutes"] is None
    assert all(torch.equal(pa[k], pb[k]) for k in pa)

    run_train(budget, tmp_path / "m", "--set", "train.minutes=100")  # resumed: the recorded 11 epochs stand
    assert params(tmp_path / "m" / "latest.pt")[0]["step"] == 33
    run_train(budget, tmp_path / "m", "--set", "train.minutes=0")  # no budget: train.epochs (12) again
    assert params(tmp_path / "m" / "latest.pt")[0]["step"] == 36


def test_the_epochs_that_fit_the_minutes():
    from model.minutes import decision_step, epochs_for_minutes

    # 40 min, 60 s spent at step 50, 0.8 s a step, 80 steps an epoch: (50 + 2340 / 0.8) // 80 = 37
    assert epochs_for_minutes(40, 60, 0.8, 50, 80, cap=50) == 37
    assert epochs_for_minutes(40, 60, 0.8, 50, 80, cap=30) == 30  # train.epochs caps it
    assert epochs_for_minutes(1, 120, 0.8, 50, 80, cap=50) == 1  # spent already: the epoch it is in
    assert epochs_for_minutes(1, 120, 0.8, 170, 80, cap=50) == 3
    assert decision_step({"lr_schedule": "cosine", "warmup_steps": 30}) == 30
    assert decision_step({"lr_schedule": "cosine", "warmup_steps": 500}) == 50
    assert decision_step({"lr_schedule": "constant", "warmup_steps": 0}) == 50


def test_a_minutes_budget_needs_a_warm_up_to_time_under_the_cosine_schedule():
    from common.errors import ConfigError
    from model.config import load_config

    with pytest.raises(ConfigError, match=r"train.minutes: needs train.warmup_steps >= 15 with the cosine schedule"):
        load_config(ROOT / "configs/train/cpu_default.yaml", {"train": {"minutes": 30, "lr_schedule": "cosine", "warmup_steps": 10}})
    load_config(ROOT / "configs/train/cpu_default.yaml", {"train": {"minutes": 30}})  # constant schedule: decided at step 50
