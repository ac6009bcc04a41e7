"""The boundary between the render driver (dataset_tools.generation.driver) and a Blender worker
process (`python -m blender_scripts.worker`): the one module both sides import.

    driver -> worker, stdin:  one RenderTask per line (RenderTask.to_line / RenderTask.from_line)
    worker -> driver, stdout: message_line(event=..., ...): MARK + a JSON object, one per line;
                              events "ready", "frame" (scene, frame, files, timings), "task_done",
                              "error" (message, trace)

Blender prints its own progress on stdout too: read_message returns None for every line that does
not start with MARK. Standard library only, so Blender's Python can import it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace

MARK = "@@bev "


@dataclass(frozen=True)
class RenderTask:
    """Frames of one scene for one worker. `topdown` and `render` are the dataset config's
    sections as its schema filled them in (every field present, defaults included)."""

    scene: str
    split: str
    recipe: dict
    frames: list
    out: str  # the data set folder, absolute
    rig: str
    fisheye_size: list | None
    topdown: dict
    render: dict
    threads: int
    losses: int = 0  # how often a worker was lost on this task (the driver gives up at MAX_LOSSES)

    def to_line(self) -> str:
        return json.dumps(asdict(self)) + "\n"

    @classmethod
    def from_line(cls, line: str) -> RenderTask:
        return cls(**json.loads(line))

    def retry(self, frames: list) -> RenderTask:
        """This task again for `frames` (the ones a lost worker did not finish)."""
        return replace(self, frames=list(frames), losses=self.losses + 1)


def message_line(**msg) -> str:
    return MARK + json.dumps(msg) + "\n"


def read_message(line: str) -> dict | None:
    """The message of a protocol line; None for any other line; ValueError for a garbled one."""
    if not line.startswith(MARK):
        return None
    msg = json.loads(line[len(MARK):])
    if not isinstance(msg, dict) or "event" not in msg:
        raise ValueError("not a protocol message")
    return msg
