"""Confidence intervals over scenes: a bootstrap from per-scene confusion matrices.

    cms, occs = per_scene_arrays(split_result["scenes"])              # (S, K, K), (S, 2, 2)
    interval = scene_bootstrap(cms, occs, class_names)                 # key -> (low, high), 95 %
    diff = paired_bootstrap((cms_a, occs_a), (cms_b, occs_b), names)   # key -> {a, b, diff, low, high}
    row = runs_bootstrap([(cms, occs), ...], names)                    # several seeds: {mean, low, high}
    diff = paired_runs_bootstrap(runs_a, runs_b, names)                # seeds and scenes (the ablation)

Frames of one scene are not independent (same layout, same weather, 2 s apart), so the unit that
is resampled is the scene. A resample draws S scenes with replacement; its score is the protocol's
score of the sum of the drawn scenes' confusion matrices (one matrix over the whole split, as
model.metrics), so every resample is exact and costs one matrix product: the draws are kept as
counts (n, S) and the summed matrices are counts @ per-scene matrices. The interval is the
percentile one (the 2.5 % and 97.5 % quantiles of the resampled scores); the seed is fixed, so
the same scores give the same interval. Keys are those of `model.metrics.BevMetrics.compute`:
`iou/<class>`, `iou/occlusion`, `miou` (a class absent from a resample is left out of its mIoU,
and resamples where a class has no IoU are left out of that class's quantiles).
"""

from __future__ import annotations

import warnings

import numpy as np

LEVEL = 0.95
RESAMPLES = 1000


def per_scene_arrays(scenes: dict) -> tuple[np.ndarray, np.ndarray]:
    """{scene: {"confusion": KxK, "occlusion_confusion": 2x2}} -> (S, K, K), (S, 2, 2) int64, in
    sorted scene order (so two runs scored on the same scenes line up)."""
    names = sorted(scenes)
    cms = np.array([scenes[n]["confusion"] for n in names], dtype=np.int64)
    occs = np.array([scenes[n]["occlusion_confusion"] for n in names], dtype=np.int64)
    return cms, occs


def iou_batch(cm: np.ndarray) -> np.ndarray:
    """(..., K, K) confusion counts -> (..., K) IoU, NaN where a class is absent from truth and
    prediction (model.metrics.iou_from_confusion on a batch)."""
    cm = cm.astype(np.float64)
    tp = np.diagonal(cm, axis1=-2, axis2=-1)
    denom = cm.sum(-2) + cm.sum(-1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denom > 0, tp / np.maximum(denom, 1), np.nan)


def scores(cm: np.ndarray, occ: np.ndarray, class_names) -> dict[str, np.ndarray]:
    """The protocol's scores of (..., K, K) class and (..., 2, 2) occlusion confusions -> key ->
    (...) array: iou/<class> for every class but the first (invalid), iou/occlusion, miou."""
    iou = iou_batch(cm)
    out = {f"iou/{n}": iou[..., i] for i, n in enumerate(class_names) if i > 0}
    out["iou/occlusion"] = iou_batch(occ)[..., 1]
    vals = np.stack([out["iou/occlusion"]] + [out[f"iou/{n}"] for n in class_names[1:]], axis=-1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a resample where every class is absent
        out["miou"] = np.nanmean(vals, axis=-1)
    return out


def resample_counts(n_scenes: int, n: int = RESAMPLES, seed: int = 0) -> np.ndarray:
    """(n, n_scenes) int64: how often each scene is drawn in each of n resamples of n_scenes scenes
    with replacement (deterministic in `seed`)."""
    rng = np.random.default_rng([0xB0075, int(seed)])
    draws = rng.integers(0, n_scenes, size=(n, n_scenes))
    return np.stack([np.bincount(d, minlength=n_scenes) for d in draws]).astype(np.int64)


def resampled(cms: np.ndarray, occs: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The summed (n, K, K) and (n, 2, 2) confusions of the resamples `counts` (n, S)."""
    s, k = cms.shape[0], cms.shape[-1]
    return (counts @ cms.reshape(s, k * k)).reshape(-1, k, k), (counts @ occs.reshape(s, 4)).reshape(-1, 2, 2)


def percentile_interval(values: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    """(low, high) quantiles of the finite values (NaN, NaN when there are none)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return float("nan"), float("nan")
    a = (1.0 - level) / 2
    return float(np.quantile(v, a)), float(np.quantile(v, 1.0 - a))


def seed_draws(k: int, n: int = RESAMPLES, seed: int = 0) -> np.ndarray:
    """(n, k) indices: the seeds (runs) drawn with replacement in each of n resamples."""
    if k == 1:
        return np.zeros((n, 1), np.int64)
    return np.random.default_rng([0x5EED5, int(seed)]).integers(0, k, size=(n, k))


def _resampled_means(runs, class_names, counts, draws) -> dict[str, np.ndarray]:
    """key -> (n,): per resample, the mean over the drawn runs of each run's score on the drawn
    scenes (`counts`, the same scenes for every run)."""
    per = [scores(*resampled(np.asarray(c, np.int64), np.asarray(o, np.int64), counts), class_names) for c, o in runs]
    rows = np.arange(counts.shape[0])[:, None]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return {key: np.nanmean(np.stack([p[key] for p in per])[draws, rows], axis=1) for key in per[0]}


def _point(runs, class_names) -> dict[str, float]:
    """key -> the mean over runs of each run's score on all its scenes."""
    per = [scores(np.asarray(c, np.int64).sum(0), np.asarray(o, np.int64).sum(0), class_names) for c, o in runs]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return {key: float(np.nanmean([p[key] for p in per])) for key in per[0]}


def _check_same_scenes(runs) -> None:
    shapes = {(np.shape(c), np.shape(o)) for c, o in runs}
    if len(shapes) != 1:
        raise ValueError(f"bootstrap: the runs are not scored on the same scenes (confusion shapes {sorted(shapes)})")


def scene_bootstrap(cms, occs, class_names, n: int = RESAMPLES, seed: int = 0, level: float = LEVEL) -> dict[str, tuple[float, float]]:
    """key -> (low, high): the `level` interval of each score over resamples of the scenes.
    cms (S, K, K) and occs (S, 2, 2): one confusion pair per scene."""
    iv = runs_bootstrap([(cms, occs)], class_names, n, seed, level)
    return {key: (v["low"], v["high"]) for key, v in iv.items()}


def runs_bootstrap(runs, class_names, n: int = RESAMPLES, seed: int = 0, level: float = LEVEL) -> dict[str, dict]:
    """Several runs (seeds) of one model scored on the same scenes: runs = [(cms, occs), ...].
    -> key -> {"mean" (over runs), "low", "high"}: each resample draws the scenes (the same for
    every run) and the runs, both with replacement, and takes the mean over the drawn runs."""
    _check_same_scenes(runs)
    counts = resample_counts(len(runs[0][0]), n, seed)
    vals = _resampled_means(runs, class_names, counts, seed_draws(len(runs), n, seed))
    point = _point(runs, class_names)
    return {key: dict(zip(("mean", "low", "high"), (point[key], *percentile_interval(v, level)))) for key, v in vals.items()}


def paired_bootstrap(a, b, class_names, n: int = RESAMPLES, seed: int = 0, level: float = LEVEL) -> dict[str, dict]:
    """Score of A minus score of B on the same scenes: a = (cms, occs), b likewise, scene i of
    both the same scene. -> key -> {"a", "b", "diff", "low", "high"}. Identical inputs give diff
    0 and the interval [0, 0]."""
    return paired_runs_bootstrap([a], [b], class_names, n, seed, level)


def paired_runs_bootstrap(runs_a, runs_b, class_names, n: int = RESAMPLES, seed: int = 0, level: float = LEVEL,
                          paired_seeds: bool = False) -> dict[str, dict]:
    """Mean over A's runs minus mean over B's runs (seeds), every run scored on the same scenes.
    Each resample draws one set of scenes for both (paired over scenes) and A's and B's runs:
    independently, or with `paired_seeds` (run i of A and of B trained from the same seed: the same
    data order, augmentation and initial state, so they share that seed's luck) the same runs for
    both. -> key -> {"a", "b", "diff", "low", "high"}."""
    _check_same_scenes([*runs_a, *runs_b])
    if paired_seeds and len(runs_a) != len(runs_b):
        raise ValueError(f"paired seeds need as many runs of A as of B, got {len(runs_a)} and {len(runs_b)}")
    counts = resample_counts(len(runs_a[0][0]), n, seed)
    va = _resampled_means(runs_a, class_names, counts, seed_draws(len(runs_a), n, seed))
    vb = _resampled_means(runs_b, class_names, counts, seed_draws(len(runs_b), n, seed if paired_seeds else seed + 1))
    pa, pb = _point(runs_a, class_names), _point(runs_b, class_names)
    out = {}
    for key in va:
        low, high = percentile_interval(va[key] - vb[key], level)
        out[key] = {"a": pa[key], "b": pb[key], "diff": pa[key] - pb[key], "low": low, "high": high}
    return out
