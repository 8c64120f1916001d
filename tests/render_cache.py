"""Renders the statistical tests need many of, cached on disk across runs (issue 47, item 7:
"cache expensive references keyed by the core's hash and the scene").

A render is a pure function of the translated scene, the settings and the compiled core
(a pixel depends only on scene, pixel, sample index and seed; docs/farm.md,
"Determinism"). So the key is exactly those: the scene as the core receives it (its
translated blob, default lighting included), the settings, a digest of the compiled core
and of the Python that hands the scene to it. A changed core, translator or setting
renders anew; only the core's raw output is stored, and everything a test computes from
it (splat resolution, region means, statistics) runs every time.

Where: beside the bench's references (~/.cache/tessera/test-renders, or under
$TESSERA_CACHE_DIR). TESSERA_TEST_RENDER_CACHE=0 turns the cache off (every render runs).
Two test processes that miss the same key both render it; the second rename wins, with the
same bytes.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from tessera_renderer.scene_blob import scene_data_to_blob
from tessera_tools.bench_cache import cache_dir, tessera_build


def enabled() -> bool:
    return os.environ.get("TESSERA_TEST_RENDER_CACHE", "1") != "0"


@functools.cache
def _python_glue_digest() -> str:
    """The tessera_renderer package's Python: the translator and the wrapper that calls
    the core (a change there may change what the core is asked to do)."""
    import tessera_renderer

    h = hashlib.sha256()
    root = Path(tessera_renderer.__file__).parent
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def scene_digest(scene) -> str:
    """The scene as the core receives it (a tessera_renderer.Scene)."""
    h = hashlib.sha256(scene_data_to_blob(scene.data))
    h.update(b"lit by default" if scene.lit_by_default else b"unlit")
    h.update(b"light BVH" if scene.uses_light_bvh else b"lights by power")
    return h.hexdigest()


def cached(tag: str, scene, settings: dict, render: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """render() -> named arrays, or the same arrays from an earlier run with the same key
    (`tag`, the scene, `settings`: JSON values, and the build)."""
    if not enabled():
        return render()
    key = json.dumps({"tag": tag, "scene": scene_digest(scene), "settings": settings,
                      "core": tessera_build(), "python": _python_glue_digest()}, sort_keys=True)
    folder = cache_dir().parent / "test-renders"
    path = folder / f"{tag}-{hashlib.sha256(key.encode()).hexdigest()[:24]}.npz"
    if path.is_file():
        with np.load(path) as f:
            if str(f["__key__"]) == key:
                return {name: f[name] for name in f.files if name != "__key__"}
    arrays = render()
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, __key__=np.array(key), **arrays)
    os.replace(tmp, path)
    return arrays
