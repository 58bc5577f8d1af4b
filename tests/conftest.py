"""Shared fixtures. Tests render in-process (workers=0) with small images."""

import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def manifest():
    from helpers.manifest import load_manifest

    return load_manifest()


@pytest.fixture
def rng():
    return np.random.default_rng(0)
