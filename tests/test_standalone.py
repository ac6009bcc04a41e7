"""The repository stands alone: its tracked files, copied into an empty folder with nothing beside
it, pass the WoodScape and config tests, and nothing in it points outside the repository."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def tracked_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p]


def test_tracked_files_alone_pass_the_woodscape_and_config_tests(tmp_path):
    alone = tmp_path / "empty" / "repo"  # nothing beside it: no ../shared
    for rel in tracked_files():
        if (ROOT / rel).is_file():
            (alone / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, alone / rel)
    assert not (alone.parent / "shared").exists()
    tests = ["tests/test_rig.py", "tests/test_cameras.py::test_radial_poly_matches_woodscape_formula",
             "tests/test_scenes.py::test_recipe_errors_name_file_and_field", "tests/test_scenes.py::test_dataset_config_render_fields",
             "tests/test_model.py::test_every_shipped_config_validates",
             "tests/test_model.py::test_config_validation_and_train_cli_exit_code"]
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--basetemp", str(tmp_path / "bt"), *tests],
                       cwd=alone, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "skipped" not in r.stdout.splitlines()[-1]


def test_nothing_refers_outside_the_repository():
    pattern = re.compile(r"\.\./shared|DESIGN\.md|STYLE\.md")
    hits = []
    for rel in tracked_files():
        path = ROOT / rel
        if rel == "tests/test_standalone.py" or path.suffix not in (".py", ".md", ".yaml", ".yml", ".txt", ".cfg", ".toml") \
                and path.name not in ("Makefile",) and not rel.startswith(".ci/"):
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{rel}:{n}: {line.strip()[:100]}")
    assert not hits, "\n".join(hits)
