"""Benchmarks of the model at HEAD: `run() -> {figure: value}`, goals in GOALS; with a baseline
(`--baseline REV`, default BASELINE; `make bench` passes it through bench.run), its training and
inference figures measured alongside in the same run (`*_baseline`, `*_ratio`: HEAD / REV).

- splat: our precomputed-index splat against LSS's cumsum-trick voxel pooling (written here from
  the LSS paper's description) and against a naive scatter, forward + backward, on the same inputs
  (cpu_default sizes, the default rig's real lift geometry); equal results checked.
- training samples/s and inference ms per four-camera frame for cpu_default, and peak memory
  (each measured in a fresh process, on a constructed data set of 480x302 images), for the
  from-scratch trunk and the pretrained EfficientNet-Lite0 (`_efficientnet_lite0` figures); the same
  under bf16 autocast (`model.precision: bf16`, `_bf16` figures, and `_bf16_vs_fp32` ratios against
  this checkout's fp32, measured alternating).
- loading ms per augmented training sample of the default config (256x160 input) and the paper's
  (480x302), one thread: what each loader worker spends per sample (the paper's configuration on a
  GPU waits for it: docs/benchmarks.md, "The paper configuration on one GPU").
- cylindrical rectification (the paper's baseline): ms per four-camera frame, tables per rig.
- the roofline: GFLOP of a training step for each trunk (`step_gflop`), this machine's
  matrix-multiply rate in fp32 and bf16 (`matmul_gflops`, the roof a convolution-bound step cannot
  pass), and the share of that roof the measured training step reaches (`train_share_of_matmul_peak`).

    PYTHONPATH=. python -m bench.model [--baseline REV|none] [--rounds N]
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from common.resources import CODE_DIR, checkout

ROOT = CODE_DIR  # the checkout (common.resources)
GOALS = {
    "splat_speedup_vs_cumsum": ">= 5",
    "train_samples_per_s": ">= 4",
    "infer_ms_per_frame": "<= 60",
}
BASELINE = "4017132"  # the default revision HEAD is compared with (any commit: --baseline REV)


# ----------------------------------------------------------------- LSS's cumsum trick


class QuickCumsum(torch.autograd.Function):
    """LSS voxel pooling: points sorted by cell; a cumulative sum over all of them, then the
    difference of the cumulative sums at the last point of each cell is that cell's sum."""

    @staticmethod
    def forward(ctx, x, ranks):
        x = x.cumsum(0)
        kept = torch.ones(x.shape[0], device=x.device, dtype=torch.bool)
        kept[:-1] = ranks[1:] != ranks[:-1]
        x, ranks_out = x[kept], ranks[kept]
        x = torch.cat((x[:1], x[1:] - x[:-1]))
        back = torch.cumsum(kept, 0)
        back[kept] -= 1
        ctx.save_for_backward(back)
        return x, ranks_out

    @staticmethod
    def backward(ctx, grad_x, grad_ranks):
        (back,) = ctx.saved_tensors
        return grad_x[back], None


def _frustum(depth, context, point_cell, cells, sum_cameras):
    b, n, d, h, w = point_cell.shape
    c = context.shape[2]
    x = depth.unsqueeze(-1) * context.permute(0, 1, 3, 4, 2).unsqueeze(2)  # (B, N, D, H, W, C)
    pc = point_cell.reshape(-1)
    kept = pc >= 0
    bn = torch.arange(b * n).repeat_interleave(d * h * w)[kept]
    grid = (bn // n if sum_cameras else bn) * cells + pc[kept]
    rows = b * (1 if sum_cameras else n) * cells
    return x.reshape(-1, c)[kept], grid, rows


def cumsum_pool(depth, context, point_cell, cells, sum_cameras=True):
    """LSS: build the full (B, N, D, H, W, C) frustum features, keep the points inside the grid,
    rank them by (batch, cell) (LSS pools all cameras of a sample into one grid), sort, cumsum
    trick, write the cell sums into the grid."""
    x, ranks, rows = _frustum(depth, context, point_cell, cells, sum_cameras)
    order = ranks.argsort()
    x, ranks = x[order], ranks[order]
    x, ranks = QuickCumsum.apply(x, ranks)
    out = x.new_zeros(rows, x.shape[1])
    out[ranks] = x
    return out


def naive_pool(depth, context, point_cell, cells, sum_cameras=True):
    """Naive scatter: the full frustum features, masked, index_add_ into the grid (autograd)."""
    x, grid, rows = _frustum(depth, context, point_cell, cells, sum_cameras)
    return x.new_zeros(rows, x.shape[1]).index_add(0, grid, x)


def _seconds(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def _time(fn, repeat=5):
    fn()  # warm-up
    ts = [_seconds(fn) for _ in range(repeat)]
    return sorted(ts)[len(ts) // 2]


def _time_interleaved(fns: dict, repeat=7, clock=time.process_time) -> dict:
    """Median seconds of each function, run round-robin so that load from other processes on a
    shared machine hits every contender alike; timed by this process's CPU time (all threads),
    which other processes' load disturbs far less than wall time."""
    for f in fns.values():
        f()
    ts = {k: [] for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            t = clock()
            f()
            ts[k].append(clock() - t)
    return {k: sorted(v)[len(v) // 2] for k, v in ts.items()}


def bench_splat(batch=4, sum_cameras=True) -> dict:
    """sum_cameras=True pools the cameras of a sample into one grid, as LSS's voxel pooling does;
    False keeps one grid per camera (what the learnable poolings need)."""
    from geometry.rig import load_rig
    from model import build_model
    from model.config import load_config
    from model.splat import splat, splat_index

    cfg = load_config(ROOT / "configs/train/cpu_default.yaml")
    model = build_model(cfg, load_rig(ROOT / "configs/rigs/default.yaml"))
    pc = model.nominal_point_cell[None].expand(batch, -1, -1, -1, -1).contiguous()
    b, n, d, h, w = pc.shape
    c = cfg["model"]["context_channels"]
    cells = model.grid.rows * model.grid.cols
    g = torch.Generator().manual_seed(0)
    depth0 = torch.rand(b, n, d, h, w, generator=g).softmax(2)
    ctx0 = torch.randn(b, n, c, h, w, generator=g)
    rows = b * (1 if sum_cameras else n) * cells
    grad = torch.randn(rows, c, generator=g)
    index = splat_index(pc, cells, sum_cameras)  # precomputed once per rig (per batch when augmenting)

    def fwd_bwd(fn):
        dd, cc = depth0.clone().requires_grad_(), ctx0.clone().requires_grad_()
        out = fn(dd, cc).reshape(rows, c)
        out.backward(grad)
        return out.detach(), dd.grad, cc.grad

    ours = lambda dd, cc: splat(dd, cc, index)
    ours_with_index = lambda dd, cc: splat(dd, cc, splat_index(pc, cells, sum_cameras))
    cums = lambda dd, cc: cumsum_pool(dd, cc, pc, cells, sum_cameras)
    naive = lambda dd, cc: naive_pool(dd, cc, pc, cells, sum_cameras)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one thread: no OpenMP spin-waiting to distort times on a shared machine
    ref = fwd_bwd(ours)
    diffs = {}
    for name, fn in (("cumsum", cums), ("naive", naive)):
        other = fwd_bwd(fn)
        diffs[name] = max(float((a - r).abs().max()) for a, r in zip(other, ref))
    t = _time_interleaved({"ours": lambda: fwd_bwd(ours), "ours_index": lambda: fwd_bwd(ours_with_index),
                           "cumsum": lambda: fwd_bwd(cums), "naive": lambda: fwd_bwd(naive)})
    torch.set_num_threads(threads)
    p = "splat" if sum_cameras else "splat_per_camera"
    return {
        f"{p}_points": int((pc >= 0).sum()),
        f"{p}_ms_ours": 1000 * t["ours"],
        f"{p}_ms_ours_incl_index": 1000 * t["ours_index"],
        f"{p}_ms_cumsum": 1000 * t["cumsum"],
        f"{p}_ms_naive": 1000 * t["naive"],
        f"{p}_speedup_vs_cumsum": t["cumsum"] / t["ours"],
        f"{p}_speedup_vs_naive": t["naive"] / t["ours"],
        f"{p}_max_abs_diff_cumsum": diffs["cumsum"],
        f"{p}_max_abs_diff_naive": diffs["naive"],
    }


# ----------------------------------------------------------------- training / inference (subprocess)


def _peak_rss_mb() -> float:
    """This process's peak resident memory (VmHWM; unlike ru_maxrss it does not inherit the
    parent's peak across fork + exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def training_setup(cfg: dict):
    """cpu_default's training pieces as model.training sets them up (threads, memory format,
    optimiser, loader), seeded: -> (model, opt, alpha, loader) over the config's training split."""
    from torch.utils.data import DataLoader

    from dataset_tools.format.reader import DatasetIndex
    from model import build_model
    from model.cpu import tune_cpu
    from model.data import BevDataset
    from model.losses import class_weights
    from model.training import EpochBatches, make_optimizer

    t = cfg["train"]
    idx = DatasetIndex(cfg["data"]["root"])
    ds = BevDataset(idx, "train", cfg, train=True)
    torch.manual_seed(0)
    model = build_model(cfg, idx.rig)
    tune_cpu(cfg, torch.device("cpu"), model)
    opt = make_optimizer(cfg, model)
    alpha = class_weights(cfg["loss"]["class_weights"])
    loader = DataLoader(ds, batch_sampler=EpochBatches(len(ds), t["batch_size"], 0, 0, 0, 1),
                        num_workers=cfg["data"]["num_workers"], generator=torch.Generator())
    return model, opt, alpha, loader


def _sfx(trunk: str, precision: str) -> str:
    return ("" if trunk == "scratch" else f"_{trunk}") + ("" if precision == "fp32" else f"_{precision}")


def _child_train(data_root: str, steps: int, trunk: str = "scratch", precision: str = "fp32") -> dict:
    """Training samples/s of cpu_default as model.training sets it up (threads, memory format,
    optimiser, loader), on the data set at data_root; the first step (loader start) not counted."""
    from model.config import load_config
    from model.losses import total_loss

    over = {"data": {"root": data_root}, "model": {"trunk": trunk, "precision": precision}}
    cfg = load_config(ROOT / "configs/train/cpu_default.yaml", over)
    t = cfg["train"]
    model, opt, alpha, loader = training_setup(cfg)
    it = iter(loader)
    times = []
    for k in range(steps + 1):
        t0 = time.perf_counter()
        batch = next(it)
        out = model(batch["images"], batch["point_cell"], batch.get("intrinsics"))
        loss, _ = total_loss(out, batch, alpha)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), t["grad_clip"])
        opt.step()
        if k:  # the first step includes the loader's start
            times.append(time.perf_counter() - t0)
    sfx = _sfx(trunk, precision)
    return {f"train_samples_per_s{sfx}": t["batch_size"] * len(times) / sum(times),
            f"train_peak_rss_mb{sfx}": _peak_rss_mb()}


def _toy_camera_targets(ds) -> None:
    """camera_targets.npy (random ray distances and classes) in each frame of `ds` that has none:
    the toy data set has no EXR passes to derive them from."""
    from dataset_tools.format.camera_targets import targets_path, write_camera_targets

    rng = np.random.default_rng(0)
    cam = ds.index.rig[ds.names[0]].camera
    fields = [(f"{k}_{n}", t) for n in ds.names for k, t in (("distance", np.uint16), ("semantic", np.uint8))]
    for ref in ds.refs:
        if targets_path(ref.dir).is_file():
            continue
        table = np.zeros((cam.height, cam.width), np.dtype(fields))
        for n in ds.names:
            table[f"distance_{n}"] = rng.integers(100, 4000, table.shape)
            table[f"semantic_{n}"] = rng.integers(0, 5, table.shape)
        write_camera_targets(ref.dir, table)


def _child_load(data_root: str, samples: int, config: str) -> dict:
    """Milliseconds to load one augmented training sample of `config` (a loader worker's work:
    read, warp, colour jitter, lift geometry; one torch thread), median over `samples`."""
    from model.config import load_config
    from model.data import BevDataset

    torch.set_num_threads(1)
    cfg = load_config(ROOT / f"configs/train/{config}.yaml", {"data": {"root": data_root}})
    ds = BevDataset(data_root, "train", cfg, train=True)
    if ds.camera_targets:  # a depth loss: random camera targets where the toy frames have none
        _toy_camera_targets(ds)
    ds[0]  # warm: caches, lazy imports
    times = []
    for i in range(samples):
        t0 = time.perf_counter()
        ds[i % len(ds)]
        times.append(time.perf_counter() - t0)
    return {f"load_ms_per_sample_{config}": 1000 * statistics.median(times)}


def _default_model(trunk: str, precision: str, frames: int | None = None):
    """cpu_default's model (seeded) on the default rig and a random input of `frames` frames of its
    cameras (default: the config's training batch): -> (config, model, input)."""
    from geometry.rig import load_rig
    from model import build_model
    from model.config import load_config

    cfg = load_config(ROOT / "configs/train/cpu_default.yaml", {"model": {"trunk": trunk, "precision": precision}})
    rig = load_rig(ROOT / "configs/rigs/default.yaml")
    torch.manual_seed(0)
    model = build_model(cfg, rig)
    w, h = cfg["data"]["input_size"]
    return cfg, model, torch.rand(frames or cfg["train"]["batch_size"], len(rig.names), 3, h, w)


def _child_infer(repeat: int, trunk: str = "scratch", precision: str = "fp32") -> dict:
    """Inference ms per four-camera frame of cpu_default, set up as a run of the config is
    (model.cpu: threads, memory format)."""
    from model.cpu import tune_cpu

    cfg, model, x = _default_model(trunk, precision, 1)
    model.eval()
    tune_cpu(cfg, torch.device("cpu"), model)
    with torch.inference_mode():
        ms = 1000 * _time(lambda: model(x), repeat)
    sfx = _sfx(trunk, precision)
    return {f"infer_ms_per_frame{sfx}": ms, f"infer_peak_rss_mb{sfx}": _peak_rss_mb()}


def step_gflop(trunk: str = "scratch") -> dict:
    """GFLOP of one cpu_default training step (its batch of four-camera frames): torch's flop counter
    over the forward pass, times 3 (the backward computes, per forward product, one for the input's
    gradient and one for the weights'). Counted from the forward because the flop counter overcounts
    the backward of grouped (depthwise) convolutions; tests/test_bench_roofline.py checks the factor
    on the scratch trunk, which has none."""
    from torch.utils.flop_counter import FlopCounterMode

    _, model, x = _default_model(trunk, "fp32")
    with torch.no_grad(), FlopCounterMode(display=False) as fc:
        model(x)
    return {f"train_gflop_per_step{_sfx(trunk, 'fp32')}": 3 * fc.get_total_flops() / 1e9}


def matmul_gflops(n: int = 2048, repeat: int = 8) -> dict:
    """The best rate of an n x n matrix product with model.cpu's thread count, in fp32 and bf16:
    what oneDNN's convolutions (matrix products underneath) can reach on this machine at most."""
    from model.cpu import compute_threads

    torch.set_num_threads(compute_threads())
    out = {}
    for name, dtype in (("fp32", torch.float32), ("bf16", torch.bfloat16)):
        a, b = torch.rand(n, n, dtype=dtype), torch.rand(n, n, dtype=dtype)
        a @ b  # warm-up
        best = min(_seconds(lambda: a @ b) for _ in range(repeat))
        out[f"matmul_gflops_{name}"] = 2 * n**3 / best / 1e9
    return out


def roofline(res: dict, trunks) -> dict:
    """The training figures in `res` as a share of this machine's matrix-multiply rate: the step's
    GFLOP times steps/s over the rate (fp32 figures against fp32's, bf16 against bf16's)."""
    from model.config import load_config

    batch = load_config(ROOT / "configs/train/cpu_default.yaml")["train"]["batch_size"]
    out = _in_child("matmul_gflops")
    for trunk in trunks:
        out.update(_in_child("step_gflop", trunk))
        gflop = out[f"train_gflop_per_step{_sfx(trunk, 'fp32')}"]
        for precision in ("fp32", "bf16"):
            sps = res.get(f"train_samples_per_s{_sfx(trunk, precision)}")
            if sps:
                out[f"train_share_of_matmul_peak{_sfx(trunk, precision)}"] = sps / batch * gflop / out[f"matmul_gflops_{precision}"]
    return out


def bench_rectify(repeat: int = 10) -> dict:
    """Cylindrical rectification (the paper's baseline) of a four-camera 480x302 frame: the remap
    tables' one-off cost per rig and the cost per frame."""
    import numpy as np

    from geometry.rectify import Rectifier
    from geometry.rig import load_rig

    rig = load_rig(ROOT / "configs/rigs/default.yaml")
    t0 = time.perf_counter()
    rect = Rectifier(rig)
    setup = time.perf_counter() - t0
    imgs = {rc.name: np.random.default_rng(0).integers(0, 255, (rc.camera.height, rc.camera.width, 3), dtype=np.uint8) for rc in rig}
    ms = 1000 * _time(lambda: [rect(n, im) for n, im in imgs.items()], repeat)
    return {"rectify_ms_per_frame": ms, "rectify_tables_s_per_rig": setup}


def _in_child(fn: str, *args, root: Path = ROOT, env: dict | None = None) -> dict:
    """bench.model.<fn>(*args) in a fresh process, with the code at `root` (this checkout, or a
    baseline commit's copy)."""
    code = f"import json, bench.model as m; print('@@' + json.dumps(m.{fn}(*{args!r})))"
    r = subprocess.run([sys.executable, "-c", code], cwd=root, env=dict(os.environ, PYTHONPATH=str(root), **(env or {})),
                       capture_output=True, text=True, timeout=1200)
    if r.returncode:
        raise RuntimeError(f"bench.model.{fn} failed{' at ' + str(root) if root != ROOT else ''}: "
                           f"{r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    return json.loads([ln for ln in r.stdout.splitlines() if ln.startswith("@@")][-1][2:])


def versus(children: list[tuple], baseline_root: Path, rounds: int, env: dict | None = None) -> dict:
    """Each child (fn, *args) run `rounds` times with this checkout's code and the baseline's,
    alternating (ABBA...), so load on a shared machine hits both alike; -> this checkout's and the
    baseline's median figures and the median of the per-pair ratios (ours / baseline). env: extra
    environment of both (OMP_NUM_THREADS=1 compares the code at equal threads)."""
    out = {}
    for fn, *args in children:
        ours, base = [], []
        for r in range(rounds):
            order = [(ours, ROOT), (base, baseline_root)]
            for dest, root in (order if r % 2 == 0 else order[::-1]):
                dest.append(_in_child(fn, *args, root=root, env=env))
        for key in ours[0]:
            if "rss" in key:
                out[key] = statistics.median(o[key] for o in ours)
                continue
            out[key] = statistics.median(o[key] for o in ours)
            out[f"{key}_baseline"] = statistics.median(b[key] for b in base)
            out[f"{key}_ratio"] = statistics.median(o[key] / b[key] for o, b in zip(ours, base))
    return out


def precision_versus(children: list[tuple], rounds: int, precision: str = "bf16") -> dict:
    """Each child (fn, *args) of this checkout in fp32 and in `precision`, alternating; -> the
    `precision` figures and the median per-pair ratio against fp32 (`*_bf16_vs_fp32`)."""
    out = {}
    for fn, *args in children:
        full, half = [], []
        for r in range(rounds):
            order = [(full, "fp32"), (half, precision)]
            for dest, prec in (order if r % 2 == 0 else order[::-1]):
                dest.append(_in_child(fn, *args, prec))
        for key in full[0]:
            if "rss" in key:
                continue
            hkey = f"{key}_{precision}"  # _sfx: the trunk's suffix, then the precision's
            out[hkey] = statistics.median(h[hkey] for h in half)
            out[f"{hkey}_vs_fp32"] = statistics.median(h[hkey] / f[key] for f, h in zip(full, half))
    return out


def run(train_steps: int = 12, infer_repeat: int = 20, baseline: str | None = None, rounds: int = 2) -> dict:
    """baseline: a commit of this repository whose training and inference figures are measured in
    the same run, alternating with this checkout's (figures *_baseline and *_ratio)."""
    from testing.toy_data import write_toy_dataset

    res = {"threads": torch.get_num_threads(), "load_average_1min_at_start": os.getloadavg()[0]}
    res.update(bench_splat(sum_cameras=True))
    res.update(bench_splat(sum_cameras=False))
    trunks = ("scratch", "efficientnet_lite0")
    with tempfile.TemporaryDirectory() as tmp:
        root = write_toy_dataset(Path(tmp) / "toy", frames=4 * (train_steps + 1), splits=("train",))
        children = [("_child_train", str(root), train_steps, t) for t in trunks] + [("_child_infer", infer_repeat, t) for t in trunks]
        if baseline:
            res["baseline_commit"] = baseline
            res.update(versus(children, checkout(baseline, Path(tmp) / "baseline"), rounds))
        else:
            for fn, *args in children:
                res.update(_in_child(fn, *args))
        res.update(precision_versus(children, rounds))
        for config in ("cpu_medium", "paper"):  # HEAD alone: the baseline has no such child
            res.update(_in_child("_child_load", str(root), 24, config))
    res.update(roofline(res, trunks))
    res.update(bench_rectify())
    res["load_average_1min_at_end"] = os.getloadavg()[0]
    res["goals"] = dict(GOALS)
    return res


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline", default=BASELINE, help=f"a commit to measure alongside (default {BASELINE}; 'none': HEAD alone)")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    out = run(baseline=None if a.baseline.lower() == "none" else a.baseline, rounds=a.rounds)
    for k, v in out.items():
        print(f"{k:32s} {v:.4g}" if isinstance(v, float) else f"{k:32s} {v}")
