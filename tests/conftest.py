"""Shared fixtures: the plant files and loaded plants; the hypothesis profiles.

Hypothesis runs derandomized by default (profile "ci": the examples follow from each
test's source, no example database, no deadline), so `make test` draws the same
examples on every run and machine. ``HYPOTHESIS_PROFILE=explore`` draws fresh random
examples (and keeps a local database) to hunt for new failures; a failure found that
way should become an ``@example`` on the test.
"""

import os

# One BLAS thread per test process: `make test` runs one pytest-xdist worker per core, and
# OpenBLAS's own threads on top of those oversubscribe the cores (the calibration tests' Gram
# solves slowed several-fold). Set before numpy loads OpenBLAS, so child processes (CLI runs,
# dask workers) inherit it; threadpoolctl covers a numpy already loaded by a plugin.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

threadpool_limits(1)
import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, deadline=None, print_blob=True)
settings.register_profile("explore", derandomize=False, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

from workbench.plant import load_plant

ROOT = Path(__file__).resolve().parents[1]
PLANTS = ROOT / "plants"
SERIALS = ("sn637", "sn629", "sn618")
FULL = os.environ.get("WORKBENCH_FULL") == "1"


def load_benchmark(name):
    """A script of ``benchmarks/`` loaded as a module (its functions, not its ``main``)."""
    import importlib.util
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def root():
    return ROOT


@pytest.fixture(scope="session")
def sn637():
    return load_plant(PLANTS / "p888_51_sn637.toml")


@pytest.fixture(scope="session")
def sn637_creep():
    return load_plant(PLANTS / "p888_51_sn637_creep.toml")


@pytest.fixture(scope="session", params=SERIALS)
def any_serial(request):
    return load_plant(PLANTS / f"p888_51_{request.param}.toml")


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


@pytest.fixture
def stable_rss():
    """``stable_rss(seed, states, outputs, inputs, margin, **kw)``: a seeded, stable ``control.rss``.

    python-control 0.10's ``rss`` draws from numpy's global random state, so an unseeded test
    draws a new system on every run. This seeds the global state for the draw (redrawing until
    every pole's real part is below ``-margin``) and restores it afterwards.
    """
    import control

    def draw(seed, states, outputs, inputs, margin, **kw):
        saved = np.random.get_state()
        np.random.seed(seed)
        try:
            sys_ = control.rss(states, outputs, inputs, **kw)
            while np.any(sys_.poles().real > -margin):
                sys_ = control.rss(states, outputs, inputs, **kw)
        finally:
            np.random.set_state(saved)
        return sys_

    return draw
