"""Tessera's Python API: what users script.

    import tessera
    image = tessera.render("scene.usda", spp=64, integrator="bdpt", res=(256, 256), aovs=["albedo"])
    image.rgba, image.layers["albedo"], image.metadata    # numpy arrays and how it was made
    image.write("out/scene.exr")
    report = tessera.compare(image, "reference.exr")     # report.differs, report.summary()
    with tessera.Client("http://farm:8000", token="TOKEN") as farm:
        job = farm.submit("scene.usda", spp=64)
        farm.wait(job.id)
        same = farm.download(job.id)                      # bit for bit tessera.render's image

The `tessera` command (tessera_cli.cli) is a thin layer over these. Heavy modules (the
renderer, OpenImageIO) load on first use, not on `import tessera`.
"""
from tessera_base import __version__

from .comparison import compare, comparison
from .rendering import Image, render

__all__ = ["Client", "FarmError", "Image", "Job", "__version__", "compare", "comparison", "render"]


def __getattr__(name: str):
    # The farm client loads httpx (about a second); the CLI's local commands never need it.
    if name in ("Client", "FarmError", "Job"):
        from . import client

        return getattr(client, name)
    raise AttributeError(f"module 'tessera' has no attribute {name!r}")
