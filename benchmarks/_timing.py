"""Shared timing helpers for the benchmark scripts (import after setting thread env vars)."""

from __future__ import annotations

import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")


def per_call(fn, *, min_time: float = 0.3, repeat: int = 5) -> float:
    """Best-of-`repeat` mean seconds per call of fn() (each repeat runs >= min_time)."""
    fn()  # warm-up (compilation, caches)
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_time / 4:
            break
        n *= 4
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def once(fn, *, repeat: int = 3) -> float:
    """Best-of-`repeat` seconds of one call of fn() after a warm-up call."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def table(title: str, rows: list[tuple[str, float, str, float]]) -> None:
    """Print rows of (rovlab case, seconds, peer case, seconds) with the speed-up ratio."""
    print(f"\n== {title} ==")
    print(f"{'rovlab':44s} {'time':>10s}   {'peer':44s} {'time':>10s}  {'speed-up':>8s}")
    for ours, t_ours, peer, t_peer in rows:
        print(f"{ours:44s} {_fmt(t_ours):>10s}   {peer:44s} {_fmt(t_peer):>10s}  {t_peer / t_ours:7.1f}x")


def _fmt(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.2f} us"
    if seconds < 1:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds:.2f} s"
