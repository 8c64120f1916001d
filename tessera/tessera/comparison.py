"""`tessera.compare`: do two renders differ beyond their Monte Carlo noise? The statistics
are tessera_tools.compare's (docs/accuracy.md); this takes images as files or as
tessera.Image objects."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Union

if TYPE_CHECKING:
    from tessera_tools.compare import CompareReport, Comparison

    from .rendering import Image

Source = Union[str, Path, "Image"]


def compare(test: Source, reference: Source, *, alpha: float | None = None, method: str = "bh",
            flip: bool = True, pooled: bool = False) -> "CompareReport":
    """Compares `test` with `reference` (EXR paths written by Tessera, or Image objects
    from tessera.render; each needs its variance and spp layers) and returns the report:
    `report.differs`, `report.summary()`, per-scale statistics, RMSE, relMSE and FLIP.
    `alpha` is the false-alarm rate (default tessera_tools.compare.ALPHA), `method` the
    multiple-testing correction ("bh" or "bonferroni"); `pooled` judges both sides with one
    pooled per-sample variance (for a cheap render against a costly reference; see
    docs/accuracy.md). Raises
    tessera_tools.compare.CompareError (a ValueError) for images that cannot be judged."""
    return comparison(test, reference, alpha=alpha, method=method, flip=flip, pooled=pooled).report


def comparison(test: Source, reference: Source, *, alpha: float | None = None, method: str = "bh",
               flip: bool = True, pooled: bool = False) -> "Comparison":
    """`compare` with the per-pixel maps behind the report (for
    tessera_tools.compare.heatmap)."""
    from tessera_tools import compare as library

    kwargs = dict(alpha=library.ALPHA if alpha is None else alpha, method=method, flip=flip, pooled=pooled)
    if isinstance(test, (str, Path)) and isinstance(reference, (str, Path)):
        return library.compare_files(test, reference, **kwargs)
    return library.compare_images(_render_image(test, "TEST"), _render_image(reference, "REFERENCE"),
                                  **kwargs)


def _render_image(source: Source, role: str):
    """One side as the library's RenderImage (compare_images checks its variance as it
    checks a file's)."""
    from tessera_base import images
    from tessera_tools import compare as library

    if isinstance(source, (str, Path)):
        return library.load(source, role)
    variance, spp = source.layers.get("variance"), source.layers.get("spp")
    if variance is None or spp is None:
        raise library.CompareError(f"{role} has no variance and spp layers: render it with variance=True")
    header = source.header()
    return images.RenderImage(source.rgba, variance, spp, header, header.get(images.VARIANCE_ATTRIBUTE))
