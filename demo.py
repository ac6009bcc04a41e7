"""`make demo`: the whole chain on a small default, each step with its own progress bar.

    build a small data set (configs/dataset/demo.yaml)     ->  data/demo
      (python -m dataset_tools dataset: render, fuse its BEV labels, audit, QA report)
    train briefly (configs/train/demo.yaml)                 ->  runs/demo
    evaluate on every split                                 ->  runs/demo/eval

Every step resumes: run it again after an interruption and finished work is skipped.
"""

from __future__ import annotations

import subprocess
import sys
import time

from common.cli import ArgumentParser, run_cli
from model.run_dir import RunDir


def step(title: str, cmd: list[str]) -> None:
    print(f"\n=== {title}\n$ {' '.join(cmd)}", flush=True)
    t0 = time.time()
    rc = subprocess.call(cmd)
    if rc != 0:
        print(f"demo: step '{title}' failed (exit {rc}); fix the above and run `make demo` again to resume", file=sys.stderr)
        sys.exit(rc)
    print(f"=== {title}: done in {time.time() - t0:.0f} s", flush=True)


def main(argv=None) -> int:
    p = ArgumentParser(prog="demo.py", description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data/demo")
    p.add_argument("--run", default="runs/demo")
    p.add_argument("--dataset-config", default="configs/dataset/demo.yaml")
    p.add_argument("--train-config", default="configs/train/demo.yaml")
    a = p.parse_args(argv)
    py = sys.executable
    t0 = time.time()
    step("1/3 build the data set: render in Blender, fuse occlusion-corrected BEV labels, audit, report",
         [py, "-m", "dataset_tools", "dataset", "--config", a.dataset_config, "--out", a.data])
    step("2/3 train the LSS-fisheye model", [py, "train.py", "--config", a.train_config, "--out", a.run, "--set", f"data.root={a.data}"])
    run = RunDir(a.run)
    ckpt, out = run.latest, run.eval
    step("3/3 evaluate on every split", [py, "eval.py", "--checkpoint", str(ckpt), "--split", "all", "--out", str(out)])
    print(f"\ndemo finished in {(time.time() - t0) / 60:.1f} min")
    print(f"  data set and contact sheets: {a.data}/  (label QA report: {a.data}/report/index.html)")
    print(f"  checkpoint:                  {ckpt}  (TensorBoard: tensorboard --logdir {run.tb})")
    print(f"  tables:                      {out.table}, {out.metrics}")
    print(f"  pictures:                    {out}/{out.FRAME_GLOB}, {out}/{out.CONFUSION_GLOB}")
    return 0


if __name__ == "__main__":
    run_cli(main, prog="demo.py")
