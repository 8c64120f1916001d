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


# The first lines of a benchmark's child process (`python -c`): argv[1], when not empty, is
# the path of another build's `_core*.so`, loaded in place of this tree's so that two
# builds are timed side by side in one run.
LOAD_CORE = r"""
import importlib.util, sys
if sys.argv[1]:
    _spec = importlib.util.spec_from_file_location("tessera_renderer._core", sys.argv[1])
    _mod = importlib.util.module_from_spec(_spec); sys.modules["tessera_renderer._core"] = _mod
    _spec.loader.exec_module(_mod)
"""


# One definition of relMSE for the scripts here and `tessera bench` (tessera/tessera_tools/bench_stats.py).
from tessera_tools.bench_stats import rel_mse  # noqa: E402,F401
