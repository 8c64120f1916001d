"""`auto` by measurement: a short pilot of the candidate integrators on the render's own
scene, and the one with the highest efficiency renders it.

Efficiency is 1 / (relative variance of one pilot image x its seconds): the inverse of the
time an integrator needs to reach a given error, since its error falls as 1 / time. The
pilot renders each candidate `PILOT_REPEATS` times (different seeds, interleaved) at
`PILOT_SPP` samples on a coarse image of the render's aspect (longer side
`PILOT_PIXELS`), and estimates the relative variance per pixel and channel across the
repeats, var / (m^2 + 0.01) with m the median of all candidates' pilot images there (the
measure relMSE uses, with a scale no candidate's fireflies inflate), averaged over the image.

Candidates are the integrators `auto` chooses between (`path`, `bdpt`). A scene whose
caustics path tracing cannot reach at all (a delta light through glass or off a smooth
metal: Scene.has_delta_caustics) leaves `bdpt` alone: path's variance there is small
because it misses that light, not because it is efficient.

The choice is measured, so it can differ between runs on different machines or loads:
it is made once per render (locally, or by `tessera submit` before the job is sent, so
every farm worker renders the same integrator) and recorded with its numbers in the
image's metadata (`tessera:auto`).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field

CANDIDATES = ("path", "bdpt")
PILOT_PIXELS = 64
PILOT_SPP = 4
PILOT_REPEATS = 4


@dataclass
class PilotRow:
    integrator: str
    seconds: float        # mean seconds of one pilot image
    rel_variance: float   # mean over pixels and channels of var / (mean^2 + 0.01), one image
    efficiency: float     # 1 / (rel_variance x seconds)


@dataclass
class Pilot:
    choice: str
    rows: list[PilotRow] = field(default_factory=list)
    size: tuple[int, int] = (0, 0)
    spp: int = PILOT_SPP
    repeats: int = PILOT_REPEATS
    reason: str = ""

    def summary(self) -> str:
        parts = ", ".join(f"{r.integrator} {r.efficiency:.3g}/s (rel. variance {r.rel_variance:.3g} in "
                          f"{r.seconds * 1e3:.0f} ms)" for r in self.rows)
        return (f"auto chose {self.choice}: pilot of {self.repeats} x {self.spp} spp at "
                f"{self.size[0]}x{self.size[1]}: efficiency {parts}" + (f"; {self.reason}" if self.reason else ""))

    def to_json(self) -> str:
        return json.dumps(asdict(self), separators=(",", ":"))


def choose(rows: list[PilotRow]) -> str:
    """The candidate with the highest efficiency (the first listed on a tie)."""
    if not rows:
        raise ValueError("no pilot measurements to choose from")
    return max(rows, key=lambda r: (r.efficiency, -rows.index(r))).integrator


def pilot_size(width: int, height: int) -> tuple[int, int]:
    scale = PILOT_PIXELS / max(width, height)
    return max(8, round(width * scale)), max(8, round(height * scale))


def pilot_image(scene, integrator: str, w: int, h: int, spp: int, seed: int, max_depth: int, threads: int):
    from tessera_base.film import assemble_image, render_tile_pass
    from tessera_base.protocol import RenderSettings, TileRect

    st = RenderSettings(width=w, height=h, spp=spp, seed=seed, max_depth=max_depth,
                        tile_size=max(8, w, h), integrator=integrator)
    result, _ = render_tile_pass(scene, st, TileRect(index=0, x0=0, y0=0, width=w, height=h), 0,
                                 integrator=integrator, threads=threads)
    return assemble_image(st, {0: [result]}).rgba[..., :3]


def run_pilot(scene, settings, threads: int = 0) -> Pilot:
    """Measures the candidates on `scene` (a tessera_renderer.Scene) for `settings`
    (its width, height and max_depth) and returns the choice with the numbers."""
    import numpy as np

    w, h = pilot_size(settings.width, settings.height)
    if scene.has_delta_caustics():
        return Pilot(choice="bdpt", size=(w, h), spp=0, repeats=0,
                     reason="a delta light lights a caustic path tracing cannot reach: bdpt without a pilot")
    images: dict[str, list] = {c: [] for c in CANDIDATES}
    seconds: dict[str, list[float]] = {c: [] for c in CANDIDATES}
    for c in CANDIDATES:  # warm-up: first-call costs stay out of the timings
        pilot_image(scene, c, 8, 8, 1, 0, settings.max_depth, threads)
    for k in range(PILOT_REPEATS):
        for c in CANDIDATES:
            start = time.perf_counter()
            img = pilot_image(scene, c, w, h, PILOT_SPP, 0x51107 + k, settings.max_depth, threads)
            seconds[c].append(time.perf_counter() - start)
            images[c].append(img.astype(np.float64))
    rows = efficiencies(images, seconds)
    return Pilot(choice=choose(rows), rows=rows, size=(w, h))


def efficiencies(images: dict[str, list], seconds: dict[str, list[float]]) -> list[PilotRow]:
    """Each candidate's row from its repeated images (same size, float64) and their seconds."""
    import numpy as np

    # The scale of each pixel: the median over every image of every candidate. A
    # candidate's own mean would hold its own fireflies, and divide them away.
    scale = np.median(np.stack([img for c in images for img in images[c]]), axis=0)
    rows = []
    for c in images:
        rel = float(np.mean(np.stack(images[c]).var(axis=0, ddof=1) / (scale ** 2 + 0.01)))
        t = float(np.mean(seconds[c]))
        rows.append(PilotRow(c, t, rel, 1.0 / (rel * t) if rel > 0 and t > 0 else float("inf")))
    return rows
