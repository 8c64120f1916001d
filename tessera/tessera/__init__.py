"""Tessera: shared pieces of the farm (job/tile protocol, image files) and the CLI."""

__version__ = "0.1.0"
