"""The one place that knows where the toolkit's own files are: presets (configs/), scene recipes
(scenes/), rigs, and the folder holding the packages (the Blender worker's and Ray's code).

    CODE_DIR                        the folder holding common/, geometry/, ... (the checkout, or site-packages)
    shipped("configs/rigs/default.yaml")  a file the toolkit ships
    preset("tiny", "dataset")       configs/dataset/tiny.yaml (a name, or a path as given)
    resolve_input(path, base)       a path a user gave: as given (from the working folder), else
                                    beside `base` (the file that names it), else a shipped file
    checkout(commit, dest)          the tree of another commit of this checkout (benches' baselines)

In a checkout (or an editable install) the shipped files are the checkout's `configs/` and
`scenes/`; an installed wheel carries them as package data of `fisheye_bev_data` (pyproject.toml),
so the commands work from any folder. Paths a user passes are always tried first as given,
against the working folder.
"""

from __future__ import annotations

import importlib.util
import subprocess
from pathlib import Path

from .errors import ConfigError

CODE_DIR = Path(__file__).resolve().parents[1]
DATA_PACKAGE = "fisheye_bev_data"  # the wheel's copy of configs/ and scenes/
SHIPPED = ("configs", "scenes")


def data_root() -> Path:
    """The folder holding configs/ and scenes/: the checkout's, else the installed package data's."""
    if all((CODE_DIR / d).is_dir() for d in SHIPPED):
        return CODE_DIR
    spec = importlib.util.find_spec(DATA_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(f"the toolkit's presets are missing: no {', '.join(SHIPPED)} in {CODE_DIR} and no package "
                          f"{DATA_PACKAGE} (reinstall: pip install fisheye-bev)")
    return Path(list(spec.submodule_search_locations)[0])


def shipped(path) -> Path:
    """A file or folder the toolkit ships, by its path in the repository (`configs/...`, `scenes/...`)."""
    return data_root() / Path(path)


def resolve_input(path, base: Path | None = None) -> Path:
    """A path a user gave: as given when absolute or found from the working folder, else beside
    `base`, else the shipped file of that path when there is one; else as given (so a message
    names what the user wrote)."""
    p = Path(path)
    if p.is_absolute() or p.exists():
        return p
    if base is not None and (Path(base) / p).exists():
        return Path(base) / p
    s = shipped(p)
    return s if s.exists() else p


def preset(name_or_path, kind: str) -> Path:
    """A config named by a preset name (`tiny` -> configs/<kind>/tiny.yaml) or a path (resolve_input)."""
    p = Path(str(name_or_path))
    if p.suffix == "" and len(p.parts) == 1 and not p.exists():
        s = shipped(Path("configs") / kind / f"{p.name}.yaml")
        if s.is_file():
            return s
    return resolve_input(p)


def dataset_config(text) -> Path:
    """--config of the dataset commands: a path, or a preset's name (`tiny`: configs/dataset/tiny.yaml)."""
    return preset(text, "dataset")


def presets(kind: str) -> list[str]:
    """The names of the shipped presets of a kind (dataset, train, rigs)."""
    return sorted(f.stem for f in shipped(Path("configs") / kind).glob("*.yaml"))


def checkout(commit: str, dest: Path) -> Path:
    """The tree of `commit` (of this checkout's repository) written to dest (git archive: no
    worktree to clean up); RuntimeError naming the commit if git cannot."""
    dest.mkdir(parents=True, exist_ok=True)
    try:
        archive = subprocess.run(["git", "-C", str(CODE_DIR), "archive", commit], capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        err = exc.stderr.decode().strip()[:200] if isinstance(exc, subprocess.CalledProcessError) else str(exc)
        raise RuntimeError(f"baseline: git archive {commit} failed: {err}") from None
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest
