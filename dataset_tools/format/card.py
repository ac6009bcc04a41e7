"""`<dataset>/README.md` and `<export>/README.md`: the dataset card, YAML front matter in the
Hugging Face dataset-card format followed by Markdown. One writer (`write_card`) and reader
(`read_card`); what goes into a card is dataset_tools.card's.

    ---
    license: cc-by-4.0
    task_categories: [image-segmentation]
    size_categories: [n<1K]
    dataset_info: {splits: [{name: train, num_examples: 28}, ...]}
    ...
    ---
    # <name>
    ...
"""

from __future__ import annotations

from pathlib import Path

import yaml

from common.files import parse_yaml, read_text, write_text_atomic

from .layout import CARD, DatasetError


def render_card(front: dict, body: str) -> str:
    return "---\n" + yaml.safe_dump(front, sort_keys=False, allow_unicode=True, width=120) + "---\n\n" + body.rstrip() + "\n"


def write_card(root, front: dict, body: str) -> Path:
    path = Path(root) / CARD
    write_text_atomic(path, render_card(front, body))
    return path


def read_card(root) -> tuple[dict, str]:
    """(front matter, Markdown body) of `<root>/README.md` (or the file itself); one DatasetError
    line for a missing file, no front matter or front matter that is not a YAML mapping."""
    path = Path(root)
    if path.is_dir():
        path = path / CARD
    text = read_text(path, DatasetError)
    if not text.startswith("---\n") or "\n---\n" not in text[3:]:
        raise DatasetError(f"{path}: no YAML front matter (a card starts with a '---' block)")
    head, body = text[4:].split("\n---\n", 1)
    try:
        front = parse_yaml(head)
    except yaml.YAMLError as exc:
        raise DatasetError(f"{path}: front matter is not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(front, dict):
        raise DatasetError(f"{path}: front matter must be a YAML mapping")
    return front, body.lstrip("\n")
