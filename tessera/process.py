"""Child processes that do not outlive their parent (the embedded farm's Redis and
workers, a worker's render process)."""
from __future__ import annotations

import signal
import sys


def _load_prctl():
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes
        return ctypes.CDLL(None).prctl
    except (OSError, AttributeError):
        return None


_prctl = _load_prctl()  # looked up here: a child after fork should only call it
_PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """In a child (e.g. as preexec_fn): receive `sig` when the parent dies (Linux only)."""
    if _prctl is not None:
        _prctl(_PR_SET_PDEATHSIG, int(sig))
