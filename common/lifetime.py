"""Child processes die with their parent: a `kill -9` of a command leaves no worker running.

    Popen(..., preexec_fn=DieWithParent())                  # a worker process (run before exec)
    ProcessPoolExecutor(..., initializer=...)               # common.backend's local pool calls it
    DataLoader(..., worker_init_fn=LoaderWorker())          # torch data loader workers

On Linux the child asks the kernel for SIGKILL when its parent dies (prctl PR_SET_PDEATHSIG), then
checks that the parent it was started by is still its parent (it may have died before the call).
Elsewhere a daemon thread polls os.getppid(). Construct `DieWithParent()` in the parent: it
remembers the parent's pid, and it pickles (spawned pool processes, loader workers).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1
POLL_S = 0.2  # the fallback watchdog's period


_LIBC = None


def _libc():
    """libc through ctypes, loaded once (in the parent: a forked child should not dlopen)."""
    global _LIBC
    if _LIBC is None and sys.platform.startswith("linux"):
        try:
            import ctypes

            _LIBC = ctypes.CDLL(None, use_errno=True)
        except OSError:
            _LIBC = False
    return _LIBC or None


def _pdeathsig() -> bool:
    libc = _libc()
    try:
        return libc is not None and libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL) == 0
    except AttributeError:
        return False


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(POLL_S)
    os._exit(1)


def die_with_parent(parent: int) -> None:
    """In a child of `parent` (a pid): end this process when `parent` ends."""
    if not _pdeathsig():
        threading.Thread(target=_watch, args=(parent,), daemon=True, name="die-with-parent").start()
    if os.getppid() != parent:  # the parent died before the kernel was told
        os._exit(1)


class DieWithParent:
    """`die_with_parent(<the pid of the process that made this object>)`, as a callable that takes
    and ignores any arguments (a preexec_fn, a pool initializer, a worker_init_fn)."""

    def __init__(self):
        self.parent = os.getpid()
        _libc()

    def __call__(self, *_args) -> None:
        die_with_parent(self.parent)


class LoaderWorker(DieWithParent):
    """DieWithParent for torch DataLoader workers, which also leave SIGINT and SIGTERM to their
    parent: a signal to the whole process group (Ctrl-C, `timeout`, a scheduler's stop) then reaches
    the training loop's graceful stop alone, which finishes the step and saves, instead of racing a
    worker's death ("DataLoader worker killed by signal: Terminated"). The parent ends its workers."""

    def __call__(self, *_args) -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        super().__call__()


OWNER_ENV = "FISHEYE_BEV_OWNER"  # marks every process a command's local Ray instance starts
_GUARD = r"""
import os, select, signal, sys, time
mark, parent, me = sys.argv[1].encode(), int(sys.argv[2]), os.getpid()

def started(pid):  # its start time, None once it is gone (or a zombie)
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return None if fields[0] == "Z" else fields[19]
    except (OSError, IndexError):
        return None

def children(pid):
    out = []
    try:
        for t in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{t}/children") as f:
                out += [int(c) for c in f.read().split()]
    except OSError:
        pass
    return out

def marked():
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/environ", "rb") as f:
                    if mark in f.read().split(b"\0"):
                        yield int(d)
            except OSError:
                pass

known = {}
while True:  # until end of file: the command has ended (or was killed); meanwhile note its descendants
    ready = select.select([0], [], [], 0.2)[0]
    if ready and not os.read(0, 4096):
        break
    # the whole tree every time: a known process (Ray's raylet) starts children (its agents) later
    todo, seen = [parent], set()
    while todo:
        for c in children(todo.pop()):
            if c != me and c not in seen:
                seen.add(c)
                known[c] = started(c)
                todo.append(c)

# Kill until a whole second has passed with nothing left to kill (8 s at most): a marked process forked
# just as its parent was killed can show up in /proc after a scan that found nothing, so one empty scan
# is not the end. (The DashboardAgent that once outlived the guard was missed by the walk above, not by
# this loop: docs/errors.md.)
end, quiet_since = time.time() + 8, None
while time.time() < end:
    pids = [p for p, t in known.items() if t is not None and started(p) == t]
    pids += [p for p in marked() if p != me and started(p) is not None]
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    known = {p: t for p, t in known.items() if started(p) == t}
    if pids:
        quiet_since = None
    elif quiet_since is None:
        quiet_since = time.time()
    elif time.time() - quiet_since >= 1.0:
        break
    time.sleep(0.05)
"""


def guard_descendants() -> None:
    """Start a guard that, once this command ends however it ends, kills every process the command
    started from now on: the descendants it saw (it looks every 0.2 s) and those that inherited a
    mark in their environment. For services that outlive their parent by design (a local Ray
    instance's workers and agents are children of its raylet, not of the command); Linux only."""
    import subprocess
    import uuid

    if not sys.platform.startswith("linux") or OWNER_ENV in os.environ:
        return
    mark = f"{OWNER_ENV}={os.getpid()}-{uuid.uuid4().hex}"
    env = {k: v for k, v in os.environ.items() if k != OWNER_ENV}
    guard = subprocess.Popen([sys.executable, "-c", _GUARD, mark, str(os.getpid())], stdin=subprocess.PIPE, env=env,
                             start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _GUARDS.append(guard)  # its stdin stays open (the pipe closes when this process ends)
    os.environ[OWNER_ENV] = mark.split("=", 1)[1]


_GUARDS: list = []
