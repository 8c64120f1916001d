"""Tessera render worker: renders tiles from the Redis stream (see worker.py)."""
from .worker import default_worker_name, run_worker

__all__ = ["run_worker", "default_worker_name"]
