"""Checking a scene against its reference, rendering only as much as the decision needs.

A check renders the scene in looks: min_spp samples, then more until the totals have doubled
up to max_spp (16, 32, 64, ... by default), each look's new samples from a seed of their own
and pooled with the earlier ones (`accumulate`). After every look:

- DIFFERS when `tessera compare` (tessera.compare, every scale) finds a difference at
  alpha / L, L the number of looks the budget allows: a Bonferroni split over the looks, so
  an unchanged scene fails a whole check with probability at most alpha however early it
  stops. The check stops there.
- SAME when every region (RefSet.region pixels square) is shown to lie within the set's
  relative tolerance of the reference: per region and channel, with D the difference of the
  two region means and sigma its standard error (both images' noise),
  |D| + z sigma <= tolerance * max(reference mean, a tenth of the image's mean), z the
  one-sided normal quantile at alpha / (L * regions * channels) (two one-sided tests,
  Bonferroni over every region, channel and look). The check stops there too.
- otherwise it renders the next look; after the last one it passes as INCONCLUSIVE (nothing
  differs beyond noise, but some regions could not be shown to be within the tolerance at
  this budget), which `strict` turns into a failure.

The number of samples per pixel the decision took is in the result (and the report).
`render_reference` renders an entry's reference EXR the same way (or on a farm, reffarm.py);
it lives here, above the manifest (refs.py), which imports neither.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from tessera_base import images
from tessera_base.exr_header import scene_sha256
from tessera_tools import compare

from . import refs
from .refs import Reference, RefsError, RefSet

# Regions darker than this share of the image's mean are judged against that share of it,
# so that a nearly black corner (whose relative noise never falls) can still be decided.
DARK_FLOOR = 0.1
# Seeds of a check's looks start this far from the reference's own, so a check never
# repeats the reference's samples.
SEED_OFFSET = 1_000_003

Verdict = Literal["same", "differs", "inconclusive"]


@dataclass
class Look:
    spp: int                 # total samples per pixel after this look
    seed: int                # the seed of this look's new samples
    verdict: str             # compare's verdict at this look
    undecided_regions: int   # regions not yet shown to be within the tolerance
    seconds: float


@dataclass
class CheckResult:
    name: str
    verdict: Verdict
    passed: bool
    spp: int                                   # samples per pixel the decision took
    max_spp: int
    regions: int
    undecided_regions: int
    region: int                                # region edge in pixels
    looks: list[Look]
    comparison: compare.Comparison
    test: images.RenderImage
    reference: images.RenderImage
    seconds: float
    why: str                                   # one sentence: why it passed or failed
    notes: list[str] = field(default_factory=list)  # refs.status: what changed since


def look_schedule(budget: refs.CheckBudget) -> list[int]:
    """Total spp after each look: min_spp, doubling, ending at max_spp."""
    totals, n = [], budget.min_spp
    while n < budget.max_spp:
        totals.append(n)
        n *= 2
    totals.append(budget.max_spp)
    return totals


def render(scene_file: str | Path, ref: Reference, *, spp: int | None, seed: int, threads: int = 0,
           progress: bool = False, target_error: float | None = None, scene=None) -> images.RenderImage:
    """One local render of `ref`'s scene as an image with its noise estimate and metadata.
    `scene`: an already loaded tessera_renderer.Scene of that file (looks reuse it)."""
    from pydantic import ValidationError

    from tessera_renderer import SceneError, load_scene

    from tessera_base.exr_header import provenance
    from .local import render_image
    from tessera_base.protocol import RenderSettings

    if scene is None:
        try:
            scene = load_scene(scene_file)
        except SceneError as exc:
            raise RefsError(f"reference {ref.name}: {exc}") from None
    noise = {} if target_error is None else dict(target_error=target_error, max_spp=ref.spp)
    try:
        settings = RenderSettings(width=ref.width, height=ref.height, spp=spp or ref.spp, seed=seed,
                                  max_depth=ref.max_depth, integrator=ref.integrator,
                                  integrator_params=ref.integrator_params, **noise)
    except ValidationError as exc:
        raise RefsError(f"reference {ref.name}: invalid settings: {exc}") from None
    result = render_image(scene, settings, threads=threads, progress=progress, variance=True)
    if result.variance is None or result.spp is None:
        raise RefsError(f"reference {ref.name}: {ref.integrator} at {settings.spp} spp gives no noise "
                        f"estimate (a splatting integrator needs at least 2 spp)")
    meta = images.render_metadata(settings.max_spp if settings.adaptive else settings.spp, seed,
                                  Path(scene_file).name, settings.integrator, result.variance_kind)
    meta.update(provenance(scene_file, target_error, result.rgba, result.variance, result.spp,
                           result.variance_kind))
    return images.RenderImage(result.rgba, result.variance, result.spp, meta, result.variance_kind)


def render_reference(folder: str | Path, ref: Reference, *, threads: int = 0,
                     progress: bool = False, farm: str | None = None,
                     token: str | None = None) -> Reference:
    """Renders `ref` (locally, or on the farm at URL `farm`) into its EXR; returns the
    entry with its version, scene hash and where it was rendered filled in."""
    from . import __version__

    scene = refs.scene_path(folder, ref)
    if not scene.is_file():
        raise RefsError(f"reference {ref.name}: scene {scene} does not exist")
    spp = ref.spp if ref.target_error is None else None
    out = Path(folder) / ref.exr
    out.parent.mkdir(parents=True, exist_ok=True)
    if farm:
        from .reffarm import render_on_farm

        render_on_farm(farm, token, scene, ref, out)
    else:
        image = render(scene, ref, spp=spp, seed=ref.seed, threads=threads, progress=progress,
                       target_error=ref.target_error)
        images.write_exr(out, image.rgba, image.metadata,
                         aovs={"variance": image.variance, "spp": image.spp})
    return ref.model_copy(update={"tessera_version": __version__, "scene_sha256": scene_sha256(scene),
                                  "rendered_on": "farm" if farm else "local"})


def accumulate(a: images.RenderImage | None, b: images.RenderImage) -> images.RenderImage:
    """Pools two independent renders of the same image into one of their samples together.
    per-sample: the exact pooled mean and sample variance; batch-means:K1 and :K2: the
    weighted mean, its variance (n1^2 s1 + n2^2 s2) / N^2 and K1 + K2 - 1 'batches' (the
    degrees of freedom add)."""
    if a is None:
        return b
    ka, kb = images.parse_variance_kind(a.variance_kind), images.parse_variance_kind(b.variance_kind)
    if ka[0] != kb[0]:
        raise RefsError(f"cannot pool a {a.variance_kind} with a {b.variance_kind} image")
    n1, n2 = a.spp.astype(np.float64), b.spp.astype(np.float64)
    n = n1 + n2
    w1, w2 = (n1 / n)[..., None], (n2 / n)[..., None]
    m1, m2 = a.rgba.astype(np.float64), b.rgba.astype(np.float64)
    rgba = w1 * m1 + w2 * m2
    v1, v2 = a.variance.astype(np.float64), b.variance.astype(np.float64)
    if ka[0] == images.VARIANCE_PER_SAMPLE:
        between = (n1 * n2 / n)[..., None] * (m1[..., :3] - m2[..., :3]) ** 2
        var = ((n1 - 1)[..., None] * v1 + (n2 - 1)[..., None] * v2 + between) / np.maximum(n - 1, 1)[..., None]
        kind = images.VARIANCE_PER_SAMPLE
    else:
        var = w1 * w1 * v1 + w2 * w2 * v2
        kind = images.batch_means_kind(ka[1] + kb[1] - 1)
    meta = dict(b.metadata)
    meta["tessera:spp"] = str(int(round(float(n.mean()))))
    meta[images.VARIANCE_ATTRIBUTE] = kind
    return images.RenderImage(rgba.astype(np.float32), var.astype(np.float32), n.astype(np.float32),
                              meta, kind)


def _mean_variance(image: images.RenderImage) -> np.ndarray:
    """The variance of each pixel's mean, (h, w, 3)."""
    kind = images.parse_variance_kind(image.variance_kind)
    var = image.variance.astype(np.float64)
    if kind[0] == images.VARIANCE_PER_SAMPLE:
        return var / np.maximum(image.spp.astype(np.float64), 1.0)[..., None]
    return var


def undecided_regions(test: images.RenderImage, reference: images.RenderImage, *, region: int,
                      tolerance: float, level: float) -> tuple[np.ndarray, int]:
    """(undecided map per region (rows, cols), number of region-channel tests): the regions
    not yet shown, at one-sided level `level` per region and channel, to lie within
    `tolerance` of the reference (module docstring)."""
    from scipy import stats

    a = test.rgba[..., :3].astype(np.float64)
    b = reference.rgba[..., :3].astype(np.float64)
    s = _mean_variance(test) + _mean_variance(reference)
    finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(s)
    a, b, s = np.where(finite, a, 0.0), np.where(finite, b, 0.0), np.where(finite, s, 0.0)
    sums = [compare._block_sums(x, region, region) for x in (a, b, s, np.ones_like(a))]
    sa, sb, ss, m = sums
    tests = int(sa.size)
    z = float(stats.norm.isf(level / max(tests, 1)))
    floor = DARK_FLOOR * np.abs(b.reshape(-1, 3).mean(axis=0))       # per channel
    margin = tolerance * np.maximum(np.abs(sb), floor * m)
    undecided = np.abs(sa - sb) + z * np.sqrt(ss) > margin
    bad = compare._block_sums((~finite).astype(np.float64), region, region) > 0
    return (undecided | bad).any(axis=2), tests


def region_z(test: images.RenderImage, reference: images.RenderImage, region: int) -> np.ndarray:
    """Per region (rows, cols): the difference of the region means over its standard error,
    signed, of the channel where it is largest (for the report's region map)."""
    a = test.rgba[..., :3].astype(np.float64)
    b = reference.rgba[..., :3].astype(np.float64)
    s = _mean_variance(test) + _mean_variance(reference)
    finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(s)
    d = compare._block_sums(np.where(finite, a - b, 0.0), region, region)
    v = compare._block_sums(np.where(finite, s, 0.0), region, region)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(v > 0, d / np.sqrt(v), 0.0)
    pick = np.abs(z).argmax(axis=2)[..., None]
    return np.take_along_axis(z, pick, axis=2)[..., 0]


def check(folder: str | Path, refset: RefSet, ref: Reference, *, seed: int | None = None,
          threads: int = 0, strict: bool = False, progress: bool = False,
          scene_file: str | Path | None = None) -> CheckResult:
    """Renders `ref`'s scene (or `scene_file` in its place: a variant, say) look after look
    and decides it against the reference EXR (module docstring)."""
    from tessera_renderer import SceneError, load_scene

    folder = Path(folder)
    scene_file = Path(scene_file) if scene_file else refs.scene_path(folder, ref)
    if not scene_file.is_file():
        raise RefsError(f"reference {ref.name}: scene {scene_file} does not exist")
    try:
        reference = compare.load(folder / ref.exr, f"reference {ref.name}:")
    except compare.CompareError as exc:
        raise RefsError(str(exc)) from None
    if reference.rgba.shape[:2] != (ref.height, ref.width):
        raise RefsError(f"reference {ref.name}: {ref.exr} is not {ref.width}x{ref.height}")
    try:
        scene = load_scene(scene_file)
    except SceneError as exc:
        raise RefsError(f"reference {ref.name}: {exc}") from None
    totals = look_schedule(ref.check)
    n_looks = len(totals)
    alpha = refset.alpha / n_looks
    base = ref.seed + SEED_OFFSET if seed is None else seed
    if base <= ref.seed < base + n_looks:
        raise RefsError(f"check seeds {base}..{base + n_looks - 1} include the reference's own "
                        f"seed {ref.seed}: pick another --seed")
    start = time.perf_counter()
    pooled, looks, done = None, [], 0
    for k, total in enumerate(totals):
        t0 = time.perf_counter()
        new = render(scene_file, ref, spp=total - done, seed=base + k, threads=threads,
                     progress=progress, scene=scene)
        pooled, done = accumulate(pooled, new), total
        comparison = compare.compare_images(pooled, reference, alpha=alpha, flip=False, pooled=True)
        undecided, tests = undecided_regions(pooled, reference, region=refset.region,
                                             tolerance=refset.tolerance, level=alpha)
        looks.append(Look(total, base + k, comparison.report.verdict, int(undecided.sum()),
                          time.perf_counter() - t0))
        if comparison.report.differs or not undecided.any():
            break
    # The report's FLIP (not part of the decision) on the final images only.
    comparison = compare.compare_images(pooled, reference, alpha=alpha, flip=True, pooled=True)
    regions = int(undecided.size)
    n_undecided = int(undecided.sum())
    if comparison.report.differs:
        verdict, passed = "differs", False
        why = (f"differs from the reference beyond noise after {done} spp: "
               + "; ".join(comparison.report.reasons))
    elif n_undecided == 0:
        verdict, passed = "same", True
        why = (f"the same: every one of {regions} regions lies within {refset.tolerance:.1%} of the "
               f"reference at confidence {1 - refset.alpha:g}, decided after {done} of at most "
               f"{totals[-1]} spp")
    else:
        verdict, passed = "inconclusive", not strict
        why = (f"no difference beyond noise at {done} spp, but {n_undecided} of {regions} regions "
               f"could not be shown to lie within {refset.tolerance:.1%} of the reference at this "
               f"budget" + (" (strict: fails)" if strict else ""))
    return CheckResult(ref.name, verdict, passed, done, totals[-1], regions, n_undecided, refset.region, looks,
                       comparison, pooled, reference, time.perf_counter() - start, why,
                       refs.status(folder, ref))
