"""Redis's replies as Python values, and its refusal of a write for lack of memory."""
from __future__ import annotations

import redis


def text(value) -> str:
    if value is None:
        return ""
    return value.decode() if isinstance(value, bytes) else str(value)


def to_float(value) -> float | None:
    value = text(value)
    return float(value) if value else None


def out_of_memory(error: redis.ResponseError) -> bool:
    """Redis refused a write at its maxmemory (noeviction); redis-py strips the OOM code
    from some of these (errors inside scripts and transactions)."""
    return isinstance(error, redis.exceptions.OutOfMemoryError) or "maxmemory" in str(error)
