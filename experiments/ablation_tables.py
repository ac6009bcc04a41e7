"""The ablation's tables.md and tables.json from its finished rows: the paper's Tables I and II with
its numbers beside ours, the supervision rows on every split, the verdicts on the claims
(model.verdicts), what rectification costs, and the runs. Figures are formatted as eval.py's
tables are (model.eval_report).
"""

from __future__ import annotations

import math

import numpy as np

from model.eval_report import fmt, fmt_interval, signed
from model.verdicts import claims as judge, summarise

from .rows import CLAIMS, COLUMNS, COLUMNS_III, EVAL_SPLITS, OUR_CLAIMS, PAPER_TABLE_I, ROWS, SUPERVISION, TABLE_I, TABLE_II, VERDICT_KEY


def claims(results: dict[str, list[dict]], class_names, which=None) -> list[dict]:
    """The verdict on every claim of `which` (default the paper's, CLAIMS) over the evaluation splits."""
    return judge(results, class_names, CLAIMS if which is None else which, EVAL_SPLITS, VERDICT_KEY)


def _cell(s) -> str:
    """The mean over seeds with its interval over seeds and scenes, else ± the spread over seeds."""
    if s is None:
        return "-"
    if s["low"] is not None and s["low"] == s["low"]:
        return fmt_interval(s["mean"], (s["low"], s["high"]))
    return fmt(s["mean"]) if s["std"] is None else f"{s['mean']:.3f} ± {s['std']:.3f}"


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
                         f"{p['seeds'][0]}, {p['seeds'][1]}{' paired' if p.get('paired_seeds') else ''} | {p['scenes']} | {signed(p['diff'])} | "
                         f"[{signed(p['low'])}, {signed(p['high'])}] | {p['detectable']:.3f} | {p['verdict']} | {_decide_cell(p.get('runs_to_decide'))} |")
    return lines


def _decide_cell(n) -> str:
    return "-" if n is None else ("never (no difference)" if n == math.inf else f"{n:.0f}")


def tables(results: dict[str, list[dict]], meta: dict) -> tuple[str, dict]:
    """tables.md and tables.json of the finished rows (`results`: row -> its seeds' result.json)."""
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
            s = summarise(results[row], split, names, COLUMNS)
            paper = PAPER_TABLE_I.get((row, split), [None] * len(COLUMNS))
            lines.append(f"| {label} | {split} | " + " | ".join(f"{_cell(s[k])} | {fmt(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
            js["table_1"].append({"method": label, "row": row, "split": split, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    lines += ["", "## Table II: ablations on the medium split", "",
              "| Ablation | Setting | " + " | ".join(f"{h} (ours) | {h} (paper)" for h in heads) + " |",
              "|---|---|" + "---|---|" * len(heads)]
    for section, label, row, paper in TABLE_II:
        if row not in results or not any("medium" in r["splits"] for r in results[row]):
            continue
        s = summarise(results[row], "medium", names, COLUMNS)
        lines.append(f"| {section} | {label} | " + " | ".join(f"{_cell(s[k])} | {fmt(p)}" for (k, _), p in zip(COLUMNS, paper)) + " |")
        js["table_2"].append({"section": section, "setting": label, "row": row, "ours": s, "paper": dict(zip([k for k, _ in COLUMNS], paper))})
    rows3 = [(label, row) for label, row in SUPERVISION if row in results]
    if rows3 and "ours" in results:
        lines += ["", "## Supervision from the renderer and bf16, on every split", "",
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
        lines += ["", "## Verdicts on the supervision rows and bf16", "",
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
