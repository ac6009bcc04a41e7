"""`make demo`: the whole chain on a small default, each step with its own progress bar.

    generate a small data set (configs/dataset/demo.yaml)  ->  data/demo
    fuse its BEV labels                                     ->  data/demo/<scene>/<frame>/labels
    train briefly (configs/train/demo.yaml)                 ->  runs/demo
    evaluate on every split                                 ->  runs/demo/eval

Every step resumes: run it again after an interruption and finished work is skipped.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

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
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data/demo")
    p.add_argument("--run", default="runs/demo")
    p.add_argument("--dataset-config", default="configs/dataset/demo.yaml")
    p.add_argument("--train-config", default="configs/train/demo.yaml")
    a = p.parse_args(argv)
    py = sys.executable
    t0 = time.time()
    step("1/4 render the scenes in Blender", [py, "-m", "dataset_tools.generate", "--config", a.dataset_config, "--out", a.data])
    step("2/4 fuse occlusion-corrected BEV labels", [py, "-m", "dataset_tools.fuse", a.data, "--config", a.dataset_config])
    step("3/4 train the LSS-fisheye model", [py, "train.py", "--config", a.train_config, "--out", a.run, "--set", f"data.root={a.data}"])
    run = RunDir(a.run)
    ckpt, out = run.latest, run.eval
    step("4/4 evaluate on every split", [py, "eval.py", "--checkpoint", str(ckpt), "--split", "all", "--out", str(out)])
    print(f"\ndemo finished in {(time.time() - t0) / 60:.1f} min")
    print(f"  data set and contact sheets: {a.data}/  (label QA: python -m dataset_tools.inspect {a.data}/<scene>/<frame>)")
    print(f"  checkpoint:                  {ckpt}  (TensorBoard: tensorboard --logdir {run.tb})")
    print(f"  tables:                      {out.table}, {out.metrics}")
    print(f"  pictures:                    {out}/{out.FRAME_GLOB}, {out}/{out.CONFUSION_GLOB}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
