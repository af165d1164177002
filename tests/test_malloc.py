"""The calibrate command's process keeps freed memory for its next arrays (``workbench._malloc``)."""

import subprocess
import sys

import pytest

_CHURN = """
import resource, sys
import numpy as np
from workbench._malloc import keep_freed_memory
on = sys.argv[1] == "1"
taken = keep_freed_memory() if on else None
n = int(sys.argv[2])
a = np.ones(n); del a
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    a = np.ones(n); b = a * 2.0
    assert b.sum() == 2.0 * n
    del a, b
print(taken, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(on, n):
    out = subprocess.run([sys.executable, "-c", _CHURN, "1" if on else "0", str(n)], capture_output=True,
                         text=True, check=True)
    taken, faults = out.stdout.split()
    return taken, int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
@pytest.mark.parametrize("n", [400_000, 3_000_000, 12_000_000])
def test_freed_arrays_are_reused_without_faulting_their_pages_again(n):
    """Arrays of 3 MB to 96 MB (a 355,000-row column to a 355,000 x 34 block), allocated and freed 20
    times: with glibc's defaults each fresh array is mapped and its pages faulted in again; with
    :func:`keep_freed_memory` the freed memory is reused (under a tenth of the faults)."""
    taken, on = _faults(True, n)
    _, off = _faults(False, n)
    if taken != "True":
        pytest.skip("not glibc: the defaults stay")
    assert on < 0.1 * off, (on, off)


def test_small_pages_stops_numpy_advising_huge_pages_in_its_process_only():
    """:func:`small_pages` turns numpy's ``madvise(MADV_HUGEPAGE)`` off in the calling process (a child
    here: the setting is permanent) and reports the setting it found; arrays compute the same."""
    code = ("import numpy as np\nfrom workbench._malloc import small_pages, huge_pages_advised\n"
            "before = huge_pages_advised()\na = np.arange(1_000_000.0)\ns0 = float(a @ a)\n"
            "was = small_pages()\nb = np.arange(1_000_000.0)\n"
            "print(before, was, huge_pages_advised(), float(b @ b) == s0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    before, was, after, same = out.stdout.split()
    assert was == before and after == "False" and same == "True"


def test_small_pages_without_numpys_switch_leaves_the_default(monkeypatch):
    """A numpy release without the private switch: the command still runs (None), nothing raised."""
    import workbench._malloc as m

    class _Bare:
        pass
    monkeypatch.setattr(m, "_numpy_multiarray", lambda: _Bare())
    assert m.small_pages() is None and m.huge_pages_advised() is None
