"""The paper's Tables I and II on our data, as one resumable command.

    python -m experiments.ablation --steps 420 --seeds 3 [--seeds-table2 2] [--scale cpu|gpu] [--data DIR] [--out DIR] [--jobs N]
    python -m experiments.ablation --budget-minutes 8 --seeds 1 ...   # equal wall-clock budgets instead

Every row (experiments.rows) is the base config (`--scale cpu`: configs/train/cpu_default.yaml;
`gpu`: configs/train/paper.yaml) with the paper's best settings and one change. Each row and seed
trains with `model.training` (what train.py runs) for the same number of optimiser steps (or the
same wall-clock budget), from the same seed, then is scored with `model.evaluation` (eval.py's
protocol, one confusion matrix per scene kept) on the easy, medium and hard splits (and `heldout`
where the data set has one). Resumable: `<out>/<row>/seed<k>/` holds the run; `result.json` there
marks it finished (never retrained; scored again on a split it lacks); a killed row resumes from
its latest.pt and its recorded training time (`budget.json`). `--jobs N` trains N rows at once
through common.backend. Writes `<out>/tables.md` and `<out>/tables.json`
(experiments.ablation_tables: the verdicts of model.verdicts).
"""

from __future__ import annotations

import time
from pathlib import Path

from common.backend import make_backend
from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import output_dir, read_json, write_json_atomic, write_text_atomic
from common.schema import deep_merge
from model.run_dir import RunDir
from model.verdicts import combine, detectable, runs_to_decide, verdict  # noqa: F401 (the ablation's statistics)

from .ablation_tables import claims, tables  # noqa: F401
from .rectification import rectification_report
from .rows import (CLAIMS, EVAL_SPLITS, OUR_CLAIMS, ROOT, ROWS, SCALES, SUPERVISION, TABLE_I_ROWS, TABLE_II,  # noqa: F401
                   TABLES_JSON, TABLES_MD, row_config)


class AblationError(InputError):
    pass


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


def _job(job: tuple[str, int], shared: tuple) -> dict:
    (base_path, out, data, budget_s, steps), extra, quiet, eval_splits = shared
    return run_row(base_path, *job, out, data, budget_s, steps, extra, quiet, eval_splits)


def run_jobs(jobs: list[tuple[str, int]], args: tuple, extra: dict, quiet: bool, eval_splits, parallel: int = 1):
    """Yield (row, result) of every (row, seed) job, in the jobs' order. With `parallel` > 1, that
    many jobs train at once in worker processes (common.backend), each with cores / parallel
    compute threads (unless --set train.threads says otherwise). A job's result does not depend on
    which worker ran it."""
    from tqdm import tqdm

    from model.cpu import compute_threads

    if parallel > 1:
        extra = deep_merge({"train": {"threads": compute_threads(parallel)}}, extra or {})  # the user's --set wins
    bar = tqdm(total=len(jobs), desc="ablation rows", dynamic_ncols=True, disable=quiet)
    for (row, _), result in zip(jobs, make_backend("local", parallel).map(_job, jobs, (args, extra, quiet or parallel > 1, eval_splits))):
        bar.update(1)
        yield row, result
    bar.close()


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
    seeds2 = a.seeds if a.seeds_table2 is None else a.seeds_table2
    for option, n in (("--seeds", a.seeds), ("--jobs", a.jobs), ("--seeds-table2", seeds2)):
        if n < 1:
            raise AblationError(f"{option}: must be >= 1, got {n}")
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
