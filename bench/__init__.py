"""`make bench`: see bench/run.py."""

import time


def best_of(fn, repeat: int = 5) -> float:
    """Fastest of `repeat` wall-clock timings of fn(), in seconds (the least disturbed run)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
