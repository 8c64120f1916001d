"""A pixel must not depend on the CPU that renders it (farm workers differ), or, where
Embree's own SIMD choice makes it depend, a farm can pin that choice.

The core is built for the x86-64 baseline with no FP contraction (CMakeLists.txt), but
glibc's libm picks an implementation of sinf, cosf, sincosf, powf, sin, pow, atan2 and
log2 per CPU at load time (an FMA/AVX2 variant on this kind of machine, an SSE2 one on
older CPUs), and the core calls all of them. The reference here is the other variant:
the same renders in a process where glibc is told the CPU lacks AVX, AVX2 and FMA
(GLIBC_TUNABLES), as on an older worker, must give the same bits. Control: in that
process libm's entry points really are other code (their offsets in libm differ), or the
comparison would be of a variant with itself.

Embree picks its traversal and intersection code per CPU too (SSE4.2, AVX, AVX2, ...),
and that does change bits. TESSERA_EMBREE_CONFIG=isa=sse4.2 pins it; an emulated old
worker (libm's baseline and Embree's SSE4.2) and a new one pinned alike must agree.
"""
import json
import os
import subprocess
import sys

import pytest

OLD_CPU = "glibc.cpu.hwcaps=-AVX_Usable,-AVX2_Usable,-FMA_Usable,-FMA4_Usable,-AVX,-AVX2,-FMA,-FMA4"
FUNCTIONS = ("sinf", "cosf", "sincosf", "powf", "sin", "pow", "atan2", "log2")

CHILD = r"""
import ctypes, hashlib, json, sys
import numpy as np
from tessera_renderer.film import new_splat_buffer
from tessera_tools.bench import SCENES, load_bench_scene

class DlInfo(ctypes.Structure):
    _fields_ = [("fname", ctypes.c_char_p), ("fbase", ctypes.c_void_p),
                ("sname", ctypes.c_char_p), ("saddr", ctypes.c_void_p)]

libm, libc = ctypes.CDLL("libm.so.6"), ctypes.CDLL(None)
offsets = {}
for name in json.loads(sys.argv[1]):
    address = ctypes.cast(getattr(libm, name), ctypes.c_void_p).value  # the resolved variant
    info = DlInfo()
    libc.dladdr(ctypes.c_void_p(address), ctypes.byref(info))
    offsets[name] = address - info.fbase
hashes = {}
for scene_name, integrator in (("cornell", "path"), ("cornell", "bdpt"), ("caustic", "path"),
                               ("caustic", "bdpt"), ("caustic", "sppm"), ("dome-glass", "path")):
    scene = load_bench_scene(SCENES[scene_name])
    splats = new_splat_buffer(40, 40)
    product = scene.scene_pass(integrator, 0, seed=5) if integrator == "sppm" else None
    rgba = scene.render_tile(0, 0, 40, 40, width=40, height=40, spp=16, seed=5, threads=2,
                             integrator=integrator, splats=splats if integrator == "bdpt" else None,
                             scene_product=product)
    hashes[f"{scene_name}/{integrator}"] = hashlib.sha256(rgba.tobytes() + splats.tobytes()).hexdigest()
print(json.dumps({"offsets": offsets, "hashes": hashes}))
"""


def _child(tunables: str | None, embree: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    for name, value in (("GLIBC_TUNABLES", tunables), ("TESSERA_EMBREE_CONFIG", embree)):
        env.pop(name, None)
        if value:
            env[name] = value
    return subprocess.run([sys.executable, "-c", CHILD, json.dumps(FUNCTIONS)], env=env, capture_output=True,
                          text=True, timeout=600)


def _run(tunables: str | None, embree: str | None = None) -> dict:
    out = _child(tunables, embree)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _cpu_flags() -> set[str]:
    with open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    return set()


@pytest.mark.shared_scenes  # the dome-glass scene
def test_images_do_not_depend_on_the_cpus_libm_variant():
    if not {"fma", "avx2"} <= _cpu_flags():
        pytest.skip("this CPU has no FMA/AVX2: libm runs its baseline variant already, there is no other to compare")
    here, old_cpu = _run(None), _run(OLD_CPU)
    switched = [f for f in FUNCTIONS if here["offsets"][f] != old_cpu["offsets"][f]]
    # Control: sincosf (the BSDF and light samplers' hemisphere and disk warps) and the
    # other FMA-dispatched functions must really be other code in the second process.
    assert "sincosf" in switched and len(switched) >= 4, (here["offsets"], old_cpu["offsets"])
    assert len(set(here["hashes"].values())) == len(here["hashes"])  # six different images
    differ = [k for k in here["hashes"] if here["hashes"][k] != old_cpu["hashes"][k]]
    assert not differ, f"these renders differ with libm's baseline variant: {differ} (switched: {switched})"


@pytest.mark.shared_scenes  # the dome-glass scene
def test_a_farm_of_mixed_cpus_pins_embrees_isa_and_agrees_bit_for_bit():
    if not {"fma", "avx2"} <= _cpu_flags():
        pytest.skip("this CPU has no AVX2: Embree has no other ISA than SSE here to compare")
    here = _run(None)
    pinned = _run(None, "isa=sse4.2")
    old_worker = _run(OLD_CPU, " isa = sse4.2 ")  # spaces: Embree alone would ignore the pin
    # What docs/farm.md says, measured: Embree's ISA changes the bits of some renders.
    assert any(here["hashes"][k] != pinned["hashes"][k] for k in here["hashes"])
    assert old_worker["hashes"] == pinned["hashes"]


def test_an_unknown_isa_is_refused_not_ignored():
    # Embree itself would fall back to SSE2 without a word.
    out = _child(None, "threads=2,isa=avx3")
    assert out.returncode != 0 and "TESSERA_EMBREE_CONFIG: unknown ISA 'avx3'" in out.stderr
