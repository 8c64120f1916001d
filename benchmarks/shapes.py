"""Geometry the benchmark scripts build in their child processes. numpy only, so that a
child can import it whichever renderer package it loads (the scripts put this folder on
the child's PYTHONPATH)."""
from __future__ import annotations

import numpy as np


def wavy_grid(q: int = 224, phase: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A q x q quad grid over [-1, 1]^2 in x and z, rippled in y by
    0.1 sin(6 x + phase) cos(5 z): 2 q^2 triangles (100,352 for q = 224). Returns points
    (V, 3) float32 and triangles (T, 3) uint32; the triangles do not depend on the phase."""
    xs = np.linspace(-1, 1, q + 1, dtype=np.float32)
    x, z = np.meshgrid(xs, xs)
    y = 0.1 * np.sin(6 * x + phase) * np.cos(5 * z)
    pts = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    i = np.arange(q)[None, :] + (q + 1) * np.arange(q)[:, None]
    a, b, c, d = i, i + 1, i + q + 2, i + q + 1
    tris = np.concatenate([np.stack([a, d, c], -1), np.stack([a, c, b], -1)], 0).reshape(-1, 3).astype(np.uint32)
    return pts, tris


def child_env() -> dict:
    """The environment of a benchmark's child process: this folder importable, and one
    BLAS thread (numpy's idle OpenBLAS workers otherwise spin beside the renderer)."""
    import os
    from pathlib import Path

    here = str(Path(__file__).resolve().parent)
    path = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": here if not path else f"{here}{os.pathsep}{path}",
            "OPENBLAS_NUM_THREADS": "1"}
