"""The paper's Tables I and II on our data, as one resumable command.

    python -m experiments.ablation --steps 420 --seeds 3 [--seeds-table2 2] [--scale cpu|gpu] [--data DIR] [--out DIR] [--jobs N]
    python -m experiments.ablation --budget-minutes 8 --seeds 1 ...   # equal wall-clock budgets instead

Every row is the base config (`--scale cpu`: configs/train/cpu_default.yaml; `gpu`:
configs/train/paper.yaml) with the paper's best settings (intrinsics-embedding pooling, uniform
class weights, occlusion loss, the pretrained EfficientNet-Lite0 trunk) and one change. Each row and
seed trains with `model.training` (what train.py runs) for the same number of optimiser steps (or
the same wall-clock budget), from the same seed, then is scored with `model.evaluation` (eval.py's
protocol, one confusion matrix per scene kept) on the easy, medium and hard splits (and `heldout`,
sampled scenes from seeds training never used, where the data set has one).

Resumable: `<out>/<row>/seed<k>/` holds the run; `result.json` there marks it finished (never
retrained; scored on an evaluation split the data set has gained since, or again where it lacks
the per-scene matrices); a killed row resumes from its latest.pt and its recorded training time
(`budget.json`).
Writes `<out>/tables.md` and `<out>/tables.json` with the paper's numbers beside ours: the mean over
seeds with its 95 % interval over seeds and scenes (model.bootstrap), and a verdict on each of the
paper's claims (CLAIMS) from the paired difference's interval (`verdict`), with the seeds that
would decide what is undecided (`runs_to_decide`). Rows of our own (SUPERVISION: issue 22's
supervision from the renderer, issue 23's bf16) get a table on every split and a verdict each
against `ours` (OUR_CLAIMS). `--jobs N` trains N rows at once (`run_jobs`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import output_dir, read_json, write_json_atomic, write_text_atomic
from common.resources import CODE_DIR
from common.schema import deep_merge
from model.bootstrap import paired_runs_bootstrap, per_scene_arrays, runs_bootstrap
from model.run_dir import RunDir

ROOT = CODE_DIR  # the checkout (common.resources)
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
    # issue 22: supervision from the renderer's passes, on top of `ours` (docs/model.md)
    "ours_depth": ("ours + depth supervision from the distance pass", {"loss": {"depth_weight": 1.0}}),
    "ours_camera_seg": ("ours + camera-view semantic head", {"loss": {"camera_seg_weight": 0.5}}),
    "ours_depth_camera_seg": ("ours + depth supervision + camera-view head",
                              {"loss": {"depth_weight": 1.0, "camera_seg_weight": 0.5}}),
    "ours_recipe": ("ours + both + soft Dice + warm-up and cosine decay (configs/train/demo.yaml's recipe)",
                    {"loss": {"depth_weight": 1.0, "camera_seg_weight": 0.5, "dice_weight": 1.0},
                     "train": {"lr_schedule": "cosine", "warmup_steps": 50}}),
    "ours_recipe_13_3_1_1": ("the recipe with class weights 13-3-1-1 (at 420 steps the weights lifted vehicles most)",
                             {"loss": {"depth_weight": 1.0, "camera_seg_weight": 0.5, "dice_weight": 1.0, "class_weights": "paper"},
                              "train": {"lr_schedule": "cosine", "warmup_steps": 50}}),
    # issue 23: the same model under bfloat16 autocast; the hoped-for verdict against `ours` is undecided (no difference)
    "ours_bf16": ("ours under bfloat16 autocast (model.precision: bf16)", {"model": {"precision": "bf16"}}),
}
COLUMNS = [("miou", "mIoU"), ("iou/occlusion", "Occlusion"), ("iou/vehicle", "Vehicles"),
           ("iou/lane_marking", "Markings"), ("iou/street", "Street"), ("iou/background", "Background")]
COLUMNS_III = COLUMNS + [("iou_tol/lane_marking", "Markings within 1 cell")]  # issue 22's table: also the tolerance IoU
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
TABLE_I_ROWS = tuple(row for _, row in TABLE_I)  # --seeds; the other rows (Table II only): --seeds-table2
# The paper's claims: (claim, [(better row, worse row)], the splits the paper shows it on). A claim is
# reproduced where every pair's mIoU difference (better - worse) has an interval above 0 on every one
# of those splits, contradicted where any is below 0; other splits are shown, not counted.
CLAIMS = [
    ("raw fisheye > cylindrically rectified (Table I, every split)", [("ours", "rectified")], ("easy", "medium", "hard")),
    ("uniform class weights > 13-3-1-1 (Table II)", [("ours", "weights_13_3_1_1")], ("medium",)),
    ("the occlusion loss helps (Table II, on 13-3-1-1)", [("weights_13_3_1_1", "weights_13_3_1_1_no_occlusion")], ("medium",)),
    ("pooling: intrinsics + embedding > sensors per cell > weighted sum, sum > max (Table II)",
     [("ours", "pool_sensors_per_cell"), ("pool_sensors_per_cell", "pool_weighted_sum"), ("pool_sum", "pool_max")], ("medium",)),
]
# Issue 22's questions, asked the same way on every split with a test set (none is the paper's).
SUPERVISION = [("depth supervision", "ours_depth"), ("camera-view head", "ours_camera_seg"),
               ("both", "ours_depth_camera_seg"), ("both + Dice + cosine schedule", "ours_recipe"),
               ("the recipe + class weights 13-3-1-1", "ours_recipe_13_3_1_1"),
               ("bf16 autocast (issue 23)", "ours_bf16")]
OUR_CLAIMS = [(f"{label} > ours" + ("" if "issue" in label else " (issue 22)"), [(row, "ours")], ("easy", "medium", "hard", "heldout"))
              for label, row in SUPERVISION]
VERDICT_KEY = "miou"


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
    return {s: {"overall": r["overall"], "frames": r["frames"], "inference_ms_per_frame": r["inference_ms_per_frame"],
                "scenes": r["scenes"]} for s, r in splits.items()}


def run_row(base_path, row, seed, out: Path, data, budget_s, steps, extra, quiet, eval_splits) -> dict:
    """Train and score one row and seed (`eval_splits`: those of EVAL_SPLITS the data set has)."""
    from model.training import train_with_budget

    run = RunDir(out / row / f"seed{seed}")
    done = run.result
    if done.is_file():
        result = read_json(done, AblationError)
        # a split added to the data set later, or one scored before per-scene matrices were kept: scored, not retrained
        missing = [s for s in eval_splits if "scenes" not in result["splits"].get(s, {})]
        if missing and run.latest.is_file():
            result["splits"].update(_split_results(evaluate_row(run, missing)))
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


def run_jobs(jobs: list[tuple[str, int]], args: tuple, extra: dict, quiet: bool, eval_splits, parallel: int = 1):
    """Yield (row, result) of every (row, seed) job, in the jobs' order. With `parallel` > 1, that
    many jobs train at once in worker processes, each with cores / parallel compute threads (unless
    --set train.threads says otherwise). On 2 cores two 1-thread runs made 1.07x the steps per hour
    of one 2-thread run (docs/results.md): little; more cores gain more. A job's result does not
    depend on which worker ran it."""
    from tqdm import tqdm

    base_path, out, data, budget_s, steps = args
    bar = tqdm(total=len(jobs), desc="ablation rows", dynamic_ncols=True, disable=quiet)
    if parallel == 1:
        for row, seed in jobs:
            yield row, run_row(base_path, row, seed, out, data, budget_s, steps, extra, quiet, eval_splits)
            bar.update(1)
        bar.close()
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from model.cpu import compute_threads

    threads = {"train": {"threads": compute_threads(parallel)}}
    extra = deep_merge(threads, extra or {})  # the user's --set train.threads wins
    done = {}
    with ProcessPoolExecutor(parallel, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_row, base_path, row, seed, out, data, budget_s, steps, extra, True, eval_splits): (row, seed)
                   for row, seed in jobs}
        try:
            for f in as_completed(futures):
                done[futures[f]] = f.result()
                bar.update(1)
        except BaseException:  # a failed job, or Ctrl-C: start no other job; those in flight finish or save and stop
            for f in futures:
                f.cancel()
            raise
    bar.close()
    for row, seed in jobs:
        yield row, done[row, seed]


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


def verdict(low: float, high: float) -> str:
    """The paired difference's interval (better - worse, in the paper's direction) -> reproduced
    (above 0), contradicted (below 0) or undecided (contains 0, or unknown)."""
    if low > 0:
        return "reproduced"
    if high < 0:
        return "contradicted"
    return "undecided"


def combine(verdicts) -> str:
    """One claim over several pairs or splits: reproduced only where every part is, contradicted
    where any part is, else undecided (also when there is no part)."""
    verdicts = list(verdicts)
    if verdicts and all(v == "reproduced" for v in verdicts):
        return "reproduced"
    return "contradicted" if "contradicted" in verdicts else "undecided"


def detectable(low: float, high: float) -> float:
    """The smallest difference this run could tell from 0: the half-width of the paired interval."""
    return (high - low) / 2


def runs_to_decide(diff: float, low: float, high: float, runs: int) -> float | None:
    """Runs per row (seeds, with the test scenes kept) that would decide an undecided difference of
    this size, if the interval shrinks as 1 / sqrt(runs): runs x (half-width / |diff|)^2, rounded
    up. None where the interval already excludes 0; inf where the difference is 0."""
    if low > 0 or high < 0:
        return None
    if diff == 0:
        return math.inf
    return float(math.ceil(runs * (detectable(low, high) / abs(diff)) ** 2))


def _runs(results: list[dict], split: str):
    """The (cms, occs) per seed of one row on `split`, or None where a seed lacks per-scene matrices
    or the seeds were scored on different scenes."""
    have = [r["splits"][split] for r in results if split in r["splits"]]
    if not have or any("scenes" not in h for h in have) or len({tuple(sorted(h["scenes"])) for h in have}) != 1:
        return None
    return [per_scene_arrays(h["scenes"]) for h in have]


def summarise(results: list[dict], split: str, class_names, columns=None) -> dict:
    """Column key -> {"mean", "std" (over seeds; None for one), "seeds", "low", "high" (95 % over
    seeds and scenes; None without per-scene matrices), "scenes"}, or None where no seed has it."""
    runs = _runs(results, split)
    iv = runs_bootstrap(runs, class_names) if runs else {}
    out = {}
    for key, _ in columns or COLUMNS:
        vals = [r["splits"][split]["overall"].get(key) for r in results if split in r["splits"]]
        vals = [v for v in vals if v is not None and v == v]
        if not vals:
            out[key] = None
            continue
        low, high = (iv[key]["low"], iv[key]["high"]) if key in iv else (None, None)
        out[key] = {"mean": float(np.mean(vals)), "std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
                    "seeds": len(vals), "low": low, "high": high, "scenes": len(runs[0][0]) if runs else None}
    return out


def claims(results: dict[str, list[dict]], class_names, which=None) -> list[dict]:
    """Every claim of `which` (default CLAIMS) with its parts (pair and split: the mIoU difference better - worse,
    its paired 95 % interval over seeds and scenes, the smallest detectable difference, the verdict)
    and its verdict on the paper's splits. Pairs or splits without per-scene scores are left out."""
    out = []
    for claim, pairs, paper_splits in CLAIMS if which is None else which:
        parts = []
        for better, worse in pairs:
            ra_all, rb_all = results.get(better, []), results.get(worse, [])
            common = {r["seed"] for r in ra_all} & {r["seed"] for r in rb_all}
            paired = len(common) >= 2  # common random numbers: seed k of both rows, paired
            if paired:
                ra_all, rb_all = ([r for r in sorted(rs, key=lambda r: r["seed"]) if r["seed"] in common] for rs in (ra_all, rb_all))
            for split in EVAL_SPLITS:
                ra, rb = _runs(ra_all, split), _runs(rb_all, split)
                if not ra or not rb or ra[0][0].shape != rb[0][0].shape or (paired and len(ra) != len(rb)):
                    continue
                d = paired_runs_bootstrap(ra, rb, class_names, paired_seeds=paired)[VERDICT_KEY]
                parts.append({"better": better, "worse": worse, "split": split, "paper_split": split in paper_splits,
                              "seeds": [len(ra), len(rb)], "paired_seeds": paired, "scenes": len(ra[0][0]), **d,
                              "detectable": detectable(d["low"], d["high"]), "verdict": verdict(d["low"], d["high"]),
                              "runs_to_decide": runs_to_decide(d["diff"], d["low"], d["high"], min(len(ra), len(rb)))})
        counted = [p["verdict"] for p in parts if p["paper_split"]]
        complete = len(counted) == len(pairs) * len(paper_splits)
        v = combine(counted) if complete or "contradicted" in counted else "undecided"
        one_seed = any(min(p["seeds"]) < 2 for p in parts)  # the interval then holds the scenes' spread, not training's
        out.append({"claim": claim, "splits": list(paper_splits), "verdict": v, "complete": complete, "one_seed": one_seed, "parts": parts})
    return out


def _cell(s) -> str:
    if s is None:
        return "-"
    if s["low"] is not None and s["low"] == s["low"]:
        return f"{s['mean']:.3f} [{s['low']:.3f}, {s['high']:.3f}]"
    return f"{s['mean']:.3f}" if s["std"] is None else f"{s['mean']:.3f} ± {s['std']:.3f}"


def _paper(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def _signed(v) -> str:
    return "-" if v is None or v != v else f"{v:+.3f}"


def _budget(meta: dict) -> str:
    return f"{meta['steps']} steps per row" if meta.get("steps") else f"{meta['budget_minutes']:g} min of training per row"


def _verdict_lines(cs: list[dict]) -> list[str]:
    """A claim's verdict table and its parts' table (markdown lines)."""
    lines = ["| Claim | Verdict |", "|---|---|"]
    for c in cs:
        lines.append(f"| {c['claim']} | **{c['verdict']}**" + ("" if c["complete"] else " (rows or splits missing)")
                     + (" (one seed: training noise not in the interval, provisional)" if c.get("one_seed") else "") + " |")
    lines += ["", "| Claim | Better - worse | Split | Seeds | Scenes | Difference | 95 % interval | Smallest detectable | Verdict | Seeds to decide |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for c in cs:
        for p in c["parts"]:
            lines.append(f"| {c['claim'].split(' (')[0]} | {p['better']} - {p['worse']} | {p['split']}{'*' if p['paper_split'] else ''} | "
                         f"{p['seeds'][0]}, {p['seeds'][1]}{' paired' if p.get('paired_seeds') else ''} | {p['scenes']} | {_signed(p['diff'])} | "
                         f"[{_signed(p['low'])}, {_signed(p['high'])}] | {p['detectable']:.3f} | {p['verdict']} | {_decide_cell(p.get('runs_to_decide'))} |")
    return lines


def _decide_cell(n) -> str:
    return "-" if n is None else ("never (no difference)" if n == math.inf else f"{n:.0f}")


def tables(results: dict[str, list[dict]], meta: dict) -> tuple[str, dict]:
    heads = [t for _, t in COLUMNS]
    names = meta["class_names"]
    lines = ["# Tables I and II on our data", "",
             f"Scale `{meta['scale']}`, data `{meta['data']}`, seeds {meta['seeds']} (Table I rows; other rows "
             f"{meta.get('seeds_table2', meta['seeds'])}), {_budget(meta)}. Ours: the mean over seeds [its 95 % interval "
             "from a bootstrap over seeds and scenes]; paper: DaF-BEVSeg.", "",
             "## Table I: raw fisheye against cylindrical rectification", "",
             "| Method | Dataset | " + " | ".join(f"{h} (ours) | {h} (paper)" for h in heads) + " |",
             "|---|---|" + "---|---|" * len(heads)]
    js = {"meta": meta, "table_1": [], "table_2": [], "table_3": [], "claims": [], "runs": results}
    for label, row in TABLE_I:
        if row not in results:
            continue
        for split in EVAL_SPLITS:
            if not any(split in r["splits"] for r in results[row]):
                continue
            s = summarise(results[row], split, names)
            paper = PAPER_TABLE_I.get((row, split), [None] * len(COLUMNS))
            lines.append(f"| {label} | {split} | " + " | ".join(f"{_cell(s[k])} | {_paper(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
            js["table_1"].append({"method": label, "row": row, "split": split, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    lines += ["", "## Table II: ablations on the medium split", "",
              "| Ablation | Setting | " + " | ".join(f"{h} (ours) | {h} (paper)" for h in heads) + " |",
              "|---|---|" + "---|---|" * len(heads)]
    for section, label, row, paper in TABLE_II:
        if row not in results or not any("medium" in r["splits"] for r in results[row]):
            continue
        s = summarise(results[row], "medium", names)
        lines.append(f"| {section} | {label} | " + " | ".join(f"{_cell(s[k])} | {_paper(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
        js["table_2"].append({"section": section, "setting": label, "row": row, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    rows3 = [(label, row) for label, row in SUPERVISION if row in results]
    if rows3 and "ours" in results:
        lines += ["", "## Supervision from the renderer (issue 22) and bf16 (issue 23), on every split", "",
                  "| Row | Dataset | " + " | ".join(t for _, t in COLUMNS_III) + " |", "|---|---|" + "---|" * len(COLUMNS_III)]
        for label, row in [("ours", "ours"), *rows3]:
            for split in EVAL_SPLITS:
                if not any(split in r["splits"] for r in results[row]):
                    continue
                s = summarise(results[row], split, names, COLUMNS_III)
                lines.append(f"| {label} | {split} | " + " | ".join(_cell(s[k]) for k, _ in COLUMNS_III) + " |")
                js["table_3"].append({"setting": label, "row": row, "split": split, "ours": s})
    js["claims"] = claims(results, names)
    lines += ["", "## Verdicts on the paper's claims", "",
              "Per claim, the mIoU difference (paper's better row minus worse row, mean over seeds), its 95 % interval "
              "from a bootstrap over seeds and scenes with the scenes paired (and the seeds, where both rows have the "
              "same two or more: seed k gives every row the same data order, augmentation and initial state), and the "
              "smallest difference this run "
              "could have detected (the interval's half-width). **reproduced**: the interval is above 0; "
              "**contradicted**: below 0; **undecided**: it contains 0. The claim's verdict counts the paper's "
              "splits (marked *); the others are shown for information. Seeds to decide: for an undecided part, "
              "the seeds per row that would decide a difference of the size measured, if the interval shrinks "
              "as 1 / sqrt(seeds) (an extrapolation from this run's spread).", "", *_verdict_lines(js["claims"])]
    if rows3:
        js["our_claims"] = claims(results, names, OUR_CLAIMS)
        lines += ["", "## Verdicts on the supervision rows (issue 22) and bf16 (issue 23)", "",
                  "The same test, each row against `ours` on every split with a test set: **reproduced** means "
                  "the row is better on every split. For bf16 the hoped-for verdict is undecided: no difference "
                  "larger than the smallest detectable one.", "", *_verdict_lines(js["our_claims"])]
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
    p = ArgumentParser(prog="experiments.ablation", description="Train and score every row of the paper's Tables I and II.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--steps", type=int, help="optimiser steps per row and seed: every row learns from the same number of batches (make ablation's default)")
    g.add_argument("--budget-minutes", type=float, help="training wall-clock minutes per row and seed instead (depends on the machine's load)")
    p.add_argument("--seeds", type=int, default=1, help="seeds 0..S-1 per row (default 1)")
    p.add_argument("--seeds-table2", type=int, help="seeds for the rows only in Table II (default: --seeds; Table I's rows always get --seeds)")
    p.add_argument("--scale", choices=sorted(SCALES), default="cpu", help="cpu: cpu_default sizes; gpu: the paper's (configs/train/paper.yaml)")
    p.add_argument("--data", help="data set root (default: the scale config's data.root)")
    p.add_argument("--out", default="runs/ablation", help="output folder (default runs/ablation)")
    p.add_argument("--rows", help=f"comma-separated subset of rows (default all: {', '.join(ROWS)})")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="override a config field of every row")
    p.add_argument("--jobs", type=int, default=1, help="rows and seeds trained at once, each with cores/jobs compute threads (default 1)")
    p.add_argument("--report", action="store_true", help="train nothing: write the tables from the rows and seeds already finished")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    if a.budget_minutes is not None and not a.budget_minutes > 0:
        raise AblationError(f"--budget-minutes: must be positive, got {a.budget_minutes}")
    if a.steps is not None and a.steps < 1:
        raise AblationError(f"--steps: must be >= 1, got {a.steps}")
    if a.seeds < 1:
        raise AblationError(f"--seeds: must be >= 1, got {a.seeds}")
    if a.jobs < 1:
        raise AblationError(f"--jobs: must be >= 1, got {a.jobs}")
    seeds2 = a.seeds if a.seeds_table2 is None else a.seeds_table2
    if seeds2 < 1:
        raise AblationError(f"--seeds-table2: must be >= 1, got {seeds2}")
    rows = list(ROWS) if not a.rows else [r.strip() for r in a.rows.split(",") if r.strip()]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        raise AblationError(f"--rows: unknown row '{unknown[0]}' (rows: {', '.join(ROWS)})")
    from model.config import parse_overrides

    extra = parse_overrides(a.set)
    base_path = ROOT / SCALES[a.scale]
    out = output_dir(a.out)
    data_root = row_config(base_path, rows[0], 0, a.data, extra)["data"]["root"]  # a bad config fails here, before any training
    from dataset_tools import TRAIN_CLASSES, DatasetIndex

    try:
        index = DatasetIndex(data_root)
    except InputError:
        if not a.report:
            raise
        index = None  # --report from finished rows alone: the data set may be gone
    eval_splits = [s for s in EVAL_SPLITS if index.splits.get(s)] if index else []
    class_names = index.class_names if index else list(TRAIN_CLASSES)
    t0 = time.perf_counter()
    results: dict[str, list[dict]] = {}
    seeds_of = {r: a.seeds if r in TABLE_I_ROWS else seeds2 for r in rows}
    jobs = [(r, s) for s in range(max(seeds_of.values())) for r in rows if s < seeds_of[r]]  # seed 0 of every row first
    budget_s = None if a.budget_minutes is None else 60 * a.budget_minutes
    if a.report:
        for row, seed in jobs:
            done = RunDir(out / row / f"seed{seed}").result
            if done.is_file():
                results.setdefault(row, []).append(read_json(done, AblationError))
    else:
        args = (base_path, out, a.data, budget_s, a.steps)
        for row, result in run_jobs(jobs, args, extra, a.quiet, eval_splits, a.jobs):
            results.setdefault(row, []).append(result)
    if not results:
        raise AblationError(f"{out}: no finished rows to report")
    meta = {"scale": a.scale, "config": SCALES[a.scale], "data": data_root, "class_names": class_names,
            "seeds": a.seeds, "seeds_table2": seeds2, "steps": a.steps, "budget_minutes": a.budget_minutes, "rows": rows, "wall_seconds_this_call": time.perf_counter() - t0}
    if "rectified" in rows and index is not None:
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
