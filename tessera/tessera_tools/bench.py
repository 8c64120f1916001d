"""`tessera bench`: error versus time for each integrator, and a peer renderer side by side.

For every scene x series (a renderer and an integrator) x rung of a ladder of sample
counts, renders the image, times it (wall clock, 2 threads) and measures its error against
a high-sample reference:

    relMSE = mean over pixels and channels of (x - ref)^2 / (ref^2 + 1e-2) - the reference's own
    RMSE   = sqrt(mean over pixels and channels of (x - ref)^2)

The reference's own relMSE (bench_stats.reference_noise, from its two seeds) is subtracted:
against a reference with relMSE 1e-3 of its own, every curve would otherwise flatten at
1e-3 and a time to 1e-3 could not be read at all. Points within three standard errors of
that correction are left out of the fits. (RMSE is reported as measured.)

Repetitions (different seeds) are interleaved: every repetition walks the ladder once and
renders every series at each rung before moving on, in an order rotated per repetition,
so that load from other processes on the machine hits all series alike. A straight line
is fitted to log10(relMSE) against log10(seconds) per series, once over all points and
once per repetition. The time to reach a relMSE target is read between the two measured
points that bracket it (interpolated), or off the line where none do (extrapolated: the
report says which); the relMSE at a time budget is read off the line; the half-range of
the per-repetition values is their error. Ratios between two series are taken per
repetition, then summarised the same way: both series' points come from the same run and
the same minutes.

References are rendered once and cached outside git (`~/.cache/tessera/references/`, or
$TESSERA_CACHE_DIR), keyed by a hash of the scene's files, the settings and the renderer
build. Two references with different seeds are rendered; the image compared against is
their mean, and their mutual relMSE is reported: the mean's own error is about a quarter
of it. The subtracted own relMSE must be known to a tenth of the finest error read (the
smallest target, or the smallest error measured if that is larger).

The peer is Mitsuba 3 (optional extra `peer`), built from Tessera's own translation of the
scene (tessera/tessera_tools/peer_mitsuba.py). Before any speed ratio is quoted, converged images of
both renderers must agree: the image mean within 1 %, and the mean of every region of a 4 x
4 grid within 1 % plus 3 standard errors of the two images' own noise there (the peer's
from its reference's passes, Tessera's from its two seeds).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .bench_cache import cached_render, scene_digest, tessera_build
from .bench_report import _markdown, _plots, _write_csv
from .bench_stats import (TARGETS, UNIT_TOLERANCE, error_at, fit_loglog, reference_noise, region_means, region_noise,
                          rel_mse, rmse, spread, time_to_measured, units_agree)

REPO = Path(__file__).resolve().parents[2]
SHARED_SCENES = Path(os.environ.get("TESSERA_SHARED_SCENES", REPO.parent / "shared" / "scenes"))
INSTALL_HINT = "pip install -e '.[bench]'"
PEER_HINT = "pip install -e '.[peer]'"


# -- scenes ------------------------------------------------------------------------------

@dataclass(frozen=True)
class BenchScene:
    name: str
    path: Path
    note: str
    reference: str = "path"             # integrator of the references
    cross_check: str | None = None      # a second integrator whose reference must agree
    lambertize: bool = False            # opaque UsdPreviewSurfaces -> Lambertian (peer variant)
    peer: bool = False                  # compare with Mitsuba
    integrators: tuple[str, ...] | None = None   # restrict (peer variants: what is compared)
    ref_scale: int = 1                  # x the config's reference spp (noisy caustics)


CORNELL = REPO / "examples" / "cornell" / "cornell.usda"
CORNELL_EXPORTED = REPO / "examples" / "cornell" / "cornell_exported.usda"
CAUSTIC = REPO / "examples" / "caustic" / "caustic.usda"
CAUSTIC_MIRROR = REPO / "examples" / "caustic" / "caustic_mirror.usda"

SCENES = {s.name: s for s in (
    BenchScene("cornell", CORNELL, "the Cornell box as authored (UsdPreviewSurface, roughness 1)"),
    BenchScene("cornell-lambert", CORNELL,
               "the Cornell box with every opaque UsdPreviewSurface made Lambertian (same albedo), "
               "the materials Mitsuba can match", lambertize=True, peer=True,
               integrators=("path", "bdpt")),
    BenchScene("cornell-exported", CORNELL_EXPORTED,
               "the Cornell box as exporters write a plain diffuse UsdPreviewSurface (specular workflow, "
               "specularColor 0: exactly Lambertian, rendered as authored)", peer=True, integrators=("path", "bdpt")),
    BenchScene("caustic", CAUSTIC, "glass sphere on a Lambertian floor, small sphere light "
               "(examples/caustic)", reference="bdpt", cross_check="path", peer=True, ref_scale=2),
    # bdpt connects nothing across the mirror (only its s = 0 strategy, path tracing, reaches
    # L S D S E), so the reference is path at 8 x 4096 spp, cross-checked by sppm.
    BenchScene("caustic-mirror", CAUSTIC_MIRROR, "the glass sphere's caustic seen only in a mirror: L S D S E "
               "(examples/caustic/caustic_mirror.usda)", reference="path", cross_check="sppm", peer=True,
               ref_scale=8),
    BenchScene("dome-glass", SHARED_SCENES / "openusd_testenv" / "testUsdImagingGLDomeLight" / "domeLightYup.usda",
               "OpenUSD test scene: smooth dielectric sphere under a PNG dome light (shared/scenes)"),
    BenchScene("instancing", SHARED_SCENES / "openusd_testenv" / "testUsdImagingGLInstancingWithMaterials"
               / "ni_ni_material_binding_resolution.usda",
               "OpenUSD test scene: nested native instances, 20k triangles, one distant light (shared/scenes)"),
)}
DEFAULT_SCENES = ("cornell", "cornell-exported", "cornell-lambert", "caustic", "dome-glass", "instancing")
DEFAULT_INTEGRATORS = ("path", "bdpt", "light")


@dataclass
class Config:
    res: int = 128
    reps: int = 3
    ladders: dict = field(default_factory=lambda: {
        "path": (4, 16, 64, 256), "light": (4, 16, 64, 256), "bdpt": (1, 4, 16, 64), "vcm": (1, 4, 16, 64),
        "local": (4, 16, 64, 256), "whitted": (4, 16, 64, 256), "mitsuba": (4, 16, 64, 256),
        "photon": (1, 4, 16), "sppm": (4, 16, 64)})
    ref_spp: dict = field(default_factory=lambda: {"path": 4096, "bdpt": 1024, "light": 4096, "sppm": 1024})
    scene_ladders: dict = field(default_factory=dict)   # {scene: {integrator: ladder}} overrides
    peer_ref_spp: int = 4096
    budget: float = 1.0          # seconds, for the equal-time error
    max_depth: int = 64
    threads: int = 2
    quick: bool = False


def quick_config() -> Config:
    ladder = (1, 4, 16)
    # 64 px: at 32 px a region of the 4 x 4 grid is 8 x 8 pixels, and one region of the
    # Cornell box disagreed by 1.4 % with Mitsuba at 4096 spp (none above 0.3 % at 64 px).
    return Config(res=64, reps=2, ladders={k: ladder for k in Config().ladders},
                  ref_spp={"path": 512, "bdpt": 128, "light": 512, "sppm": 64}, peer_ref_spp=1024, budget=0.1,
                  quick=True)


def bench_scene_data(bs: BenchScene):
    """The scene's translation as the bench renders it (lambertized for the peer variants),
    not yet built: a core built for Lambert-only scenes (benchmarks/lambert_only.py) cannot
    build the authored materials that lambertize replaces."""
    from tessera_renderer import translate_stage

    from .peer_mitsuba import lambertize

    if not bs.path.is_file():
        raise FileNotFoundError(f"scene {bs.name}: {bs.path} not found")
    data = translate_stage(str(bs.path), instancing="auto")
    return lambertize(data) if bs.lambertize else data


def load_bench_scene(bs: BenchScene):
    from tessera_renderer import Scene, load_scene

    from .peer_mitsuba import lambertize

    if not bs.path.is_file():
        raise FileNotFoundError(f"scene {bs.name}: {bs.path} not found")
    scene = load_scene(bs.path)
    if bs.lambertize:
        scene = Scene(lambertize(scene.data))
    return scene


def render_tessera(scene, integrator: str, spp: int, seed: int, res: int, cfg: Config) -> np.ndarray:
    """One image as one tile pass, rendered and assembled as every Tessera render is."""
    from tessera_base import integrators
    from tessera_base.film import assemble_image, render_tile_pass, run_scene_pass
    from tessera_base import protocol
    from tessera_base.protocol import RenderSettings, TileRect

    settings = RenderSettings(width=res, height=res, spp=spp, seed=seed, max_depth=cfg.max_depth,
                              tile_size=max(8, res), integrator=integrator)
    rect = TileRect(index=0, x0=0, y0=0, width=res, height=res)
    if integrators.scene_passes(integrator):
        # Iterations as the farm runs them (passes of 1, 1, 2, 4, ... samples up to spp),
        # each scene pass timed with its tile pass: progressive methods need them all.
        settings = settings.model_copy(update=dict(target_error=1e-12, min_spp=1, max_spp=spp))
        results, k = [], 0
        while protocol.pass_range(settings, k) is not None:
            product = run_scene_pass(scene, settings, k, integrator=integrator, threads=cfg.threads)
            results.append(render_tile_pass(scene, settings, rect, k, integrator=integrator, threads=cfg.threads,
                                            scene_product=product)[0])
            k += 1
        return assemble_image(settings, {0: results}).rgba[..., :3]
    result, _ = render_tile_pass(scene, settings, rect, 0, integrator=integrator, threads=cfg.threads)
    return assemble_image(settings, {0: [result]}).rgba[..., :3]


class MitsubaPeer:
    """One Mitsuba variant with the bench scenes loaded into it. `variant` may name a
    sampler after a slash ("llvm_ad_rgb/ldsampler"; default: Mitsuba's independent sampler);
    the whole string labels the peer's series."""

    def __init__(self, variant: str, threads: int):
        from . import peer_mitsuba

        self.variant = variant
        self.mi_variant, _, sampler = variant.partition("/")
        self.sampler = sampler or "independent"
        self.threads = threads
        self.pm = peer_mitsuba
        self.mi = peer_mitsuba.set_variant(self.mi_variant, threads)
        self.version = self.mi.__version__
        self.scenes: dict = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="tessera-bench-mi-")

    def load(self, name: str, data, res: int, cfg: Config) -> None:
        self.pm.set_variant(self.mi_variant, self.threads)
        d = self.pm.scene_dict(data, res, res, Path(self._tmp.name) / name, max_depth=cfg.max_depth,
                               sampler=self.sampler)
        self.scenes[name] = self.mi.load_dict(d)

    def render(self, name: str, spp: int, seed: int) -> np.ndarray:
        self.pm.set_variant(self.mi_variant, self.threads)
        return self.pm.render(self.scenes[name], spp, seed)

    def render_passes(self, name: str, spp: int, seed: int, pass_spp: int = 256) -> tuple[np.ndarray, dict]:
        """The mean of passes of `pass_spp` samples, and (as {"region_noise": ...}) the
        relative standard error of its region means from the passes' spread (None with
        fewer than two passes or unequal ones)."""
        total, acc, passes = 0, None, []
        k = 0
        while total < spp:
            n = min(pass_spp, spp - total)
            img = self.render(name, n, seed * 100003 + k).astype(np.float64)
            passes.append((n, img))
            acc = img * n if acc is None else acc + img * n
            total += n
            k += 1
        equal = len(passes) > 1 and len({n for n, _ in passes}) == 1
        noise = region_noise(pass_images=[img for _, img in passes]).tolist() if equal else None
        return (acc / total).astype(np.float32), {"region_noise": noise}


# -- the run -------------------------------------------------------------------------------

@dataclass
class Series:
    scene: str
    renderer: str       # "tessera" or "mitsuba <variant>"
    integrator: str
    ladder: tuple[int, ...]

    @property
    def label(self) -> str:
        return f"{self.renderer} {self.integrator}"


def run(scene_names, integrators, cfg: Config, out: Path, peer_variants=("scalar_rgb", "llvm_ad_rgb"),
        log=print) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    build = tessera_build()
    result: dict = {"config": {"res": cfg.res, "reps": cfg.reps, "ladders": {k: list(v) for k, v in cfg.ladders.items()},
                               "ref_spp": cfg.ref_spp, "peer_ref_spp": cfg.peer_ref_spp, "budget_seconds": cfg.budget,
                               "max_depth": cfg.max_depth, "threads": cfg.threads, "quick": cfg.quick},
                    "tessera": build, "cpu_count": os.cpu_count(), "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
                    "peer": {}, "scenes": {}}
    try:
        result["load_average_start"] = os.getloadavg()
    except OSError:
        pass

    # Peers: every requested variant that runs here; say why one does not.
    peers: list[MitsubaPeer] = []
    want_peer = any(SCENES[n].peer for n in scene_names)
    if want_peer:
        from . import peer_mitsuba

        if not peer_mitsuba.available():
            result["peer"]["error"] = f"mitsuba is not installed ({PEER_HINT})"
            log(f"peer: mitsuba is not installed; no side-by-side ({PEER_HINT})")
        else:
            for variant in peer_variants:
                try:
                    peers.append(MitsubaPeer(variant, cfg.threads))
                    result["peer"][variant] = "ok"
                except RuntimeError as exc:
                    result["peer"][variant] = str(exc)
                    log(f"peer: {exc}")
    rows: list[dict] = []
    for name in scene_names:
        bs = SCENES[name]
        log(f"[{name}] {bs.note}")
        scene = load_bench_scene(bs)
        res = cfg.res
        sdig = scene_digest(bs.path)
        info: dict = {"note": bs.note, "path": str(bs.path.relative_to(REPO.parent) if bs.path.is_relative_to(REPO.parent) else bs.path),
                      "res": res, "triangles": scene.num_triangles}
        # References: two seeds of the reference integrator, averaged.
        ref_int = bs.reference
        ref_spp = cfg.ref_spp[ref_int] * bs.ref_scale

        def tkey(integrator, spp, seed):
            return {"scene": name, "scene_digest": sdig, "lambertize": bs.lambertize, "renderer": build,
                    "integrator": integrator, "spp": spp, "seed": seed, "res": res, "max_depth": cfg.max_depth,
                    "threads_do_not_matter": True}

        refs = []
        for seed in (900001, 900002):
            img, meta = cached_render(tkey(ref_int, ref_spp, seed),
                                      lambda s=seed: render_tessera(scene, ref_int, ref_spp, s, res, cfg), log)
            refs.append((img, meta))
        ref = (refs[0][0].astype(np.float64) + refs[1][0]) / 2
        mutual = rel_mse(refs[0][0], refs[1][0])
        own, own_error = reference_noise(refs[0][0], refs[1][0])
        ra, rb = region_means(refs[0][0]).sum(-1), region_means(refs[1][0]).sum(-1)
        lit = (ra + rb) > 0.04 * (ra + rb).mean()
        ref_region_noise = region_noise(halves=(refs[0][0], refs[1][0]))
        seed_region_noise = float(np.max(ref_region_noise[lit])) if lit.any() else float("nan")
        info["reference"] = {"integrator": ref_int, "spp": ref_spp, "seeds": 2, "mutual_rel_mse": mutual,
                             "region_mean_noise": seed_region_noise,
                             "estimated_rel_mse_of_mean": own, "own_rel_mse_error": own_error,
                             "seconds": [m["seconds"] for _, m in refs], "cached": [m["cached"] for _, m in refs]}
        log(f"  reference: {ref_int} 2 x {ref_spp} spp, mutual relMSE {mutual:.3g} "
            f"(the mean's own relMSE {own:.2g} ± {own_error:.1g}, subtracted from every point); its region means "
            f"differ by at most "
            f"{seed_region_noise:.2%} between the two seeds")
        if bs.cross_check:
            cc_spp = cfg.ref_spp[bs.cross_check]
            cc, meta = cached_render(tkey(bs.cross_check, cc_spp, 900003),
                                     lambda: render_tessera(scene, bs.cross_check, cc_spp, 900003, res, cfg), log)
            agree = units_agree(ref, cc)
            info["reference"]["cross_check"] = {"integrator": bs.cross_check, "spp": cc_spp,
                                                "rel_mse_vs_reference": rel_mse(cc, ref), **agree}
            log(f"  cross-check: {bs.cross_check} {cc_spp} spp vs the {ref_int} reference: means within "
                f"{agree['worst_mean_deviation']:.2%}, regions within {agree['worst_region_deviation']:.2%} "
                f"(relMSE {rel_mse(cc, ref):.3g}) -> {'agree' if agree['agree'] else 'DISAGREE'}")

        # An integrator without a tuned ladder gets the peer's (the plain one).
        ladders = {**cfg.ladders, **cfg.scene_ladders.get(name, {})}
        series = [Series(name, "tessera", i, ladders.get(i, ladders["mitsuba"])) for i in integrators
                  if bs.integrators is None or i in bs.integrators]
        # Peer: converged images must agree before any ratio is quoted.
        if bs.peer and peers:
            info["peer"] = {}
            for peer in peers:
                tag = f"mitsuba {peer.variant}"
                try:
                    peer.load(name, scene.data, res, cfg)
                except Exception as exc:  # noqa: BLE001 - Unmatched or a Mitsuba error: report it
                    info["peer"][tag] = {"error": str(exc)}
                    log(f"  {tag}: not comparable: {exc}")
                    continue
                mref, meta = cached_render(
                    {"scene": name, "scene_digest": sdig, "lambertize": bs.lambertize,
                     "renderer": f"mitsuba {peer.version} {peer.variant}", "integrator": "path",
                     "spp": cfg.peer_ref_spp * bs.ref_scale, "seed": 7, "res": res, "max_depth": cfg.max_depth,
                     "tessera_translation": build, "region_noise": True},
                    lambda p=peer: p.render_passes(name, cfg.peer_ref_spp * bs.ref_scale, 7), log)
                # Both converged images' own noise per region: the peer's from its passes,
                # Tessera's from its two seeds.
                noise = None
                if meta.get("region_noise") is not None:
                    noise = np.hypot(np.asarray(meta["region_noise"], np.float64), ref_region_noise)
                agree = units_agree(ref, mref, noise=noise)
                info["peer"][tag] = {"reference_spp": cfg.peer_ref_spp * bs.ref_scale, "reference_seconds": meta["seconds"],
                                     "rel_mse_vs_tessera_reference": rel_mse(mref, ref), **agree}
                log(f"  units: {tag} {cfg.peer_ref_spp * bs.ref_scale} spp vs Tessera's reference: image means "
                    f"{', '.join(f'{r:.4f}' for r in agree['mean_ratio'])} (max deviation "
                    f"{agree['worst_mean_deviation']:.2%}), worst of {agree['regions_compared']} regions "
                    f"{agree['worst_region_deviation']:.2%}"
                    + (f" ({agree['worst_region_excess']:.2%} beyond 3 standard errors of both images' noise)"
                       if "worst_region_excess" in agree else "")
                    + f" -> {'AGREE' if agree['agree'] else 'DISAGREE'} (tolerance {UNIT_TOLERANCE:.0%})")
                series.append(Series(name, tag, "path", ladders["mitsuba"]))
        # Warm-up outside the timings: caches, and for Mitsuba's LLVM variants the kernels,
        # which are compiled per sample count (measured: the first call at a new spp is slow).
        for s in series:
            for spp in (s.ladder if "llvm" in s.renderer else s.ladder[:1]):
                _render_series(s, scene, peers, spp, 1, res, cfg)
        # Interleaved repetitions.
        n_rungs = max(len(s.ladder) for s in series)
        for rep in range(cfg.reps):
            order = series[rep % len(series):] + series[:rep % len(series)]
            for k in range(n_rungs):
                for s in order:
                    if k >= len(s.ladder):
                        continue
                    spp = s.ladder[k]
                    seed = 1 + rep * 1000 + k
                    start = time.perf_counter()
                    img = _render_series(s, scene, peers, spp, seed, res, cfg)
                    seconds = time.perf_counter() - start
                    raw = rel_mse(img, ref)
                    row = {"scene": name, "renderer": s.renderer, "integrator": s.integrator, "spp": spp,
                           "rep": rep, "seed": seed, "res": res, "seconds": seconds,
                           "rel_mse": raw - own, "rel_mse_raw": raw, "rmse": rmse(img, ref)}
                    rows.append(row)
            log(f"  repetition {rep + 1}/{cfg.reps} done")
        # The subtraction's resolution: points within it say nothing about their series.
        floor = 3 * own_error
        info["series"] = _summarise(name, series, rows, cfg, floor)
        smallest = min(r["rel_mse"] for r in rows if r["scene"] == name)
        info["reference"]["smallest_measured_rel_mse"] = smallest
        # What the run reads off its points: times to the targets, so the reference must
        # resolve a tenth of the smallest target (or of the smallest error, if above it).
        finest = max(smallest, min(TARGETS))
        info["reference"]["ok"] = bool(floor < 0.1 * finest)
        log(f"  reference check: the subtracted own relMSE is known to ±{floor:.2g} (3 sigma) vs the finest "
            f"error read, {finest:.3g} ({finest / max(floor, 1e-30):.0f}x; smallest measured {smallest:.3g}) -> "
            f"{'OK' if info['reference']['ok'] else 'TOO NOISY'}")
        info["ratios"] = _ratios(info, cfg)
        result["scenes"][name] = info
    for peer in peers:
        peer._tmp.cleanup()
    try:
        result["load_average_end"] = os.getloadavg()
    except OSError:
        pass
    _write_csv(out / "error-vs-time.csv", rows)
    (out / "error-vs-time.json").write_text(json.dumps(result, indent=2, default=_json_default) + "\n")
    _plots(result, rows, out)
    (out / "error-vs-time-results.md").write_text(_markdown(result))
    return result


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def _render_series(s: Series, scene, peers, spp, seed, res, cfg) -> np.ndarray:
    if s.renderer == "tessera":
        return render_tessera(scene, s.integrator, spp, seed, res, cfg)
    variant = s.renderer.split(" ", 1)[1]
    peer = next(p for p in peers if p.variant == variant)
    return peer.render(s.scene, spp, seed)


def _summarise(name, series, rows, cfg, floor: float = 0.0) -> dict:
    """Per series: the log-log fits (overall and per repetition) of the points above `floor`,
    the rungs' spreads, the times to each target and the error at the budget."""
    out = {}
    for s in series:
        every = [r for r in rows if r["scene"] == name and r["renderer"] == s.renderer and r["integrator"] == s.integrator]
        pts = [r for r in every if r["rel_mse"] > floor]
        secs = [r["seconds"] for r in pts]
        errs = [r["rel_mse"] for r in pts]
        fit = fit_loglog(secs, errs)
        reps = sorted({r["rep"] for r in pts})
        rep_fits = [fit_loglog([r["seconds"] for r in pts if r["rep"] == k], [r["rel_mse"] for r in pts if r["rep"] == k])
                    for k in reps]
        entry = {"label": s.label, "renderer": s.renderer, "integrator": s.integrator,
                 "fit": {"intercept": fit[0], "slope": fit[1]}, "rep_fits": rep_fits,
                 "seconds_range": [min(secs), max(secs)], "rel_mse_range": [min(errs), max(errs)],
                 "points_below_resolution": len(every) - len(pts), "rungs": []}
        for spp in s.ladder:
            at = [r for r in every if r["spp"] == spp]
            entry["rungs"].append({"spp": spp, "seconds": spread([r["seconds"] for r in at]),
                                   "rel_mse": spread([r["rel_mse"] for r in at]),
                                   "rmse": spread([r["rmse"] for r in at])})
        medians = [(r["seconds"]["median"], r["rel_mse"]["median"]) for r in entry["rungs"] if r["rel_mse"]["n"]]
        for target in TARGETS:
            per_rep = [time_to_measured([r["seconds"] for r in pts if r["rep"] == k],
                                        [r["rel_mse"] for r in pts if r["rep"] == k], target, f)
                       for k, f in zip(reps, rep_fits)]
            t_all, how = time_to_measured([m[0] for m in medians], [m[1] for m in medians], target, fit)
            entry[f"time_to_{target:g}"] = {"all": t_all, **spread([t for t, _ in per_rep]), "how": how,
                                            "reps": [t for t, _ in per_rep]}
        how = "interpolated" if min(secs) <= cfg.budget <= max(secs) else "extrapolated"
        entry["rel_mse_at_budget"] = {"all": error_at(fit, cfg.budget),
                                      **spread([error_at(f, cfg.budget) for f in rep_fits]), "how": how}
        # Efficiency 1/(relMSE x seconds) at the largest rung: the classic single-number summary.
        top = [r for r in pts if r["spp"] == s.ladder[-1]]
        entry["efficiency_top_rung"] = spread([1.0 / (r["rel_mse"] * r["seconds"]) for r in top])
        out[s.label] = entry
    return out


def _ratios(info, cfg) -> dict:
    """Time-to-equal-error ratios between series of this scene, per repetition, at each
    target and at the relMSE that Tessera path reaches at the budget."""
    series = info["series"]
    pairs = []
    if "tessera path" in series and "tessera bdpt" in series:
        pairs.append(("tessera bdpt", "tessera path"))
    if "tessera path" in series and "tessera light" in series:
        pairs.append(("tessera light", "tessera path"))
    peer_ok = {tag: v.get("agree", False) for tag, v in info.get("peer", {}).items()}
    for label in series:
        if label.startswith("mitsuba"):
            tag = label.rsplit(" ", 1)[0]
            for mine in ("tessera path", "tessera bdpt"):
                if mine in series:
                    pairs.append((mine, label))
    out = {}
    for a, b in pairs:
        entry = {}
        for target in TARGETS:
            ta, tb = series[a][f"time_to_{target:g}"]["reps"], series[b][f"time_to_{target:g}"]["reps"]
            vals = [x / y for x, y in zip(ta, tb)]
            ea, eb = series[a][f"time_to_{target:g}"]["how"], series[b][f"time_to_{target:g}"]["how"]
            entry[f"{target:g}"] = {**spread(vals), "how": "interpolated" if ea == eb == "interpolated" else "extrapolated"}
        key = f"{a} / {b}"
        if b.startswith("mitsuba"):
            tag = b.rsplit(" ", 1)[0]
            entry["units_agree"] = peer_ok.get(tag, False)
        out[key] = entry
    return out


def add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", default=None,
                   help=f"comma-separated, from {', '.join(SCENES)} (default: all; --quick: cornell,cornell-lambert)")
    p.add_argument("--integrators", default=",".join(DEFAULT_INTEGRATORS),
                   help="comma-separated tessera integrators (default path,bdpt,light; local and whitted "
                        "estimate only a subset of light paths, so their error does not vanish)")
    p.add_argument("--quick", action="store_true", help="tiny sizes and ladders (a test, seconds)")
    p.add_argument("--out", help="output directory (default docs/benchmarks/error-vs-time; --quick: out/bench-quick)")
    p.add_argument("--res", type=int, help="image width and height in pixels")
    p.add_argument("--reps", type=int, help="interleaved repetitions (seeds)")
    p.add_argument("--budget", type=float, help="time budget in seconds for the equal-time error")
    p.add_argument("--peer", default=None,
                   help="Mitsuba variants to compare with, comma-separated, '' for none (default "
                        "scalar_rgb,llvm_ad_rgb; --quick: scalar_rgb), each optionally with a sampler "
                        "(llvm_ad_rgb/ldsampler; default independent). llvm_ad_rgb needs Debian's libllvm19")


def main(args: argparse.Namespace) -> int:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(f"tessera bench: needs matplotlib for its plots: {INSTALL_HINT}", file=sys.stderr)
        return 2
    cfg = quick_config() if args.quick else Config()
    if args.res:
        cfg.res = args.res
    if args.reps:
        cfg.reps = args.reps
    if args.budget:
        cfg.budget = args.budget
    names = [s for s in (args.scenes.split(",") if args.scenes else
                         (("cornell", "cornell-lambert") if args.quick else DEFAULT_SCENES)) if s]
    unknown = [n for n in names if n not in SCENES]
    if unknown:
        print(f"tessera bench: unknown scene(s) {', '.join(unknown)}; known: {', '.join(SCENES)}", file=sys.stderr)
        return 2
    integrators = [i for i in args.integrators.split(",") if i]
    from tessera_base import integrators as registry
    bad = [i for i in integrators if i not in [r["name"] for r in registry.integrators()]]
    if bad:
        print(f"tessera bench: unknown integrator(s) {', '.join(bad)}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else (REPO / "out" / "bench-quick" if args.quick else REPO / "docs" / "benchmarks" / "error-vs-time")
    peer_arg = args.peer if args.peer is not None else ("scalar_rgb" if args.quick else "scalar_rgb,llvm_ad_rgb")
    peers = tuple(v for v in peer_arg.split(",") if v)
    try:
        result = run(names, integrators, cfg, out, peers, log=lambda m: print(m, file=sys.stderr, flush=True))
    except FileNotFoundError as exc:
        print(f"tessera bench: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}/error-vs-time.csv, error-vs-time.json, error-vs-time-results.md and "
          f"{len(result['scenes'])} plots", file=sys.stderr)
    failed = [n for n, i in result["scenes"].items() if not i["reference"]["ok"]
              or (i["reference"].get("cross_check") and not i["reference"]["cross_check"]["agree"])
              or any(not v.get("agree", False) for v in i.get("peer", {}).values() if "error" not in v)]
    if failed:
        print(f"tessera bench: checks failed for {', '.join(failed)} (see error-vs-time-results.md)", file=sys.stderr)
        return 1
    return 0
