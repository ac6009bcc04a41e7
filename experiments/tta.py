"""Time to accuracy (issue 33): the training minutes, validation included, until the held-out
scores reach a target (mIoU 0.60 and lane markings 0.20), for this checkout and a baseline commit
trained on the same data set with each commit's own default config; the median over seeds of each,
and their ratio (this checkout / baseline) is the figure.

    python -m experiments.tta --data data/medium [--baseline 4017132] [--seeds 0 1 2] [--out runs/tta]
        [--target miou=0.60 iou/lane_marking=0.20] [--val-every 110] [--config configs/train/cpu_medium.yaml]

Each run is that commit's `train.py --config CONFIG` (its own tree: the baseline's is written by
`git archive` under OUT) with data.root, data.val_split=heldout, train.seed and train.val_every
set, into OUT/<tag>_s<seed>. Where the baseline's reader refuses fields that frames have gained
since (the camera's `sensor` record in meta.json), it reads OUT/data_for_baseline: links to the
same files, meta.json without those fields. Runs go one after another, seeds in turn and the two commits in the
order A B, B A, ... (a machine that slows down over hours slows both alike), never two at once.
A run is stopped (SIGTERM: train.py saves latest.pt) at the first validation that reaches every
target; its result is written to OUT/<tag>_s<seed>.json and the run is not trained again. An
interrupted command resumes: a run without a result continues from its folder (train.py resumes)
and the minutes leave the pause out (experiments.curve's training time). A run that ends its
schedule short of the target counts its whole time, marked not reached: a median with such a run
is a lower bound. The minutes are training time from the first step (start-up and the data set's
first load not counted) up to the step whose validation reached the target, every earlier
validation's time included.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

from common.cli import ArgumentParser, run_cli
from common.errors import InputError
from common.files import write_text_atomic
from common.resources import CODE_DIR, checkout

from .curve import CurveError, read_curve

BASELINE = "4017132"  # the commit issue 33 measures against
TARGET = {"miou": 0.60, "iou/lane_marking": 0.20}
POLL_S = 20.0


class TtaError(InputError):
    pass


_KNOWN_META = """import json
from dataclasses import fields
from dataset_tools.format.meta import FrameMeta
print(json.dumps([f.name for f in fields(FrameMeta) if f.name != "path"]))"""


def meta_fields(root: Path) -> list[str] | None:
    """The frame meta.json fields the tree at `root` reads (its FrameMeta), None if it cannot say."""
    r = subprocess.run([sys.executable, "-c", _KNOWN_META], cwd=root, env={**os.environ, "PYTHONPATH": str(root)},
                       capture_output=True, text=True, timeout=120)
    try:
        return list(json.loads(r.stdout)) if r.returncode == 0 else None
    except ValueError:
        return None


def data_view(data: Path, known: list[str], view: Path) -> Path:
    """`data` as an older tree reads it: a folder of hard links to its files whose meta.json files keep only
    the fields in `known` (a reader that refuses unknown fields, as 4017132's does the camera's
    `sensor` record, then reads the same frames). Made once; a finished view is reused."""
    done = view / ".complete"
    if done.is_file():
        return view
    for src in sorted(data.rglob("*")):
        dst = view / src.relative_to(data)
        if src.is_dir():
            dst.mkdir(parents=True, exist_ok=True)
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.name == "meta.json":
            meta = json.loads(src.read_text())
            write_text_atomic(dst, json.dumps({k: v for k, v in meta.items() if k in known}))
        elif not dst.exists():
            try:
                os.link(src, dst)  # a hard link: readers may refuse symbolic links
            except OSError:  # another file system
                shutil.copy2(src, dst)
    done.write_text("")
    return view


def parse_targets(items) -> dict[str, float]:
    out = {}
    for it in items:
        name, sep, value = str(it).partition("=")
        try:
            v = float(value)
        except ValueError:
            v = None
        if not sep or not name or v is None or not 0.0 < v <= 1.0:
            raise TtaError(f"--target: '{it}' is not METRIC=VALUE with 0 < VALUE <= 1 (e.g. miou=0.60)")
        out[name] = v
    return out


def reached(curve: dict, target: dict) -> int | None:
    """Index of the first validation whose every target metric is at least its target, or None."""
    for i in range(len(curve["steps"])):
        if all(curve[m][i] >= v for m, v in target.items()):
            return i
    return None


def _curve(run: Path, target: dict) -> dict | None:
    try:
        return read_curve(run, list(target))
    except CurveError:
        return None  # nothing validated yet


def result_of(curve: dict | None, target: dict, finished: bool) -> dict | None:
    """A run's result from its curve: minutes and step at the first validation reaching the
    target; when `finished` (the schedule ended) short of it, its whole time, not reached."""
    if curve is None:
        return None
    i = reached(curve, target)
    if i is None and not finished:
        return None
    k = i if i is not None else len(curve["steps"]) - 1
    return {"reached": i is not None, "minutes": round(curve["minutes"][k], 4), "step": curve["steps"][k],
            "scores": {m: round(curve[m][k], 4) for m in target}, "target": target}


def train_to_target(root: Path, run: Path, args: list[str], target: dict) -> dict:
    """Train (train.py of the tree at `root`) until the validation reaches `target` or the schedule
    ends; -> the run's result. Its log: RUN/tta_train.log."""
    run.mkdir(parents=True, exist_ok=True)
    log = open(run / "tta_train.log", "a")
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.Popen([sys.executable, "train.py", "--quiet", *args, "--out", str(run.resolve())], cwd=root, env=env,
                            stdout=log, stderr=subprocess.STDOUT)
    try:
        while proc.poll() is None:
            time.sleep(POLL_S)
            res = result_of(_curve(run, target), target, finished=False)
            if res is not None:
                proc.send_signal(signal.SIGTERM)  # train.py saves latest.pt and stops
                proc.wait()
                return res
    except BaseException:
        proc.send_signal(signal.SIGTERM)
        proc.wait()
        raise
    finally:
        log.close()
    if proc.returncode:
        tail = (run / "tta_train.log").read_text(errors="replace").strip().splitlines()[-1:] or ["(no output)"]
        raise TtaError(f"{run}: train.py of {root} exited {proc.returncode}: {tail[0][:300]}")
    res = result_of(_curve(run, target), target, finished=True)
    if res is None:
        raise TtaError(f"{run}: training ended without a validation score (train.val_every larger than the run?)")
    return res


def summary(results: dict, target: dict) -> dict:
    """{tag: {'minutes': median, 'runs', 'all_reached'}, 'ratio': head / baseline}."""
    out = {}
    for tag, runs in results.items():
        done = [r for r in runs.values() if r]
        if done:
            out[tag] = {"minutes": round(statistics.median(r["minutes"] for r in done), 2), "runs": len(done),
                        "all_reached": all(r["reached"] for r in done)}
    if "head" in out and "baseline" in out and out["baseline"]["minutes"] > 0:
        out["ratio"] = round(out["head"]["minutes"] / out["baseline"]["minutes"], 3)
    out["target"] = target
    return out


def table(results: dict, summ: dict) -> str:
    lines = ["| run | seed | minutes | step | reached | scores |", "|---|---|---|---|---|---|"]
    for tag, runs in results.items():
        for seed, r in sorted(runs.items()):
            if r:
                scores = ", ".join(f"{m} {v:.3f}" for m, v in r["scores"].items())
                lines.append(f"| {tag} | {seed} | {r['minutes']:.1f} | {r['step']} | {'yes' if r['reached'] else 'no'} | {scores} |")
    for tag in ("head", "baseline"):
        if tag in summ:
            s = summ[tag]
            lines.append(f"| {tag} median | | {s['minutes']:.1f} | | {'yes' if s['all_reached'] else 'not all (a lower bound)'} | |")
    if "ratio" in summ:
        lines.append(f"\nhead / baseline: {summ['ratio']:.3f} (goal <= 0.5)")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = ArgumentParser(prog="experiments.tta", description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="the data set both commits train on (make dataset's data/medium)")
    p.add_argument("--baseline", default=BASELINE, help=f"the commit measured against (default {BASELINE}; 'none': this checkout only)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--out", default="runs/tta", help="run folders and results (resumable)")
    p.add_argument("--target", nargs="+", default=[f"{k}={v}" for k, v in TARGET.items()], metavar="METRIC=VALUE")
    p.add_argument("--val-every", type=int, default=110, help="steps between validations (train.val_every)")
    p.add_argument("--config", default="configs/train/cpu_medium.yaml", help="each commit's own config at this path")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE", help="more config overrides (both commits)")
    a = p.parse_args(argv)
    target = parse_targets(a.target)
    data = Path(a.data).resolve()
    if not (data / "index.json").is_file():
        raise TtaError(f"--data: {a.data} is not a data set (no index.json; make dataset)")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    roots = {"head": CODE_DIR}
    if a.baseline.lower() != "none":
        src = out / f"baseline_{a.baseline}"
        if not (src / "train.py").is_file():
            checkout(a.baseline, src)
        roots["baseline"] = src.resolve()
    results: dict = {tag: {} for tag in roots}
    known_fields: dict = {}  # tag -> the meta.json fields its reader accepts (None: all), asked once
    for k, seed in enumerate(a.seeds):
        for tag in (list(roots) if k % 2 == 0 else list(roots)[::-1]):
            done = out / f"{tag}_s{seed}.json"
            if done.is_file():
                results[tag][seed] = json.loads(done.read_text())
                continue
            if not (roots[tag] / a.config).is_file():
                raise TtaError(f"--config: {a.config} is not in {tag}'s tree ({roots[tag]})")
            if tag not in known_fields:
                known_fields[tag] = meta_fields(roots[tag]) if tag != "head" else None
            known = known_fields[tag]
            extra = set(json.loads(next(data.glob("*/*/meta.json")).read_text())) - set(known or [])
            root = data_view(data, known, (out / f"data_for_{tag}").resolve()) if known and extra else data
            args = ["--config", a.config, "--set", f"data.root={root}", "--set", "data.val_split=heldout",
                    "--set", f"train.seed={seed}", "--set", f"train.val_every={a.val_every}"]
            for s in a.set:
                args += ["--set", s]
            print(f"tta: {tag} seed {seed} -> {out / f'{tag}_s{seed}'}", flush=True)
            res = train_to_target(roots[tag], out / f"{tag}_s{seed}", args, target)
            write_text_atomic(done, json.dumps(res, indent=1))
            results[tag][seed] = res
    summ = summary(results, target)
    write_text_atomic(out / "tta.json", json.dumps({"runs": {t: {str(s): r for s, r in v.items()} for t, v in results.items()},
                                                    "summary": summ}, indent=1))
    print(table(results, summ), end="")
    return 0


if __name__ == "__main__":
    run_cli(main)
