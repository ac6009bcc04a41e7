"""Verdicts on claims of the form "row A scores better than row B", from several training runs
(seeds) per row scored per scene: the statistics of experiments.ablation, beside the bootstrap they
rest on (model.bootstrap).

    summarise(results, split, class_names, columns)   # column -> mean over seeds, 95 % interval
    claims(results, class_names, which, splits)       # each claim's parts and verdict
    verdict(low, high)                                # an interval -> reproduced / contradicted / undecided

`results`: row -> the result.json of each of its seeds ({"seed", "splits": {split: {"overall",
"scenes"}}}). A claim is reproduced where every pair's difference (better - worse) has an interval
above 0 on every one of its splits, contradicted where any is below 0; other splits are shown,
not counted.
"""

from __future__ import annotations

import math

import numpy as np

from .bootstrap import paired_runs_bootstrap, per_scene_arrays, runs_bootstrap


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


def runs_of(results: list[dict], split: str):
    """The (cms, occs) per seed of one row on `split`, or None where a seed lacks per-scene matrices
    or the seeds were scored on different scenes."""
    have = [r["splits"][split] for r in results if split in r["splits"]]
    if not have or any("scenes" not in h for h in have) or len({tuple(sorted(h["scenes"])) for h in have}) != 1:
        return None
    return [per_scene_arrays(h["scenes"]) for h in have]


def summarise(results: list[dict], split: str, class_names, columns) -> dict:
    """Column key -> {"mean", "std" (over seeds; None for one), "seeds", "low", "high" (95 % over
    seeds and scenes; None without per-scene matrices), "scenes"}, or None where no seed has it."""
    runs = runs_of(results, split)
    iv = runs_bootstrap(runs, class_names) if runs else {}
    out = {}
    for key, _ in columns:
        vals = [r["splits"][split]["overall"].get(key) for r in results if split in r["splits"]]
        vals = [v for v in vals if v is not None and v == v]
        if not vals:
            out[key] = None
            continue
        low, high = (iv[key]["low"], iv[key]["high"]) if key in iv else (None, None)
        out[key] = {"mean": float(np.mean(vals)), "std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
                    "seeds": len(vals), "low": low, "high": high, "scenes": len(runs[0][0]) if runs else None}
    return out


def claims(results: dict[str, list[dict]], class_names, which, splits, key: str = "miou") -> list[dict]:
    """Every claim of `which` ((claim, [(better row, worse row)], the splits it is judged on)) with its parts (pair and split: the mIoU difference better - worse,
    its paired 95 % interval over seeds and scenes, the smallest detectable difference, the verdict)
    and its verdict on the paper's splits. Pairs or splits without per-scene scores are left out."""
    out = []
    for claim, pairs, paper_splits in which:
        parts = []
        for better, worse in pairs:
            ra_all, rb_all = results.get(better, []), results.get(worse, [])
            common = {r["seed"] for r in ra_all} & {r["seed"] for r in rb_all}
            paired = len(common) >= 2  # common random numbers: seed k of both rows, paired
            if paired:
                ra_all, rb_all = ([r for r in sorted(rs, key=lambda r: r["seed"]) if r["seed"] in common] for rs in (ra_all, rb_all))
            for split in splits:
                ra, rb = runs_of(ra_all, split), runs_of(rb_all, split)
                if not ra or not rb or ra[0][0].shape != rb[0][0].shape or (paired and len(ra) != len(rb)):
                    continue
                d = paired_runs_bootstrap(ra, rb, class_names, paired_seeds=paired)[key]
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
