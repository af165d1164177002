"""The closed-loop benchmark's claims in reduced form: chunking is invisible, memory does not grow with the run.

No timing assertions (figures come from `workbench bench`).
"""

import importlib.util

import pytest

from workbench.bench import _hold
from workbench.verify.closed_loop import CHUNK


@pytest.fixture(scope="module")
def memory(root):
    spec = importlib.util.spec_from_file_location("closed_loop_memory", root / "benchmarks" / "closed_loop_memory.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_hold_is_the_same_in_one_call_or_two(root):
    n, first, dec = 200_000, 70_000, 1000
    assert n > CHUNK > first          # the one call crosses a chunk boundary, the split one elsewhere
    paths = (root / "plants" / "p888_51_sn637_creep.toml", root / "controllers" / "sn637_loopshape.json")
    one, ref = _hold(*paths, noise=False)
    whole = one.run(ref, decimate=dec, periods=n)
    two, _ = _hold(*paths, noise=False)
    two.run(ref, decimate=dec, periods=first)
    tail = two.run(ref, decimate=dec, periods=n - first)
    assert two.u == pytest.approx(one.u, abs=1e-12, rel=0)
    assert tail.x_m[-1] == pytest.approx(whole.x_m[-1], abs=1e-12, rel=0)
    assert tail.t_s[-1] == pytest.approx(whole.t_s[-1])


def test_peak_memory_does_not_grow_with_the_run(memory, root, monkeypatch):
    monkeypatch.chdir(root)
    short, _ = memory.peak_rss_mb(200_000, 1000)
    long, _ = memory.peak_rss_mb(2_000_000, 1000)
    assert long - short < 30.0
