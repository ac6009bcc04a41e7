"""common.lifetime's guard: what a command started dies with it on `kill -9`, also a process that a
known child starts later and that lacks the command's mark (Ray's raylet starts its agents after it
appeared, and their setproctitle hides the mark: docs/errors.md)."""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.lifetime import OWNER_ENV
from test_robustness import alive

ROOT = Path(__file__).resolve().parents[1]

COMMAND = r"""
import subprocess, sys, time
from common.lifetime import OWNER_ENV, guard_descendants

guard_descendants()
late = f"sleep 1; env -u {OWNER_ENV} sleep 300 & echo $!; wait"  # a grandchild, 1 s after its parent
child = subprocess.Popen(["sh", "-c", late], stdout=subprocess.PIPE, text=True)
print(child.stdout.readline().strip(), flush=True)
time.sleep(300)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the guard is Linux only")
def test_guard_kills_an_unmarked_grandchild_started_after_its_parent_was_seen():
    env = {k: v for k, v in os.environ.items() if k != OWNER_ENV}
    p = subprocess.Popen([sys.executable, "-c", COMMAND], cwd=ROOT, env=dict(env, PYTHONPATH=str(ROOT)),
                         stdout=subprocess.PIPE, text=True)
    grandchild = int(p.stdout.readline())
    deadline = time.monotonic() + 5
    while not Path(f"/proc/{grandchild}/cmdline").read_bytes().startswith(b"sleep") and time.monotonic() < deadline:
        time.sleep(0.01)  # until `env` has exec'd sleep: the forked shell still has the mark
    assert OWNER_ENV.encode() not in Path(f"/proc/{grandchild}/environ").read_bytes()
    time.sleep(0.6)  # the guard walks the tree every 0.2 s
    p.kill()
    p.wait()
    deadline = time.monotonic() + 5
    while alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)
    survived = alive(grandchild)
    if survived:
        os.kill(grandchild, 9)
    assert not survived, "a process started by a known child, without the mark, outlived the command by 5 s"
