"""`auto` by measurement: a short pilot of the candidate integrators on the render's own
scene, and the one with the highest efficiency renders it.

Efficiency is 1 / (relative variance of one pilot image x its seconds): the inverse of the
time an integrator needs to reach a given error, since its error falls as 1 / time. The
pilot renders each candidate `PILOT_REPEATS` times (different seeds, interleaved) at
`PILOT_SPP` samples on a coarse image of the render's aspect (longer side
`PILOT_PIXELS`), and estimates the relative variance per pixel and channel across the
repeats, var / (m^2 + 0.01) with m the median of all candidates' pilot images there (the
measure relMSE uses, with a scale no candidate's fireflies inflate), averaged over the image.

Candidates are the integrators `auto` chooses between, as the core's registry declares them
(each integrator's `pilot_candidate`, read through tessera_base.integrators.pilot_candidates;
this module names none): today `path` and `bdpt` always, and the photon-merging `sppm` and
`vcm` when the scene has mirrors or glass (Scene.has_delta_surfaces: the caustics merging is
for) and the render runs in passes (a noise target: merging integrators converge over
iterations, and a fixed-spp render is one iteration). A scene whose caustics path tracing
cannot reach at all (a delta light through glass or off a smooth metal:
Scene.has_delta_caustics) leaves out the candidates without `delta_caustics` (`path`): its
variance there is small because it misses that light, not because it is efficient.

The pilot image is coarse, the render is not: a candidate's seconds are extrapolated to
the render's size, its tile pass scaled by the pixel count and its scene pass (photons or
light paths, whose cost does not depend on the image) added once. A merging integrator's
variance falls more slowly than 1/J over J passes: its radius shrinks from batch to batch,
so it falls as J^(-alpha), alpha its default radius exponent (the registry's `merging_alpha`,
the constant its `alpha` setting defaults to). To reach the render's noise target (relative variance
eps = target_error^2) it needs J = (v / eps)^(1/alpha) passes where an unbiased one needs
v / eps, so its efficiency is multiplied by the handicap J'^(1 - 1/alpha), J' = v / eps
clamped to [1, the batches the render holds at most].

Rare hits: a pixel that sees a small light through a mirror once in thousands of samples
gives whichever candidate's 16 pilot samples hit it a relative variance that swamps the
rest, a lottery every candidate shares (all trace the camera side alike). So each
candidate also gets a typical efficiency, from the median of the means of 8 groups of
pixels, which no single pixel moves. The rule: the highest efficiency wins, unless a
merging integrator has the highest typical efficiency; then it does. Discounting rare hits
helps the unbiased candidates most (their fireflies are rare hits too), so a merging
integrator that wins even so is the faster one. The rule's choices are checked against
time to relMSE in docs/benchmarks/auto.md.

The choice is measured, so it can differ between runs on different machines or loads:
it is made once per render (locally, or by `tessera submit` before the job is sent, so
every farm worker renders the same integrator) and recorded with its numbers in the
image's metadata (`tessera:auto`).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field

PILOT_PIXELS = 64
PILOT_SPP = 4
PILOT_REPEATS = 4
TYPICAL_GROUPS = 8


@dataclass
class PilotRow:
    integrator: str
    seconds: float        # mean seconds of one pilot pass, extrapolated to the render's size
    rel_variance: float   # mean over pixels and channels of var / (mean^2 + 0.01), one image
    efficiency: float     # handicap / (rel_variance x seconds)
    scene_seconds: float = 0.0  # of `seconds`, the scene pass's
    handicap: float = 1.0       # J'^(1 - 1/alpha) for merging integrators, else 1
    # The same from the median of the means of TYPICAL_GROUPS groups of pixels, which a
    # few lucky pixels do not move (0: not measured).
    typical_rel_variance: float = 0.0
    typical_efficiency: float = 0.0


@dataclass
class Pilot:
    choice: str
    rows: list[PilotRow] = field(default_factory=list)
    size: tuple[int, int] = (0, 0)
    spp: int = PILOT_SPP
    repeats: int = PILOT_REPEATS
    reason: str = ""

    def summary(self) -> str:
        # `seconds` is extrapolated from the coarse pilot image, not measured at full size.
        parts = ", ".join(f"{r.integrator} {r.efficiency:.3g}/s (rel. variance {r.rel_variance:.3g}; "
                          f"~{r.seconds * 1e3:.0f} ms a {self.spp}-spp pass, extrapolated to full size)"
                          for r in self.rows)
        return (f"auto chose {self.choice}: pilot of {self.repeats} x {self.spp} spp at "
                f"{self.size[0]}x{self.size[1]}: efficiency {parts}" + (f"; {self.reason}" if self.reason else ""))

    def to_json(self) -> str:
        return json.dumps(asdict(self), separators=(",", ":"))


def choose(rows: list[PilotRow]) -> str:
    """The candidate with the highest efficiency (the first listed on a tie), unless a
    merging integrator has the highest typical efficiency: then that one (the module's rule)."""
    if not rows:
        raise ValueError("no pilot measurements to choose from")
    from tessera_base.integrators import merging_alpha

    best = max(rows, key=lambda r: (r.efficiency, -rows.index(r)))
    typical = max(rows, key=lambda r: (r.typical_efficiency, -rows.index(r)))
    if not merging_alpha(best.integrator) and merging_alpha(typical.integrator) and typical.typical_efficiency > 0:
        return typical.integrator
    return best.integrator


def pilot_size(width: int, height: int) -> tuple[int, int]:
    scale = PILOT_PIXELS / max(width, height)
    return max(8, round(width * scale)), max(8, round(height * scale))


def candidates(scene, settings) -> tuple[str, ...]:
    """The integrators the pilot measures for this scene and render (the registry's rule)."""
    from tessera_base.integrators import pilot_candidates

    if getattr(scene, "has_media", False):
        # Only integrators that handle media accept the scene: nothing to measure between.
        return (scene.resolve_integrator("auto"),)
    return pilot_candidates(mirrors_or_glass=scene.has_delta_surfaces(), noise_target=settings.adaptive,
                            delta_caustics=scene.has_delta_caustics(),
                            light_paths=scene.kind_without_light_paths() is None)


def left_out(names: tuple[str, ...], light_paths: bool = True) -> list[str]:
    """The always-candidates a scene's delta-light caustics left out of `names` (among those
    its lights allow: `light_paths` as in pilot_candidates)."""
    from tessera_base.integrators import pilot_candidates

    always = pilot_candidates(mirrors_or_glass=False, noise_target=False, delta_caustics=False,
                              light_paths=light_paths)
    return [c for c in always if c not in names]


def merging_handicap(integrator: str, rel_variance: float, settings) -> float:
    """The factor on a merging integrator's efficiency (the module's rule); 1 for others."""
    from tessera_base.integrators import merging_alpha

    alpha = merging_alpha(integrator)
    if not alpha or not settings.target_error:
        return 1.0
    passes = min(max(1.0, rel_variance / settings.target_error ** 2), float(merging_batches(settings)))
    return passes ** (1.0 - 1.0 / alpha)


def merging_batches(settings) -> int:
    """J: the photon (sppm) or light-path (vcm) batches the render's passes hold at most,
    one per first pass's worth of samples."""
    return max(1, settings.max_spp // settings.min_spp)


def pilot_image(scene, integrator: str, w: int, h: int, spp: int, seed: int, max_depth: int, threads: int):
    """One pilot pass: (image, seconds of its scene pass, seconds of its tile pass)."""
    from tessera_base import integrators
    from tessera_base.film import assemble_image, render_tile_pass, run_scene_pass
    from tessera_base.protocol import RenderSettings, TileRect

    # One pass of `spp` samples for every candidate: a noise target whose first pass is the
    # whole pilot (a fixed spp would run sppm and vcm in passes from one sample).
    st = RenderSettings(width=w, height=h, target_error=1.0, min_spp=spp, max_spp=spp, seed=seed,
                        max_depth=max_depth, tile_size=max(8, w, h), integrator=integrator)
    product, scene_seconds = None, 0.0
    if integrators.scene_passes(integrator):
        start = time.perf_counter()
        product = run_scene_pass(scene, st, 0, integrator=integrator, threads=threads)
        scene_seconds = time.perf_counter() - start
    start = time.perf_counter()
    result, _ = render_tile_pass(scene, st, TileRect(index=0, x0=0, y0=0, width=w, height=h), 0,
                                 integrator=integrator, threads=threads, scene_product=product)
    image = assemble_image(st, {0: [result]}).rgba[..., :3]
    return image, scene_seconds, time.perf_counter() - start


def run_pilot(scene, settings, threads: int = 0, seed: int = 0x51107) -> Pilot:
    """Measures the candidates, each with its default settings, on `scene` (a
    tessera_renderer.Scene) for `settings` (its size, max_depth and pass schedule) and
    returns the choice with the numbers."""
    import numpy as np

    w, h = pilot_size(settings.width, settings.height)
    names = candidates(scene, settings)
    if getattr(scene, "has_media", False):
        return Pilot(choice=names[0], size=(w, h), spp=0, repeats=0,
                     reason=f"the scene has participating media, which only {names[0]} renders: no pilot")
    light_paths = scene.kind_without_light_paths() is None
    missed = f"a delta light lights a caustic {', '.join(left_out(names, light_paths))} cannot reach" \
        if left_out(names, light_paths) else f"{scene.kind_without_light_paths()} lights start no light paths"
    if len(names) == 1:
        return Pilot(choice=names[0], size=(w, h), spp=0, repeats=0, reason=f"{missed}: {names[0]} without a pilot")
    images: dict[str, list] = {c: [] for c in names}
    scene_s: dict[str, list[float]] = {c: [] for c in names}
    tile_s: dict[str, list[float]] = {c: [] for c in names}
    for c in names:  # warm-up: first-call costs stay out of the timings
        pilot_image(scene, c, 8, 8, 1, 0, settings.max_depth, threads)
    for k in range(PILOT_REPEATS):
        for c in names:
            img, ts, tt = pilot_image(scene, c, w, h, PILOT_SPP, seed + k, settings.max_depth, threads)
            scene_s[c].append(ts)
            tile_s[c].append(tt)
            images[c].append(img.astype(np.float64))
    scale = settings.width * settings.height / (w * h)
    seconds = {c: [a + b * scale for a, b in zip(scene_s[c], tile_s[c])] for c in names}
    rows = efficiencies(images, seconds)
    for r in rows:
        r.scene_seconds = float(np.mean(scene_s[r.integrator]))
        r.handicap = merging_handicap(r.integrator, r.rel_variance, settings)
        r.efficiency *= r.handicap
        r.typical_efficiency *= merging_handicap(r.integrator, r.typical_rel_variance, settings)
    reason = missed if left_out(names, light_paths) else ""
    return Pilot(choice=choose(rows), rows=rows, size=(w, h), reason=reason)


def typical_mean(per_pixel) -> float:
    """The median of the means of TYPICAL_GROUPS groups of pixels (a fixed shuffle): the
    mean of a typical group, which one pixel's rare hit does not move."""
    import numpy as np

    v = np.asarray(per_pixel, np.float64).reshape(-1)
    groups = np.array_split(v[np.random.default_rng(0).permutation(len(v))], TYPICAL_GROUPS)
    return float(np.median([g.mean() for g in groups]))


def efficiencies(images: dict[str, list], seconds: dict[str, list[float]]) -> list[PilotRow]:
    """Each candidate's row from its repeated images (same size, float64) and their seconds,
    before any handicap: 1 / (relative variance x seconds), mean and typical."""
    import numpy as np

    # The scale of each pixel: the median over every image of every candidate. A
    # candidate's own mean would hold its own fireflies, and divide them away.
    scale = np.median(np.stack([img for c in images for img in images[c]]), axis=0)
    rows = []
    for c in images:
        per_pixel = (np.stack(images[c]).var(axis=0, ddof=1) / (scale ** 2 + 0.01)).mean(axis=-1)
        rel, typical = float(per_pixel.mean()), typical_mean(per_pixel)
        t = float(np.mean(seconds[c]))
        rows.append(PilotRow(c, t, rel, 1.0 / (rel * t) if rel > 0 and t > 0 else float("inf"),
                             typical_rel_variance=typical,
                             typical_efficiency=1.0 / (typical * t) if typical > 0 and t > 0 else float("inf")))
    return rows
