"""Foundations every Tessera layer above the renderer shares: the job/tile schema
(protocol), the image codec (images), tile passes and image assembly (film), the
integrator registry as Python sees it (integrators), denoising and process helpers.

It imports only tessera_renderer and third-party libraries (tests/test_layers.py)."""

__version__ = "0.1.0"
