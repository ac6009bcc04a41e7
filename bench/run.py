"""`make bench`: run every bench module, write bench/out/results.json and results.md.

A bench module exposes `run() -> dict` mapping a figure's name either to
{"value": number, "unit": str, "goal": str or None, "met": bool or None} or to a plain value, with
goals for plain values under the key "goals" ({name: ">= 5"}). A module that fails is reported in
the table (and `make bench` exits non-zero), not hidden.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import sys
import time
from pathlib import Path

from common.files import write_text_atomic

MODULES = ["bench.geometry", "bench.scenes", "bench.realism", "bench.topdown", "bench.fusion", "bench.model", "bench.report",
           "bench.ray_backend"]
OUT = Path("bench/out")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", help="module names (e.g. geometry model)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--baseline", default=None,
                    help="commit the model and realism parts measure alongside, as ratios (default: each part's "
                         "BASELINE; 'none' to skip)")
    args = ap.parse_args(argv)
    results, failed = {}, False
    for name in MODULES:
        short = name.split(".")[-1]
        if args.only and short not in args.only:
            continue
        t0 = time.perf_counter()
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # not written yet
            raise
        print(f"bench: {short} ...", flush=True)
        try:
            figures = normalise(mod.run(**_options(short, args)))
            results[short] = {"figures": figures, "seconds": round(time.perf_counter() - t0, 1)}
        except Exception as exc:  # noqa: BLE001 - a bench failure is reported in the table
            results[short] = {"error": f"{type(exc).__name__}: {exc}"}
            failed = True
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "cpus": _cpus(), "time": time.strftime("%Y-%m-%d %H:%M")}
    write_text_atomic(args.out / "results.json", json.dumps({"meta": meta, "results": results}, indent=2))
    write_text_atomic(args.out / "results.md", to_markdown(meta, results))
    print(to_markdown(meta, results))
    print(f"written {args.out / 'results.json'} and {args.out / 'results.md'}")
    return 1 if failed else 0


def _options(part: str, args) -> dict:
    if part == "realism":
        from bench.realism import BASELINE
    elif part == "model":
        from bench.model import BASELINE
    else:
        return {}

    baseline = BASELINE if args.baseline is None else args.baseline
    return {"baseline": None if baseline.lower() == "none" else baseline}


def normalise(figures: dict) -> dict:
    """Every figure as {"value", "unit", "goal", "met"}; "met" from a ">= x" / "<= x" goal."""
    figures = dict(figures)
    goals = figures.pop("goals", {})
    out = {}
    for name, v in figures.items():
        if isinstance(v, dict) and "value" in v:
            out[name] = v
            continue
        goal, met = goals.get(name), None
        if goal and isinstance(v, (int, float)):
            op, bound = goal.split()
            met = v >= float(bound) if op == ">=" else v <= float(bound)
        out[name] = {"value": v, "unit": "", "goal": goal, "met": met}
    return out


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0))


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def to_markdown(meta: dict, results: dict) -> str:
    lines = [f"Bench on {meta['cpus']} CPUs, Python {meta['python']}, {meta['time']}", "",
             "| part | figure | value | unit | goal | met |", "|---|---|---|---|---|---|"]
    for part, r in results.items():
        if "error" in r:
            lines.append(f"| {part} | (failed) | {r['error']} | | | |")
            continue
        for name, f in r["figures"].items():
            met = {True: "yes", False: "NO", None: ""}[f.get("met")]
            lines.append(f"| {part} | {name} | {_fmt(f['value'])} | {f.get('unit', '')} | {f.get('goal') or ''} | {met} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
