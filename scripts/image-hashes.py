"""SHA-256 of rendered float pixels, per (scene, integrator): proof that a refactoring left
images bit-identical. Run it at two commits and diff the output.

    .venv/bin/python scripts/image-hashes.py > /tmp/after.txt
    .venv/bin/python scripts/image-hashes.py --integrators path,bdpt > /tmp/some.txt

Each image is rendered whole (one tile), with a full-frame splat buffer whatever the
integrator (one that does not splat leaves it zero and reports no light paths), and
resolved to float32 RGBA the way the farm and local renders do. The hash covers those
float32 bytes, so one changed bit anywhere in the image changes it.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared" / "scenes"

# (label, path, default_light): the examples and a handful of the shared real scenes,
# chosen to cover every light kind (rect, disk, sphere, distant, textured dome, the
# default light), glass, metals, textures and instancing. A shared scene's bundle root is
# its top folder (some reference assets beside their layer's directory).
SCENES = [
    ("cornell", REPO / "examples/cornell/cornell.usda", False),
    ("caustic", REPO / "examples/caustic/caustic.usda", False),
    ("arnold-disk", SHARED / "arnoldusd_disk_rect_lights/test_2439.4/data/disk.usda", False),
    ("arnold-rect", SHARED / "arnoldusd_disk_rect_lights/test_2439.5/data/rect.usda", False),
    ("normal-map", SHARED / "openusd_testenv/testUsdImagingGLMaterialXvsNative/nativeNormalMap.usda", False),
    ("pyramids", SHARED / "usdwg_subdiv_pyramids/Creases_SpinningPyramids.usda", True),
    ("dome-yup", SHARED / "openusd_testenv/testUsdImagingGLDomeLight/domeLightYup.usda", False),
    ("ni-binding", SHARED / "openusd_testenv/testUsdImagingGLInstancingWithMaterials/"
                   "ni_ni_material_binding_resolution.usda", False),
    ("ref-lights", SHARED / "usdwg_internal_reference_lights/InternalReferenceTest.usda", False),
    ("teapot", SHARED / "usdwg_teapot/Teapot.usd", True),
]


def default_integrators() -> list[str]:
    import tessera_renderer
    if not hasattr(tessera_renderer, "integrators"):
        sys.exit("this commit has no integrator registry: give --integrators")
    return [i["name"] for i in tessera_renderer.integrators()]


def scene_passes(name: str) -> bool:
    import tessera_renderer
    infos = tessera_renderer.integrators() if hasattr(tessera_renderer, "integrators") else []
    return any(i["name"] == name and i.get("scene_passes") for i in infos)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--integrators", help="comma-separated names (default: every registered integrator)")
    p.add_argument("--res", type=int, default=48, help="image width and height (default 48)")
    p.add_argument("--spp", type=int, default=8, help="samples per pixel (default 8)")
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--max-depth", type=int, default=8)
    args = p.parse_args()

    from tessera_renderer import load_scene
    from tessera_renderer.film import new_splat_buffer
    try:
        from tessera_base.film import resolve_splats
    except ImportError:  # a tree from before the one splat normalisation
        from tessera_renderer.film import resolve_image as resolve_splats

    integrators = args.integrators.split(",") if args.integrators else default_integrators()
    for label, path, default_light in SCENES:
        root = SHARED / path.relative_to(SHARED).parts[0] if path.is_relative_to(SHARED) else None
        scene = load_scene(path, root=root, default_light=default_light)
        for integrator in integrators:
            splats = new_splat_buffer(args.res, args.res)
            stats: dict = {}
            extra = {}
            if scene_passes(integrator):  # one iteration: its scene pass, then the frame
                extra["scene_product"] = scene.scene_pass(integrator, 0, seed=args.seed,
                                                          max_depth=args.max_depth, threads=2)
            rgba = scene.render_tile(0, 0, args.res, args.res, width=args.res, height=args.res, spp=args.spp,
                                     seed=args.seed, max_depth=args.max_depth, threads=2, integrator=integrator,
                                     splats=splats, stats=stats, **extra)
            image = resolve_splats(rgba, splats, stats["light_paths"], scene.splat_exponent)
            digest = hashlib.sha256(np.ascontiguousarray(image, np.float32).tobytes()).hexdigest()
            mean = image[..., :3].mean()  # shows that the image is not trivially black or flat
            print(f"{label:12s} {integrator:8s} {digest} mean {mean:.6g}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
