"""The calibrate command's own process: freed memory kept for its next arrays (glibc's ``mallopt``), 4 kB pages.

A calibration allocates and frees many temporaries of 355,000 x k floats (Gram products per
block, projected columns, shifted copies). glibc serves every allocation above its mmap threshold
(128 kB, raised dynamically up to 32 MB) with a fresh ``mmap`` and returns it with ``munmap`` on
``free``: the next array of the same size faults its pages in again and the kernel zeroes them,
system time that counts in the command's CPU figure (the creep protocol record: 282,000 minor
faults; with the heap kept, 126,000 and ~0.6 s less system time, issue 13's speed floor). Here
allocations come from the heap and freed memory stays in it (no trim below 2 GB): the same numbers,
computed in memory the process already touched. The settings are process-wide and permanent, so
only the command-line process (``workbench calibrate`` / ``python -m workbench calibrate``, which
exits after its run) takes them; an in-process ``cli.main([...])`` call (a test) and a library caller
keep glibc's defaults unless they call :func:`keep_freed_memory`. When a ``mallopt`` call is refused,
the ones before it stay applied (each is harmless alone) and False is returned.

:func:`small_pages` (session 16, the same command process only) stops numpy asking the kernel for
transparent huge pages (``madvise(MADV_HUGEPAGE)`` on every array of 4 MB and more): on a kernel whose
huge-page defrag is ``madvise`` (this machine's), each such fault compacts memory synchronously, and the
speed benchmark's creep record spent 3.4 s of system time against 1.2-1.5 s with 4 kB pages (user time
unchanged within the run-to-run spread, 17.3-17.7 s; the same arrays, the same numbers).
"""

import ctypes
import sys

__all__ = ["keep_freed_memory", "small_pages", "huge_pages_advised"]

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_MAX = -4


def keep_freed_memory():
    """Serve large allocations from the heap and keep freed memory in it (glibc only).

    Returns
    -------
    bool
        True when glibc took the settings; False elsewhere (another C library, no ``mallopt``):
        the defaults stay, nothing else changes.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_MAX, 0) and mallopt(_M_TRIM_THRESHOLD, 2 ** 31 - 1)
                and mallopt(_M_TOP_PAD, 64 << 20))


def small_pages():
    """Stop numpy advising transparent huge pages for its large arrays (process-wide, permanent).

    Returns
    -------
    bool or None
        numpy's setting before the call (True: it advised huge pages); None when this numpy has no
        such switch (a private function: a release without it leaves the default, the command runs).
        Nothing is computed differently: the same arrays live in 4 kB pages.
    """
    multiarray = _numpy_multiarray()
    switch = getattr(multiarray, "_set_madvise_hugepage", None)
    if switch is None:
        return None
    return bool(switch(False))


def huge_pages_advised():
    """numpy's current huge-page advice (True, False), or None when this numpy has no such switch."""
    get = getattr(_numpy_multiarray(), "_get_madvise_hugepage", None)
    return None if get is None else bool(get())


def _numpy_multiarray():
    try:
        from numpy._core import multiarray
    except ImportError:                 # numpy < 2
        from numpy.core import multiarray
    return multiarray
