"""The trade-off's Pareto front and the recommendation for a target frame time.

A point is on the front of its resolution when no other point there is at least as fast and at least as
accurate (PSNR against the reference), and strictly better in one of the two.
"""

from __future__ import annotations


def pareto_front(points: list[dict]) -> list[str]:
    """Labels of the points no other point dominates in (seconds_per_frame lower, psnr higher), fastest first."""
    ranked = sorted(points, key=lambda p: (p["seconds_per_frame"], -p["psnr"]))
    front, best = [], float("-inf")
    for p in ranked:
        if p["psnr"] > best:
            front.append(p["label"])
            best = p["psnr"]
    return front


def recommend(points: list[dict], target_ms: float) -> dict | None:
    """The most accurate bundle within ``target_ms`` per frame (None when no bundle is that fast)."""
    fits = [p for p in points if p["kind"] == "bundle" and 1000.0 * p["seconds_per_frame"] <= target_ms]
    return max(fits, key=lambda p: p["psnr"]) if fits else None
