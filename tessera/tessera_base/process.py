"""Child processes that do not outlive their parent (the embedded farm's Redis and
workers, a worker's render process, the API's scene inspection), and temporary
directories that do not outlive a crash of their owner by more than its next start."""
from __future__ import annotations

import os
import shutil
import signal
import sys
import tempfile


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


def limited_child(memory_bytes: int):
    """A preexec_fn for a child that must not outlive the API nor exceed `memory_bytes` of
    address space (0: no limit), and writes no core file (a pre-flight inspection, a
    comparison). It runs between fork and exec, so it does as little as it can."""
    import resource

    def apply() -> None:
        die_with_parent(signal.SIGKILL)  # a killed API must not leave a 5 GB child running
        if memory_bytes > 0:
            resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    return apply


def private_tempdir(kind: str) -> str:
    """A fresh directory tessera-<kind>-<pid>-XXXX in the temporary directory: the pid in
    its name lets the next process of that kind remove it if this one is killed."""
    return tempfile.mkdtemp(prefix=f"tessera-{kind}-{os.getpid()}-")


def remove_orphaned_tempdirs(kind: str) -> list[str]:
    """Removes the private_tempdir(kind) directories whose process no longer runs (a
    SIGKILL leaves them, holding users' scenes). Returns their paths."""
    removed = []
    root = tempfile.gettempdir()
    prefix = f"tessera-{kind}-"
    for name in os.listdir(root):
        if not name.startswith(prefix):
            continue
        pid = name[len(prefix):].split("-", 1)[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        path = os.path.join(root, name)
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"

