"""Tessera HTTP service: accepts USD uploads, queues tile tasks, serves merged images.

It never imports pxr or the renderer: untrusted scenes are inspected in a subprocess."""
from .app import create_app
from .settings import Settings

__all__ = ["create_app", "Settings"]
