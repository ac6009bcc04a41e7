"""One writer per output folder: `with hold_lock(folder): ...`.

The lock is `<folder>/.lock`, held with flock(2) for the life of the process (so a process killed
with -9 releases it at once) and naming its holder (`pid host`) for the message a second writer
gets. A lock file left by a dead process is simply taken over.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import socket
from pathlib import Path

LOCK_NAME = ".lock"


def holder(path) -> str:
    """'pid N on host H' as the lock file says (or 'another process' when it cannot be read)."""
    try:
        pid, host = Path(path).read_text().split()[:2]
        return f"pid {int(pid)} on {host}"
    except (OSError, ValueError):
        return "another process"


@contextlib.contextmanager
def hold_lock(folder):
    """Hold `<folder>/.lock` for the block (the folder is created); a second holder gets an
    OSError (EBUSY) naming the lock file and the holder: the CLI boundary prints one line, exit 1."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OSError(errno.EBUSY, f"in use by {holder(path)} (one writer at a time; wait for it to finish)", str(path)) from None
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:  # else the holder removed the file between our open and flock: try again
            break
        os.close(fd)
    try:
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
        except OSError as exc:  # a full disk: the run could not write anything either
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)
