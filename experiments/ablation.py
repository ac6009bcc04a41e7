"""The paper's Tables I and II on our data, as one resumable command.

    python -m experiments.ablation --budget-minutes 9 --seeds 1 [--scale cpu|gpu] [--data DIR] [--out DIR]
    python -m experiments.ablation --steps 400 --seeds 3 ...        # equal step budgets instead

Every row is the base config (`--scale cpu`: configs/train/cpu_default.yaml; `gpu`:
configs/train/paper.yaml) with the paper's best settings (intrinsics-embedding pooling, uniform
class weights, occlusion loss, the pretrained EfficientNet-Lite0 trunk) and one change. Each row and
seed trains with `model.training` (what train.py runs) for the same wall-clock budget (or the same
number of steps), from the same seed, then is scored with `model.evaluation` (eval.py's protocol) on
the easy, medium and hard splits (and `heldout`, sampled scenes from seeds training never used,
where the data set has one).

Resumable: `<out>/<row>/seed<k>/` holds the run; `result.json` there marks it finished (never
retrained; scored on an evaluation split the data set has gained since); a killed row resumes from
its latest.pt and its recorded training time (`budget.json`).
Writes `<out>/tables.md` and `<out>/tables.json` with the paper's numbers beside ours (mean and
standard deviation over seeds when there are several).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import output_dir, read_json, write_json_atomic, write_text_atomic
from common.schema import deep_merge
from model.run_dir import RunDir

ROOT = Path(__file__).resolve().parents[1]
SCALES = {"cpu": "configs/train/cpu_default.yaml", "gpu": "configs/train/paper.yaml"}
BASE = {"model": {"pooling": "intrinsics_embedding", "trunk": "efficientnet_lite0"},
        "loss": {"class_weights": "uniform", "occlusion_weight": 1.0}}
# row name -> (description, config changes to BASE)
ROWS = {
    "ours": ("raw fisheye, fisheye cameras", {}),
    "rectified": ("cylindrically rectified images, cylindrical cameras", {"data": {"rectify": "cylindrical"}}),
    "ours_scratch_trunk": ("raw fisheye, from-scratch trunk", {"model": {"trunk": "scratch"}}),
    "weights_13_3_1_1": ("class weights 13-3-1-1, occlusion loss", {"loss": {"class_weights": "paper"}}),
    "weights_13_3_1_1_no_occlusion": ("class weights 13-3-1-1, no occlusion loss",
                                      {"loss": {"class_weights": "paper", "occlusion_weight": 0.0}}),
    "pool_sum": ("sum pooling", {"model": {"pooling": "sum"}}),
    "pool_max": ("max pooling", {"model": {"pooling": "max"}}),
    "pool_weighted_sum": ("weighted-sum pooling", {"model": {"pooling": "weighted_sum"}}),
    "pool_sensors_per_cell": ("sensors-per-cell pooling", {"model": {"pooling": "sensors_per_cell"}}),
}
COLUMNS = [("miou", "mIoU"), ("iou/occlusion", "Occlusion"), ("iou/vehicle", "Vehicles"),
           ("iou/lane_marking", "Markings"), ("iou/street", "Street"), ("iou/background", "Background")]
TABLES_MD, TABLES_JSON = "tables.md", "tables.json"  # in --out, beside the rows' run folders <row>/seed<k>/
EVAL_SPLITS = ("easy", "medium", "hard", "heldout")  # heldout: sampled scenes of unseen seeds, where the data set has them

# The paper's numbers (DaF-BEVSeg, Tables I and II), in COLUMNS order (None: not reported).
PAPER_TABLE_I = {
    ("rectified", "easy"): [0.659, None, 0.607, 0.379, 0.773, 0.875],
    ("rectified", "medium"): [0.540, None, 0.539, 0.214, 0.645, 0.763],
    ("rectified", "hard"): [0.314, None, 0.317, 0.114, 0.523, 0.303],
    ("ours", "easy"): [0.796, 0.815, 0.776, 0.517, 0.895, 0.978],
    ("ours", "medium"): [0.690, 0.682, 0.764, 0.364, 0.858, 0.782],
    ("ours", "hard"): [0.466, 0.666, 0.464, 0.176, 0.572, 0.449],
}
# (section, label, row, paper numbers on the medium split)
TABLE_II = [
    ("Class weights", "13-3-1-1", "weights_13_3_1_1", [0.658, 0.687, 0.716, 0.346, 0.803, 0.736]),
    ("Class weights", "1-1-1-1", "ours", [0.690, 0.682, 0.764, 0.364, 0.858, 0.782]),
    ("Loss for occluded areas (13-3-1-1)", "with", "weights_13_3_1_1", [0.658, 0.687, 0.716, 0.346, 0.803, 0.736]),
    ("Loss for occluded areas (13-3-1-1)", "without", "weights_13_3_1_1_no_occlusion", [0.631, 0.675, 0.724, 0.342, 0.752, 0.662]),
    ("BEV pooling", "Sum", "pool_sum", [0.666, 0.665, 0.719, 0.308, 0.862, 0.776]),
    ("BEV pooling", "Max", "pool_max", [0.656, 0.602, 0.748, 0.309, 0.857, 0.764]),
    ("BEV pooling", "Weighted sum", "pool_weighted_sum", [0.667, 0.607, 0.755, 0.325, 0.860, 0.769]),
    ("BEV pooling", "Sensors per cell", "pool_sensors_per_cell", [0.679, 0.644, 0.759, 0.363, 0.861, 0.774]),
    ("BEV pooling", "Intrinsics + embedding", "ours", [0.690, 0.682, 0.764, 0.364, 0.858, 0.782]),
]
TABLE_I = [("LSS, cylindrically rectified", "rectified"), ("LSS-fisheye (ours), raw fisheye", "ours"),
           ("LSS-fisheye, raw fisheye, from-scratch trunk", "ours_scratch_trunk")]


class AblationError(InputError):
    pass


def row_config(base_path: Path, row: str, seed: int, data: str | None, extra: dict | None = None) -> dict:
    from model.config import load_config

    over = deep_merge(deep_merge(BASE, ROWS[row][1]), {
        "data": {"val_split": ""},  # scored once at the end, by eval's protocol
        "train": {"seed": seed, "epochs": 10**6, "image_every": 0},
    })
    if data:
        over = deep_merge(over, {"data": {"root": data}})
    if extra:
        over = deep_merge(over, extra)
    return load_config(base_path, over)


def evaluate_row(run: RunDir, splits) -> dict:
    from model.evaluation import evaluate_splits, open_checkpoint

    model, cfg, _, index = open_checkpoint(run.latest)
    return evaluate_splits(model, cfg, index, splits, run.eval)


def _split_results(splits: dict) -> dict:
    return {s: {"overall": r["overall"], "frames": r["frames"], "inference_ms_per_frame": r["inference_ms_per_frame"]}
            for s, r in splits.items()}


def run_row(base_path, row, seed, out: Path, data, budget_s, steps, extra, quiet, eval_splits) -> dict:
    """Train and score one row and seed (`eval_splits`: those of EVAL_SPLITS the data set has)."""
    from model.training import train_with_budget

    run = RunDir(out / row / f"seed{seed}")
    done = run.result
    if done.is_file():
        result = read_json(done, AblationError)
        missing = [s for s in eval_splits if s not in result["splits"]]
        if missing and run.latest.is_file():
            result["splits"].update(_split_results(evaluate_row(run, missing)))  # a split added to the data set later: scored, not retrained
            write_json_atomic(done, result)
        return result
    run.root.mkdir(parents=True, exist_ok=True)
    cfg = row_config(base_path, row, seed, data, extra)
    t0 = time.perf_counter()
    state = train_with_budget(cfg, run.root, budget_s, steps, quiet)
    splits = evaluate_row(run, eval_splits)
    result = {"row": row, "seed": seed, "steps": state["step"], "train_seconds": state["seconds"],
              "eval_seconds": time.perf_counter() - t0 - state["seconds"],
              "splits": _split_results(splits)}
    write_json_atomic(done, result)
    return result


def rectification_report(cfg: dict, frames: int = 12) -> dict:
    """What the rectified baseline loses and costs on this data set: the share of each fisheye's
    valid pixels the cylinder drops, the share of seen BEV cells (p(o) >= 0.5) no rectified image
    covers (mean over up to `frames` evaluation frames), and the remap time per four-camera frame."""
    from dataset_tools import DatasetIndex, read_frame
    from geometry.rectify import lost_fisheye_pixels, lost_visible_cells
    from model.rectified import rectifier

    index = DatasetIndex(cfg["data"]["root"])
    rect = rectifier(index.rig, deep_merge(cfg, {"data": {"rectify": "cylindrical"}}))
    refs = [r for s in EVAL_SPLITS for r in index.frames(s)] or index.frames(cfg["data"]["train_split"])
    refs = refs[:: max(1, len(refs) // frames)][:frames]
    lost_cells, ms = [], []
    for ref in refs:
        f = read_frame(ref, cameras=index.rig.names)
        t0 = time.perf_counter()
        for n, img in f["images"].items():
            rect(n, img)
        ms.append(1000 * (time.perf_counter() - t0))
        lost_cells.append(lost_visible_cells(index.rig, rect.rig, index.grid, f["visibility"]))
    c = cfg["data"]["cylinder"]
    return {"hfov_deg": c["hfov_deg"], "vfov_deg": c["vfov_deg"],
            "size": [[rc.camera.width, rc.camera.height] for rc in rect.rig][0],
            "lost_fisheye_pixels": {rc.name: lost_fisheye_pixels(rc, rect.rig[rc.name].camera) for rc in index.rig},
            "lost_seen_cells": float(np.mean(lost_cells)) if lost_cells else None, "frames": len(refs),
            "rectify_ms_per_frame": float(np.median(ms)) if ms else None}


# ----------------------------------------------------------------- tables


def summarise(results: list[dict], split: str) -> dict:
    """Column key -> (mean, std, n) over seeds."""
    out = {}
    for key, _ in COLUMNS:
        vals = [r["splits"][split]["overall"].get(key) for r in results if split in r["splits"]]
        vals = [v for v in vals if v is not None and v == v]
        out[key] = (float(np.mean(vals)), float(np.std(vals, ddof=1)) if len(vals) > 1 else None, len(vals)) if vals else None
    return out


def _cell(s) -> str:
    if s is None:
        return "-"
    mean, std, _ = s
    return f"{mean:.3f}" if std is None else f"{mean:.3f} ± {std:.3f}"


def _paper(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def tables(results: dict[str, list[dict]], meta: dict) -> tuple[str, dict]:
    heads = [t for _, t in COLUMNS]
    lines = ["# Tables I and II on our data", "",
             f"Scale `{meta['scale']}`, data `{meta['data']}`, seeds {meta['seeds']}, "
             + (f"{meta['steps']} steps per row" if meta["steps"] else f"{meta['budget_minutes']:g} min of training per row")
             + ". Ours: mean ± standard deviation over seeds (one seed: no spread); paper: DaF-BEVSeg.", "",
             "## Table I: raw fisheye against cylindrical rectification", "",
             "| Method | Dataset | " + " | ".join(f"{h} (ours) | {h} (paper)" for h in heads) + " |",
             "|---|---|" + "---|---|" * len(heads)]
    js = {"meta": meta, "table_1": [], "table_2": [], "runs": results}
    for label, row in TABLE_I:
        if row not in results:
            continue
        for split in EVAL_SPLITS:
            if not any(split in r["splits"] for r in results[row]):
                continue
            s = summarise(results[row], split)
            paper = PAPER_TABLE_I.get((row, split), [None] * len(COLUMNS))
            lines.append(f"| {label} | {split} | " + " | ".join(f"{_cell(s[k])} | {_paper(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
            js["table_1"].append({"method": label, "row": row, "split": split, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    lines += ["", "## Table II: ablations on the medium split", "",
              "| Ablation | Setting | " + " | ".join(f"{h} (ours) | {h} (paper)" for h in heads) + " |",
              "|---|---|" + "---|---|" * len(heads)]
    for section, label, row, paper in TABLE_II:
        if row not in results:
            continue
        s = summarise(results[row], "medium")
        lines.append(f"| {section} | {label} | " + " | ".join(f"{_cell(s[k])} | {_paper(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
        js["table_2"].append({"section": section, "setting": label, "row": row, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    r = meta.get("rectification")
    if r:
        px = ", ".join(f"{n} {100 * v:.1f}%" for n, v in r["lost_fisheye_pixels"].items())
        lines += ["", "## What rectification loses and costs", "",
                  f"Cylinder {r['hfov_deg']:g} x {r['vfov_deg']:g} degrees, {r['size'][0]}x{r['size'][1]} px. "
                  f"Fisheye pixels (with a ray) outside the cylinder: {px}. Seen BEV cells (p(o) >= 0.5) that no "
                  f"rectified image covers: {100 * r['lost_seen_cells']:.2f}% (mean of {r['frames']} frames). "
                  f"Rectification: {r['rectify_ms_per_frame']:.1f} ms per four-camera frame."]
    lines += ["", "## Runs", "", "| Row | What | Seeds | Steps | Training s | Inference ms/frame (medium) |", "|---|---|---|---|---|---|"]
    for row, rs in results.items():
        inf = [r["splits"]["medium"]["inference_ms_per_frame"] for r in rs if "medium" in r["splits"]]
        steps = ", ".join(str(r["steps"]) for r in rs)
        secs = ", ".join(f"{r['train_seconds']:.0f}" for r in rs)
        lines.append(f"| {row} | {ROWS[row][0]} | {len(rs)} | {steps} | {secs} | " + (f"{np.mean(inf):.1f}" if inf else "-") + " |")
    return "\n".join(lines) + "\n", js


def main(argv=None) -> int:
    from tqdm import tqdm

    p = ArgumentParser(prog="experiments.ablation", description="Train and score every row of the paper's Tables I and II.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--budget-minutes", type=float, help="training wall-clock minutes per row and seed")
    g.add_argument("--steps", type=int, help="training steps per row and seed (instead of a time budget)")
    p.add_argument("--seeds", type=int, default=1, help="seeds 0..S-1 per row (default 1)")
    p.add_argument("--scale", choices=sorted(SCALES), default="cpu", help="cpu: cpu_default sizes; gpu: the paper's (configs/train/paper.yaml)")
    p.add_argument("--data", help="data set root (default: the scale config's data.root)")
    p.add_argument("--out", default="runs/ablation", help="output folder (default runs/ablation)")
    p.add_argument("--rows", help=f"comma-separated subset of rows (default all: {', '.join(ROWS)})")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a config field of every row")
    p.add_argument("--report", action="store_true", help="train nothing: write the tables from the rows and seeds already finished")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    if a.budget_minutes is not None and not a.budget_minutes > 0:
        raise AblationError(f"--budget-minutes: must be positive, got {a.budget_minutes}")
    if a.steps is not None and a.steps < 1:
        raise AblationError(f"--steps: must be >= 1, got {a.steps}")
    if a.seeds < 1:
        raise AblationError(f"--seeds: must be >= 1, got {a.seeds}")
    rows = list(ROWS) if not a.rows else [r.strip() for r in a.rows.split(",") if r.strip()]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        raise AblationError(f"--rows: unknown row '{unknown[0]}' (rows: {', '.join(ROWS)})")
    from model.config import parse_overrides

    extra = parse_overrides(a.set)
    base_path = ROOT / SCALES[a.scale]
    out = output_dir(a.out)
    data_root = row_config(base_path, rows[0], 0, a.data, extra)["data"]["root"]  # a bad config fails here, before any training
    if not a.report:
        from dataset_tools import DatasetIndex

        have = DatasetIndex(data_root).splits
        eval_splits = [s for s in EVAL_SPLITS if have.get(s)]
    t0 = time.perf_counter()
    results: dict[str, list[dict]] = {}
    jobs = [(r, s) for s in range(a.seeds) for r in rows]
    budget_s = None if a.budget_minutes is None else 60 * a.budget_minutes
    for row, seed in tqdm(jobs, desc="ablation rows", dynamic_ncols=True, disable=a.quiet or a.report):
        if a.report:
            done = RunDir(out / row / f"seed{seed}").result
            if done.is_file():
                results.setdefault(row, []).append(read_json(done, AblationError))
            continue
        results.setdefault(row, []).append(run_row(base_path, row, seed, out, a.data, budget_s, a.steps, extra, a.quiet, eval_splits))
    if not results:
        raise AblationError(f"{out}: no finished rows to report")
    meta = {"scale": a.scale, "config": SCALES[a.scale], "data": data_root,
            "seeds": a.seeds, "steps": a.steps, "budget_minutes": a.budget_minutes, "rows": rows, "wall_seconds_this_call": time.perf_counter() - t0}
    if "rectified" in rows:
        meta["rectification"] = rectification_report(row_config(base_path, "rectified", 0, a.data, extra))
    md, js = tables(results, meta)
    write_text_atomic(out / TABLES_MD, md)
    write_json_atomic(out / TABLES_JSON, js, indent=2)
    if not a.quiet:
        print(md)
    print(f"written {out / TABLES_MD} and {out / TABLES_JSON}")
    return 0


if __name__ == "__main__":
    run_cli(main)
