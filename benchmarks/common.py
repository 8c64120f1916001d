"""What the benchmark scripts share: paths, the median ± half-range summary, relMSE.
(Scripts run as `python benchmarks/NAME.py`, so this imports as `common`.)"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
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


def write_results(stem: str, data: dict, lines: list[str]) -> None:
    """docs/benchmarks/<stem>.json (the numbers) and <stem>.md (the report, also printed)."""
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"{stem}.json").write_text(json.dumps(data, indent=2) + "\n")
    (OUT / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


class WarmChild:
    """A Python child process (`python -c script core`) kept warm across measurements: each
    request is one line on its stdin, each answer one JSON line on its stdout. `core` is a
    `_core*.so` of another build to load in place of this tree's (LOAD_CORE), or ""."""

    def __init__(self, script: str, core: str = ""):
        self.p = subprocess.Popen([sys.executable, "-c", script, core], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, cwd=REPO,
                                  env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})

    def ask(self, *words) -> dict:
        self.p.stdin.write(" ".join(str(w) for w in words) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise RuntimeError("the benchmark's child process died (its error is above)")
        return json.loads(line)

    def close(self) -> None:
        self.p.stdin.close()
        self.p.wait()


# One definition of relMSE for the scripts here and `tessera bench` (tessera/tessera_tools/bench_stats.py).
from tessera_tools.bench_stats import rel_mse  # noqa: E402,F401
