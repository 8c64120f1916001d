"""`tessera.render`: a local render as a Python object. It goes through the same tile
passes and image assembly as `tessera render` and the farm (tessera.local.render_image,
tessera_base.film), so the image's splats are already normalised whatever the integrator
and the pixels equal the CLI's and the farm's bit for bit."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

if TYPE_CHECKING:  # numpy loads with the renderer, not on `import tessera`
    import numpy as np


@dataclass
class Image:
    """A rendered image: float32 linear RGBA (h, w, 4), its layers and how it was made.

    `layers` maps a layer name (tessera_base.images.AOV_EXR_CHANNELS: albedo, normal,
    depth, spp, variance, denoised) to a float32 (h, w) or (h, w, c) array, exactly the
    extra channels `tessera render` writes to the EXR. `metadata` holds the EXR header
    attributes (tessera:spp, tessera:seed, tessera:scene, tessera:integrator,
    tessera:variance, tessera:version) plus, under plain keys, what the render measured
    (integrator as resolved, seconds, samples, passes, warnings)."""

    rgba: np.ndarray
    layers: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def rgb(self) -> np.ndarray:
        """The beauty without alpha, (h, w, 3)."""
        return self.rgba[..., :3]

    @property
    def width(self) -> int:
        return int(self.rgba.shape[1])

    @property
    def height(self) -> int:
        return int(self.rgba.shape[0])

    def header(self) -> dict[str, str]:
        """The EXR header attributes (the `tessera:` keys of metadata)."""
        return {k: str(v) for k, v in self.metadata.items() if k.startswith("tessera:")}

    def write(self, path: str | Path, *, png: bool = False,
              crop: tuple[int, int, int, int] | None = None) -> Path:
        """Writes the image as `tessera render` does: float EXR with every layer; with
        `png`, an sRGB preview beside it (same name, .png); with `crop` (x0, y0, x1, y1,
        exclusive), only that region as the data window inside the full display window."""
        from tessera_base.images import write_exr, write_png_preview

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_exr(path, self.rgba, self.header(), aovs=self.layers, crop=crop)
        if png:  # a crop's preview is the crop
            x0, y0, x1, y1 = crop or (0, 0, self.width, self.height)
            write_png_preview(path.with_suffix(".png"), self.rgba[y0:y1, x0:x1])
        return path

    @classmethod
    def read(cls, path: str | Path) -> "Image":
        """An EXR written by Tessera (locally, by `write`, or downloaded from a farm)."""
        from tessera_base.images import read_exr, read_exr_aovs
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            raise OSError(f"cannot open {path}: {oiio.geterror()}")
        try:
            header = {a.name: str(a.value) for a in inp.spec().extra_attribs if a.name.startswith("tessera:")}
        finally:
            inp.close()
        return cls(read_exr(path), read_exr_aovs(path), header)


def render(scene: str | Path | Any, *, spp: int = 64, integrator: str | None = None,
           res: tuple[int, int] | None = None, aovs: Iterable[str] = (), seed: int = 0,
           max_depth: int | None = None, tile_size: int | None = None,
           target_error: float | None = None, min_spp: int | None = None,
           max_spp: int | None = None, time_limit: float | None = None,
           integrator_params: Mapping[str, float] | None = None, denoise: bool = False,
           variance: bool = True, threads: int = 0, progress: bool = False,
           frame: float | None = None, root: str | Path | None = None,
           default_light: bool = True, subdivision_level: int | None = None,
           camera: str | None = None, shutter: tuple[float, float] | None = None,
           variants: Sequence[str] = (), crop: tuple[int, int, int, int] | None = None,
           **settings: Any) -> Image:
    """Renders `scene` locally and returns the image.

    `scene` is a USD file or .zip/.usdz bundle path, or a scene already loaded with
    tessera_renderer.load_scene (then frame, root, default_light, subdivision_level, camera
    shutter and variants are the loader's business). `variants` select variants in place of
    the stage's own, each `/Prim/Path:set=value`. `frame` is the time code to render (default:
    the stage's startTimeCode); `shutter` (open, close) replaces the camera's
    shutter:open/close, in time codes from the frame ((0, 0): no motion blur). `camera` is the path of the Camera prim to render
    through (default: the RenderSettings' camera, else the first camera, else a default
    three-quarter view). `res` is (width, height); by default the stage's
    UsdRenderSettings or 512x512. `integrator` is a registered name (default: the
    registry's first; `tessera render --integrator help` lists them). `aovs` names extra
    layers (albedo, normal, depth, spp, variance). With `variance` (the default) the image
    also carries the noise estimate `tessera.compare` needs (variance and spp layers).
    `target_error` renders to a noise target instead of a fixed spp (min_spp, max_spp,
    time_limit bound it). `crop` (x0, y0, x1, y1, exclusive) renders only that region
    (pixels outside it stay 0; write the image with the same crop). Everything else is as
    for `tessera render`; `dicing_rate` (with `dicing_max_level`, `dicing_memory`) chooses
    subdivision levels from the camera at `res` when `subdivision_level` is None;
    any other render setting (tessera_base.protocol.SETTINGS, e.g. seed_offset) is a keyword
    of its own name.

    Raises tessera_renderer.SceneError when the scene cannot be read, ValueError for
    settings out of range (pydantic's ValidationError is a ValueError)."""
    from tessera_base.protocol import SETTINGS, RenderSettings

    if unknown := sorted(set(settings) - set(SETTINGS)):
        raise TypeError(f"render() got an unknown setting {unknown[0]!r} (settings: {', '.join(SETTINGS)})")
    loaded = _load(scene, frame=frame, root=root, default_light=default_light,
                   subdivision_level=subdivision_level, camera=camera, shutter=shutter, variants=variants,
                   dicing=(settings.get("dicing_rate"), settings.get("dicing_max_level"),
                           settings.get("dicing_memory"), res))
    width, height = res or (loaded.width, loaded.height)
    optional = dict(integrator=integrator, max_depth=max_depth, tile_size=tile_size,
                    target_error=target_error, min_spp=min_spp, max_spp=max_spp, time_limit=time_limit)
    settings = RenderSettings(width=width, height=height, spp=spp, seed=seed, aovs=list(aovs),
                              denoise=denoise, integrator_params=dict(integrator_params or {}), crop=crop,
                              **{k: v for k, v in optional.items() if v is not None}, **settings)
    if settings.denoise:
        from tessera_base.denoise import unavailable_reason

        if (reason := unavailable_reason()) is not None:
            raise RuntimeError(f"denoise: {reason}")
    name = Path(scene).name if isinstance(scene, (str, Path)) else "scene"
    image = render_scene(loaded, settings, scene_name=name, threads=threads, progress=progress,
                         variance=variance)
    if isinstance(scene, (str, Path)):
        from tessera_base.exr_header import scene_sha256

        image.metadata["tessera:scene_sha256"] = scene_sha256(scene)
    return image


def render_scene(scene, settings, *, scene_name: str, threads: int = 0, progress: bool = False,
                 variance: bool = True, log=None) -> Image:
    """`render` for a loaded tessera_renderer.Scene and checked
    tessera_base.protocol.RenderSettings (what `tessera render` calls once it has reported
    the scene and the settings). Integrator `auto` runs a pilot first (tessera.pilot) and
    renders with the measured choice; `log`, if given, receives its one-line summary."""
    from tessera_base import integrators
    from tessera_base.images import render_metadata

    from .local import render_image

    pilot = None
    if settings.integrator == integrators.AUTO:
        from .pilot import run_pilot

        pilot = run_pilot(scene, settings, threads=threads)
        settings = settings.model_copy(update={"integrator": pilot.choice})
        if log is not None:
            log(pilot.summary())
    result = render_image(scene, settings, threads=threads, progress=progress, variance=variance)
    # The noise estimate `tessera compare` needs rides along as layers; for light and bdpt
    # it is the batch estimate, never the camera half's per-sample variance.
    layers = dict(result.aovs)
    if result.variance is not None:
        layers["variance"] = result.variance
        layers.setdefault("spp", result.spp)
    variance_kind = result.variance_kind if "variance" in layers and result.variance is not None else None
    metadata: dict[str, Any] = render_metadata(settings.max_spp if settings.adaptive else settings.spp,
                                               settings.sample_seed, scene_name, settings.integrator, variance_kind)
    from tessera_base.exr_header import noise_attributes

    from tessera_base.protocol import in_crop

    metadata.update(noise_attributes(settings.target_error, in_crop(settings, result.rgba),
                                     in_crop(settings, layers.get("variance")), in_crop(settings, layers.get("spp")),
                                     variance_kind))
    metadata.update(integrator=result.integrator, seconds=result.seconds, samples=result.samples,
                    samples_per_second=result.samples_per_second, passes=result.passes,
                    warnings=[*getattr(scene, "warnings", []),
                              *integrators.scene_warnings(result.integrator,
                                                          curve_segments=getattr(scene, "num_curve_segments", 0),
                                                          linked_lights=getattr(scene, "num_linked_lights", 0),
                                                          media=getattr(scene, "has_media", False))],
                    denoise_warning=result.denoise_warning, black_warning=result.black_warning)
    if pilot is not None:
        metadata["tessera:auto"] = pilot.to_json()
        metadata["auto_pilot"] = pilot.summary()
    return Image(result.rgba, layers, metadata)


def _load(scene, *, frame, root, default_light, subdivision_level, camera, shutter=None, variants=(),
          dicing=None):
    if not isinstance(scene, (str, Path)):
        return scene
    from tessera_base.protocol import parse_variant
    from tessera_renderer import SceneError, load_scene
    from tessera_renderer.usd.dicing import Dicing

    try:
        selections = [parse_variant(v) for v in variants]
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    return load_scene(scene, frame=frame, root=root, default_light=default_light,
                      subdivision_level=subdivision_level, camera=camera, shutter=shutter, variants=selections,
                      dicing=Dicing.requested(*dicing) if dicing else None)
