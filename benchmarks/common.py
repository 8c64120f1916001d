"""What the benchmark scripts share: paths, the median ± half-range summary, relMSE.
(Scripts run as `python benchmarks/NAME.py`, so this imports as `common`.)"""
from __future__ import annotations

import statistics
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CORNELL = REPO / "examples" / "cornell" / "cornell.usda"
OUT = REPO / "docs" / "benchmarks"


def summary(values: list[float]) -> dict:
    """Median with the half-range (min..max) as its error."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "half_range": (max(values) - min(values)) / 2, "n": len(values), "values": values}


def fmt(s: dict, unit: str = "", digits: int = 3) -> str:
    return (f"{s['median']:.{digits}g}{unit} ± {s['half_range']:.2g}{unit} "
            f"(n={s['n']}, range {s['min']:.{digits}g}–{s['max']:.{digits}g})")


def rel_mse(img: np.ndarray, ref: np.ndarray) -> float:
    """Mean over pixels and channels of (x - ref)^2 / (ref^2 + 1e-2)."""
    x, r = img[..., :3].astype(np.float64), ref[..., :3].astype(np.float64)
    return float(np.mean((x - r) ** 2 / (r * r + 1e-2)))
