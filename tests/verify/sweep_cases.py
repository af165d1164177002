"""Module-level sweep functions for tests/verify/test_sweep.py: worker processes import them by name."""

import os
import time
from pathlib import Path


def square(payload):
    """{"y": x**2, "pid": ...} after sleeping payload["sleep_s"] (if given); raises for x == payload["fail_at"]."""
    x = payload["x"]
    time.sleep(payload.get("sleep_s", 0.0))
    if x == payload.get("fail_at"):
        raise ValueError(f"planned failure at x = {x}")
    return {"y": x**2, "pid": os.getpid()}


def meet(payload):
    """Wait until ``payload["n"]`` distinct processes have checked in under ``payload["dir"]``.

    A case that never meets the others returns after ``payload["wait_s"]`` with met=False,
    so a pool that runs everything in one process fails the test instead of hanging it.
    """
    folder = Path(payload["dir"])
    (folder / str(os.getpid())).touch()
    deadline = time.monotonic() + payload["wait_s"]
    while len(list(folder.iterdir())) < payload["n"] and time.monotonic() < deadline:
        time.sleep(0.01)
    return {"met": len(list(folder.iterdir())) >= payload["n"], "pid": os.getpid()}
