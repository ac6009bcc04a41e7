"""TensorBoard logging that fails loudly: a write error (a full disk) is one OSError naming the
log folder, raised by the next call on the writer (common.cli prints it as one line, exit 1),
never a traceback printed by TensorBoard's writer thread.

    writer = TensorBoardLog(run_dir.tb)     # SummaryWriter's methods: add_scalar, add_image, close, ...
"""

from __future__ import annotations

import threading
from pathlib import Path

_hook_installed = False


def _quiet_writer_threads() -> None:
    """TensorBoard's writer thread re-raises its error (Python then prints it); the writer's next
    call raises it again in the main thread, where it is reported once."""
    global _hook_installed
    if _hook_installed:
        return
    previous = threading.excepthook

    def hook(args):
        if type(args.thread).__name__ == "_AsyncWriterThread" and issubclass(args.exc_type, OSError):
            return
        previous(args)

    threading.excepthook = hook
    _hook_installed = True


class TensorBoardLog:
    """A SummaryWriter on `folder` whose OSErrors name the folder."""

    def __init__(self, folder):
        from torch.utils.tensorboard import SummaryWriter

        _quiet_writer_threads()
        self.folder = Path(folder)
        self._writer = self._named(SummaryWriter)(str(self.folder))

    def _named(self, fn):
        def call(*args, **kwargs):
            try:
                return fn(*args, **kwargs)
            except OSError as exc:
                raise OSError(exc.errno, exc.strerror or str(exc), str(self.folder)) from None
        return call

    def __getattr__(self, name):
        attr = getattr(self._writer, name)
        return self._named(attr) if callable(attr) else attr
