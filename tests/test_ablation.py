"""experiments.ablation end to end at a tiny scale: every row of Tables I and II trains a few
steps on real renders, is scored, lands in tables.md / tables.json, and is not rerun."""

import json
import shutil

import pytest

from experiments import ablation


@pytest.fixture
def tiny_with_test_splits(tiny_dataset, tmp_path):
    """The tiny render (train only) with its frames also listed as easy, medium and hard splits."""
    root = tmp_path / "ds"
    shutil.copytree(tiny_dataset, root)
    index = json.loads((root / "index.json").read_text())
    frames = index["splits"]["train"]
    index["splits"].update(easy=frames[:2], medium=frames[2:4], hard=frames[4:6])
    (root / "index.json").write_text(json.dumps(index))
    return root


TINY = ["data.input_size=[64, 40]", "data.grid={bound: 25.0, res: 0.78125}", "data.num_workers=0",
        "model.encoder.widths=[8, 16, 16]", "model.encoder.blocks=[1, 1]", "model.stride=8", "model.context_channels=8",
        "model.depth={min: 1.0, max: 30.0, bins: 8}", "model.bev_encoder={widths: [8, 16, 16], blocks: [1, 1]}",
        "train.batch_size=2", "train.threads=1", "augment.enabled=false"]


def runner_args(*args) -> list[str]:
    """The runner's arguments plus --quiet and the tiny model (TINY) as --set overrides."""
    return [*args, "--quiet", *[a for s in TINY for a in ("--set", s)]]


def test_every_row_trains_is_scored_and_lands_in_the_tables(tiny_with_test_splits, tmp_path):
    out = tmp_path / "ablation"
    args = runner_args("--steps", "2", "--seeds", "1", "--data", str(tiny_with_test_splits), "--out", str(out))
    assert ablation.main(args) == 0
    tables = json.loads((out / "tables.json").read_text())
    assert {r["row"] for r in tables["table_1"]} == {"ours", "rectified", "ours_scratch_trunk"}
    assert len(tables["table_1"]) == 3 * 3 and len(tables["table_2"]) == len(ablation.TABLE_II)
    for entry in tables["table_1"] + tables["table_2"]:
        mean, std, n = entry["ours"]["miou"]
        assert 0.0 <= mean <= 1.0 and n == 1 and std is None
    for row in ablation.ROWS:
        result = json.loads((out / row / "seed0" / "result.json").read_text())
        assert result["steps"] == 2 and set(result["splits"]) == {"easy", "medium", "hard"}
    ckpt_cfg = __import__("torch").load(out / "rectified" / "seed0" / "latest.pt", weights_only=False)["config"]
    assert ckpt_cfg["data"]["rectify"] == "cylindrical" and ckpt_cfg["model"]["trunk"] == "efficientnet_lite0"
    md = (out / "tables.md").read_text()
    assert "0.796" in md and "0.659" in md and "Intrinsics + embedding" in md  # the paper's numbers beside ours

    # a finished row is not rerun: its result stays byte for byte, and a second call is quick
    before = (out / "pool_max" / "seed0" / "result.json").read_bytes()
    (out / "pool_max" / "seed0" / "latest.pt").unlink()
    assert ablation.main(args) == 0
    assert (out / "pool_max" / "seed0" / "result.json").read_bytes() == before
    assert not (out / "pool_max" / "seed0" / "latest.pt").exists()

    # --report writes the tables from finished rows only, training nothing
    (out / "tables.json").unlink()
    assert ablation.main(args[:1] + ["1"] + args[2:] + ["--report", "--seeds", "2"]) == 0
    assert len(json.loads((out / "tables.json").read_text())["table_2"]) == len(ablation.TABLE_II)
    assert not (out / "ours" / "seed1").exists()


def test_bad_arguments_are_one_line_errors(tmp_path):
    import subprocess
    import sys

    from common.errors import InputError

    with pytest.raises(InputError, match="--rows: unknown row 'nope'"):
        ablation.main(["--steps", "1", "--rows", "nope", "--out", str(tmp_path / "o")])
    with pytest.raises(InputError, match="--budget-minutes"):
        ablation.main(["--budget-minutes", "0", "--out", str(tmp_path / "o")])
    for args, message in [(["--steps", "1", "--budget-minutes", "1"], "argument --budget-minutes: not allowed with argument --steps"),
                          (["--steps", "many"], "argument --steps: invalid int value: 'many'"),
                          ([], "one of the arguments --budget-minutes --steps is required")]:
        r = subprocess.run([sys.executable, "-m", "experiments.ablation", *args, "--out", str(tmp_path / "o")], capture_output=True, text=True)
        assert r.returncode == 2 and r.stderr.strip() == f"error: experiments.ablation: {message} (see --help)", r.stderr


def test_a_time_budget_trains_in_resumable_chunks(tiny_with_test_splits, tmp_path):
    out = tmp_path / "ablation"
    args = runner_args("--budget-minutes", "0.002", "--rows", "ours", "--data", str(tiny_with_test_splits), "--out", str(out))
    assert ablation.main(args) == 0
    state = json.loads((out / "ours" / "seed0" / "budget.json").read_text())
    result = json.loads((out / "ours" / "seed0" / "result.json").read_text())
    assert state["seconds"] >= 0.12 and state["step"] == result["steps"] >= 1


def test_a_split_added_later_is_scored_without_retraining(tiny_with_test_splits, tmp_path):
    out = tmp_path / "ablation"
    args = runner_args("--steps", "1", "--rows", "ours", "--data", str(tiny_with_test_splits), "--out", str(out))
    assert ablation.main(args) == 0
    run = out / "ours" / "seed0"
    assert "heldout" not in json.loads((run / "result.json").read_text())["splits"]
    assert "| heldout |" not in (out / "tables.md").read_text()
    index_path = tiny_with_test_splits / "index.json"
    index = json.loads(index_path.read_text())
    index["splits"]["heldout"] = index["splits"]["train"][6:8]
    index_path.write_text(json.dumps(index))
    trained = (run / "latest.pt").stat().st_mtime_ns
    assert ablation.main(args) == 0
    result = json.loads((run / "result.json").read_text())
    assert set(result["splits"]) == {"easy", "medium", "hard", "heldout"} and result["splits"]["heldout"]["frames"] == 2
    assert result["steps"] == 1 and (run / "latest.pt").stat().st_mtime_ns == trained
    assert "| LSS-fisheye (ours), raw fisheye | heldout |" in (out / "tables.md").read_text()
