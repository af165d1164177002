"""Shared fixtures: the plant files and loaded plants."""

import os
from pathlib import Path

import numpy as np
import pytest

from workbench.plant import load_plant

ROOT = Path(__file__).resolve().parents[1]
PLANTS = ROOT / "plants"
SERIALS = ("sn637", "sn629", "sn618")
FULL = os.environ.get("WORKBENCH_FULL") == "1"


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
