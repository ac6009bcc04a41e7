"""bench.model's baseline comparison: a commit's tree written aside and measured in
fresh processes with its own code."""

import subprocess

import pytest

from bench import model as bm


def head_commit() -> str:
    return subprocess.run(["git", "-C", str(bm.ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()


def test_checkout_writes_the_commits_tree_and_runs_its_code(tmp_path, monkeypatch):
    root = bm.checkout(head_commit(), tmp_path / "base")
    assert (root / "bench" / "model.py").is_file() and (root / "model" / "lss.py").is_file()
    assert not (root / ".git").exists()
    # a child runs the checkout's code, not this one's: mark the copy and ask it
    (root / "bench" / "model.py").write_text((root / "bench" / "model.py").read_text() + "\ndef _whoami():\n    return {'root': str(ROOT)}\n")
    assert bm._in_child("_whoami", root=root) == {"root": str(root)}


def test_versus_pairs_the_two_checkouts_and_takes_the_median_ratio(tmp_path, monkeypatch):
    calls = []

    def fake(fn, *args, root, env=None):
        calls.append(root)
        return {"x": 2.0 if root == bm.ROOT else 4.0, "x_peak_rss_mb": 1.0}

    monkeypatch.setattr(bm, "_in_child", fake)
    out = bm.versus([("_child_train", "data", 1)], tmp_path, rounds=2)
    assert calls == [bm.ROOT, tmp_path, tmp_path, bm.ROOT]  # ABBA
    assert out == {"x": 2.0, "x_baseline": 4.0, "x_ratio": 0.5, "x_peak_rss_mb": 1.0}


def test_an_unknown_baseline_is_one_line(tmp_path):
    with pytest.raises(RuntimeError, match="baseline: git archive nosuchcommit"):
        bm.checkout("nosuchcommit", tmp_path / "b")


def test_precision_versus_pairs_fp32_and_bf16_of_this_checkout(monkeypatch):
    calls = []

    def fake(fn, *args, root=bm.ROOT, env=None):
        calls.append(args[-1])
        return {"x" + ("" if args[-1] == "fp32" else "_bf16"): 4.0 if args[-1] == "fp32" else 3.0, "x_peak_rss_mb": 1.0}

    monkeypatch.setattr(bm, "_in_child", fake)
    out = bm.precision_versus([("_child_infer", 5, "scratch")], rounds=2)
    assert calls == ["fp32", "bf16", "bf16", "fp32"]
    assert out == {"x_bf16": 3.0, "x_bf16_vs_fp32": 0.75}


def test_a_bf16_inference_child_runs_for_real():
    out = bm._in_child("_child_infer", 2, "scratch", "bf16")
    assert out["infer_ms_per_frame_bf16"] > 0 and out["infer_peak_rss_mb_bf16"] > 0
