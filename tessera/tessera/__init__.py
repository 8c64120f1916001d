"""Tessera: the public Python API and the `tessera` command (tessera.cli)."""
from tessera_base import __version__

__all__ = ["__version__"]
