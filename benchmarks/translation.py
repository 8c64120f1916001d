"""Translation benchmark: USD -> SceneData, the cached blob round trip, and instancing memory.

    .venv/bin/python benchmarks/translation.py [--repeats 5]

1. A 1M-triangle mesh (a 1000 x 500 quad grid = 1,000,000 triangles), written as .usdc, in two flavours: bare (points + faces) and dressed
   (faceVarying normals + faceVarying st). Times: sandbox pre-flight + stage open +
   translation (`translate_stage`), `translate_to_blob`, `scene_from_blob` to SceneData
   (the cached reload), and the BVH build of `Scene`.
2. Peak memory of the translation, measured in a fresh child process each time as
   (ru_maxrss after) - (ru_maxrss before, with the stage libraries already imported), and
   related to the raw geometry bytes of the result (positions + indices [+ normals + st]).
3. 10,000 instances of a 100k-triangle prototype (a PointInstancer), translated with
   instancing="instances": time, peak memory and the bytes of the result, against the
   bytes flattening would need (computed, not allocated: 1e9 triangles).

Every figure is the median of its repeats, with min and max. Results go to
docs/benchmarks/translation.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "benchmarks"

_CHILD = r"""
import json, resource, sys, time
import numpy as np
from pxr import Usd  # libraries loaded before the baseline
import tessera_renderer
from tessera_renderer.usd import translate_stage
from tessera_renderer.scene_blob import translate_to_blob, scene_data_from_blob, scene_data_to_blob
path, mode, instancing = sys.argv[1], sys.argv[2], sys.argv[3]
if mode == "mem":
    import tracemalloc
    tracemalloc.start()
    data = translate_stage(path, instancing=instancing)
    print(json.dumps({"traced_peak_bytes": tracemalloc.get_traced_memory()[1]}))
    sys.exit(0)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
t = time.perf_counter()
data = translate_stage(path, instancing=instancing)
dt = time.perf_counter() - t
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
out = {"translate_s": dt, "peak_bytes": after - before}
def nbytes(d):
    n = d.positions.nbytes + d.indices.nbytes + d.triangle_material.nbytes
    n += sum(x.nbytes for x in (d.shading_normals, d.uvs) if x is not None)
    for p in d.prototypes:
        n += sum(v.nbytes for v in p.values() if v is not None)
    return n + d.instance_transforms.nbytes + d.instances.nbytes
out["result_bytes"] = nbytes(data)
out["raw_geometry_bytes"] = data.positions.nbytes + data.indices.nbytes + sum(
    x.nbytes for x in (data.shading_normals, data.uvs) if x is not None) + sum(
    p["positions"].nbytes + p["indices"].nbytes for p in data.prototypes)
out["triangles"] = int(len(data.indices))
out["instances"] = int(len(data.instances))
if mode == "full":
    t = time.perf_counter(); blob = scene_data_to_blob(data); out["to_blob_s"] = time.perf_counter() - t
    out["blob_bytes"] = len(blob)
    t = time.perf_counter(); d2 = scene_data_from_blob(blob); out["from_blob_s"] = time.perf_counter() - t
    t = time.perf_counter(); tessera_renderer.Scene(d2); out["bvh_build_s"] = time.perf_counter() - t
print(json.dumps(out))
"""


def write_grid(path: Path, dressed: bool) -> None:
    import numpy as np
    from pxr import Sdf, Usd, UsdGeom, Vt

    nx, ny = 1000, 500   # quads -> 1,000,000 triangles
    xs, ys = np.meshgrid(np.arange(nx + 1, dtype=np.float32), np.arange(ny + 1, dtype=np.float32))
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size, np.float32)], 1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    a = (j * (nx + 1) + i).ravel()
    quads = np.stack([a, a + 1, a + nx + 2, a + nx + 1], 1).astype(np.int32)
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Grid")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel()))
    mesh.CreateSubdivisionSchemeAttr("none")
    if dressed:
        n = np.tile(np.array([[0, 0, 1]], np.float32), (quads.size, 1))
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(n))
        mesh.SetNormalsInterpolation("faceVarying")
        st = (pts[quads.ravel(), :2] / [nx, ny]).astype(np.float32)
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "faceVarying")
        pv.Set(Vt.Vec2fArray.FromNumpy(st))
    stage.GetRootLayer().Save()


def write_instances(path: Path) -> None:
    import numpy as np
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    nx, ny = 250, 200   # 100,000 triangles
    xs, ys = np.meshgrid(np.arange(nx + 1, dtype=np.float32), np.arange(ny + 1, dtype=np.float32))
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size, np.float32)], 1) / 250
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    a = (j * (nx + 1) + i).ravel()
    quads = np.stack([a, a + 1, a + nx + 2, a + nx + 1], 1).astype(np.int32)
    pi = UsdGeom.PointInstancer.Define(stage, "/Forest")
    proto = UsdGeom.Mesh.Define(stage, "/Forest/Prototypes/Tile")
    proto.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    proto.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads), 4, np.int32)))
    proto.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.ravel()))
    proto.CreateSubdivisionSchemeAttr("none")
    pi.CreatePrototypesRel().SetTargets([proto.GetPath()])
    n = 10_000
    g = np.arange(n)
    pos = np.stack([(g % 100) * 1.5, (g // 100) * 1.5, np.zeros(n)], 1).astype(np.float32)
    pi.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(pos))
    pi.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.zeros(n, np.int32)))
    stage.GetRootLayer().Save()


def run_child(path: Path, mode: str, instancing: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(path), mode, instancing],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def summary(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "n": len(values)}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    import os
    results: dict = {"machine": {"platform": platform.platform(), "python": platform.python_version(),
                                 "cpus": os.cpu_count(), "load_average_before": os.getloadavg()[0]}}
    with tempfile.TemporaryDirectory() as tmp:
        for flavour in ("bare", "dressed"):
            path = Path(tmp, f"grid_{flavour}.usdc")
            write_grid(path, flavour == "dressed")
            runs = [run_child(path, "full", "flatten") for _ in range(args.repeats)]
            r = {k: summary([x[k] for x in runs]) for k in runs[0] if isinstance(runs[0][k], float)}
            for k in ("triangles", "raw_geometry_bytes", "result_bytes", "blob_bytes"):
                r[k] = runs[0][k]
            r["peak_bytes"] = summary([x["peak_bytes"] for x in runs])
            r["peak_over_raw"] = r["peak_bytes"]["median"] / r["raw_geometry_bytes"]
            r["traced_peak_bytes"] = run_child(path, "mem", "flatten")["traced_peak_bytes"]
            r["traced_peak_over_raw"] = r["traced_peak_bytes"] / r["raw_geometry_bytes"]
            r["usdc_bytes"] = path.stat().st_size
            results[f"mesh_1M_{flavour}"] = r
            print(flavour, json.dumps({k: (v["median"] if isinstance(v, dict) else v) for k, v in r.items()}))
        path = Path(tmp, "instances.usdc")
        write_instances(path)
        runs = [run_child(path, "light", "instances") for _ in range(max(1, args.repeats // 2))]
        r = {"translate_s": summary([x["translate_s"] for x in runs]),
             "peak_bytes": summary([x["peak_bytes"] for x in runs]),
             "result_bytes": runs[0]["result_bytes"], "instances": runs[0]["instances"],
             "traced_peak_bytes": run_child(path, "mem", "instances")["traced_peak_bytes"],
             "prototype_triangles": 100_000,
             # what flattening would hold: float32 xyz per vertex + uint32 x3 per triangle
             "flattened_bytes_estimate": 10_000 * (251 * 201 * 12 + 100_000 * 12)}
        results["instances_10k_of_100k"] = r
        print("instances", json.dumps({k: (v["median"] if isinstance(v, dict) else v) for k, v in r.items()}))
    results["machine"]["load_average_after"] = os.getloadavg()[0]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "translation.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "translation.md").write_text(render_md(results))
    return 0


def _mb(n: float) -> str:
    return f"{n / 1e6:.1f} MB"


def render_md(r: dict) -> str:
    lines = ["# Translation benchmark", "",
             "Measured by `benchmarks/translation.py` on " + r["machine"]["platform"] +
             f" ({r['machine']['cpus']} CPUs; 1-minute load average {r['machine'].get('load_average_before', 0):.1f} "
             f"before and {r['machine'].get('load_average_after', 0):.1f} after: the machine is shared, so "
             "times are upper bounds). Medians of repeats, each in a fresh process; (min..max) in brackets.", "",
             "| 1M-triangle mesh | bare (points + faces) | dressed (+ faceVarying normals and st) |",
             "|---|---|---|"]
    b, d = r["mesh_1M_bare"], r["mesh_1M_dressed"]

    def s(x):
        return f"{x['median']:.3f} s ({x['min']:.3f}..{x['max']:.3f})"

    def ms(x):
        return f"{x['median'] * 1e3:.2f} ms ({x['min'] * 1e3:.2f}..{x['max'] * 1e3:.2f})"
    lines += [
        f"| USD -> SceneData (`translate_stage`: sandbox pre-flight, stage open, translation) | {s(b['translate_s'])} | {s(d['translate_s'])} |",
        f"| SceneData -> blob (`scene_data_to_blob`) | {s(b['to_blob_s'])} | {s(d['to_blob_s'])} |",
        f"| cached reload: blob -> SceneData (`scene_data_from_blob`, zero-copy) | {ms(b['from_blob_s'])} | {ms(d['from_blob_s'])} |",
        f"| BVH build (`Scene(data)`, C++) | {s(b['bvh_build_s'])} | {s(d['bvh_build_s'])} |",
        f"| blob size | {_mb(b['blob_bytes'])} | {_mb(d['blob_bytes'])} |",
        f"| .usdc size | {_mb(b['usdc_bytes'])} | {_mb(d['usdc_bytes'])} |",
        f"| raw geometry of the result (positions + indices [+ normals + st]) | {_mb(b['raw_geometry_bytes'])} | {_mb(d['raw_geometry_bytes'])} |",
        f"| peak memory of the translation (RSS growth) | {_mb(b['peak_bytes']['median'])} | {_mb(d['peak_bytes']['median'])} |",
        f"| peak / raw geometry | {b['peak_over_raw']:.1f}x | {d['peak_over_raw']:.1f}x |",
        f"| peak of numpy/Python allocations (tracemalloc) | {_mb(b['traced_peak_bytes'])} "
        f"({b['traced_peak_over_raw']:.1f}x raw) | {_mb(d['traced_peak_bytes'])} ({d['traced_peak_over_raw']:.1f}x raw) |",
        "", "## 10,000 instances of a 100k-triangle prototype (PointInstancer, `instancing=\"instances\"`)", "",
    ]
    i = r["instances_10k_of_100k"]
    lines += ["| | |", "|---|---|",
              f"| translation | {s(i['translate_s'])} |",
              f"| peak memory of the translation (RSS growth over the imported libraries) | "
              f"{_mb(i['peak_bytes']['median']) if i['peak_bytes']['median'] else 'none: stays under the high-water mark of importing pxr'} |",
              f"| peak of numpy/Python allocations (tracemalloc) | {_mb(i['traced_peak_bytes'])} |",
              f"| result: one prototype + {i['instances']} transforms | {_mb(i['result_bytes'])} |",
              f"| flattened, the same geometry would need | {_mb(i['flattened_bytes_estimate'])} (1e9 triangles; not allocated) |",
              "", "The translation side holds one copy of the prototype; the core's memory and build time for "
              "the same 10,000 instances (one BVH per prototype, Embree instances) are in "
              "docs/benchmarks/instancing.md.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
