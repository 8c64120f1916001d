"""The cached bdpt reference for tests/renderer/test_vcm_caustic.py: per-seed region means of bdpt on
examples/caustic/caustic.usda (64 x 64, max_depth 8, the whole frame, so every pixel sample
also traces a light path for the caustic). bdpt needs ~10^7 light paths for a caustic mean
to 0.3 %, minutes on two cores, so the test compares vcm against these numbers instead of
rendering them. Rerun after any change to bdpt or the scene (the test checks the scene's
hash); each seed is appended as it finishes.

    .venv/bin/python scripts/vcm-caustic-reference.py --seeds 24 --spp 256
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "tests" / "renderer"))

from test_vcm_caustic import CAUSTIC, REFERENCE, W, H, region_masks, region_means  # noqa: E402
from tessera_renderer import load_scene  # noqa: E402
from vcm_helpers import render_iteration  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--spp", type=int, default=256)
    args = ap.parse_args()
    scene_hash = hashlib.sha256(CAUSTIC.read_bytes()).hexdigest()
    data = json.loads(REFERENCE.read_text()) if REFERENCE.exists() else {}
    if data.get("scene_sha256") != scene_hash or data.get("spp") != args.spp:
        data = {"scene_sha256": scene_hash, "integrator": "bdpt", "width": W, "height": H, "max_depth": 8,
                "spp": args.spp, "seeds": {}}
    scene, masks = load_scene(str(CAUSTIC)), region_masks()
    for s in range(args.seeds):
        seed = 1000 + s
        if str(seed) in data["seeds"]:
            continue
        img = render_iteration(scene, "bdpt", 0, spp=args.spp, seed=seed, width=W, height=H)
        data["seeds"][str(seed)] = region_means(img, masks)
        REFERENCE.parent.mkdir(exist_ok=True)
        REFERENCE.write_text(json.dumps(data, indent=1) + "\n")
        print(seed, data["seeds"][str(seed)], flush=True)


if __name__ == "__main__":
    main()
