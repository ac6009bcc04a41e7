"""Everything between renders and training, by stage:

- `generation/`: dataset configs, scene recipes and the render driver (`python -m dataset_tools generate`)
- `format/`: the on-disk layout of a data set (`layout`), EXR/PNG I/O, the index and the reader
- `labels/`: fine classes, visibility p(o) and label fusion (`python -m dataset_tools fuse`)
- `qa/`: validate, inspect, consistency, stats, contact sheets, the audit and the HTML report
- `pipeline`: the stage order (render, contact sheets, fuse, audit, report; `python -m dataset_tools dataset`)

Every command is `python -m dataset_tools <command>`, from the one table in `__main__.py`; the
modules at this level (generate, fuse, merge, index) are the commands that are not QA tools.

    from dataset_tools import DatasetIndex, read_frame
    idx = DatasetIndex("data/small"); f = read_frame(idx.frames("train")[0])
"""

from .format.labels import read_labels
from .format.layout import SPLITS, DatasetError, FrameFiles, Manifest
from .format.reader import DatasetIndex, FrameRef, downsample_labels, read_frame
from .labels.classes import TRAIN_CLASSES, TRAIN_PALETTE, colorize, colorize_train

__all__ = ["DatasetIndex", "FrameRef", "read_frame", "read_labels", "downsample_labels", "DatasetError",
           "FrameFiles", "Manifest", "SPLITS", "TRAIN_CLASSES", "TRAIN_PALETTE", "colorize", "colorize_train"]
