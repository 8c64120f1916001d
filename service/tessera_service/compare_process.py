"""/compare in a child process with a time and memory limit, as pre-flight inspection runs.

Comparing two renders in the API process cost it about 700 bytes per pixel (two 2048²
EXRs of 219 KB each held the API at 3.1 GB for 31 s; the 64 Mpx limit of the comparison
would be about 45 GB), and Python returns little of that to the system afterwards. In a
child, the memory is bounded by RLIMIT_AS and given back when the child exits; images over
a pixel limit are refused from their headers before any pixel is decoded.

The child is `python -m tessera_tools.compare_child TEST REFERENCE OPTIONS_JSON`.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from tessera_base.process import limited_child

# The child imports only the comparison (not this package, which imports the whole API).
MODULE = "tessera_tools.compare_child"


class CompareRefused(Exception):
    """The comparison cannot be made; `status` is the HTTP status, the message the client's."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def compare_in_child(test: Path, reference: Path, *, alpha: float, method: str, flip: bool,
                     max_pixels: int, memory_bytes: int, timeout: float) -> dict:
    """The comparison report (CompareReport as a dict); CompareRefused when it cannot be
    made (CompareError: 422; an image over `max_pixels` or the memory limit: 413)."""
    options = {"alpha": alpha, "method": method, "flip": flip, "max_pixels": max_pixels}
    # One malloc arena per thread would reserve 64 MB of address space each (see preflight).
    env = {**os.environ, "MALLOC_ARENA_MAX": "2"}
    try:
        proc = subprocess.run([sys.executable, "-m", MODULE, str(test), str(reference),
                               json.dumps(options)],
                              stdin=subprocess.DEVNULL, capture_output=True, env=env,
                              timeout=timeout, preexec_fn=limited_child(memory_bytes))
    except subprocess.TimeoutExpired:
        raise CompareRefused(503, f"the comparison took longer than {timeout:g} s "
                                  f"(TESSERA_COMPARE_TIMEOUT)") from None
    lines = proc.stdout.decode(errors="replace").strip().splitlines()
    try:
        answer = json.loads(lines[-1]) if lines else None
    except ValueError:
        answer = None
    if isinstance(answer, dict) and "report" in answer:
        return answer["report"]
    if isinstance(answer, dict) and "error" in answer:
        raise CompareRefused(int(answer.get("status", 422)), str(answer["error"]))
    stderr = proc.stderr.decode(errors="replace")
    if "MemoryError" in stderr or "bad_alloc" in stderr or proc.returncode == -signal.SIGKILL:
        raise CompareRefused(413, "the images are too large to compare within the comparison's "
                                  f"memory limit ({memory_bytes >> 20} MiB, "
                                  "TESSERA_COMPARE_MEMORY_BYTES)")
    if "failed to map segment" in stderr:  # a library could not even be loaded
        raise RuntimeError(f"the comparison's memory limit ({memory_bytes >> 20} MiB, "
                           f"TESSERA_COMPARE_MEMORY_BYTES) is too small to start it")
    tail = " | ".join(stderr.strip().splitlines()[-3:])
    raise RuntimeError(f"the comparison process failed (exit {proc.returncode}): {tail}")
