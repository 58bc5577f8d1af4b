"""Shared fixtures. Tests render in-process (workers=0) with small images."""

import os

import numpy as np
import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def manifest():
    from helpers.data.manifest import load_manifest

    return load_manifest()


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: on a shared 2-core machine, OpenMP with 2 threads
    slows down >10x as soon as another process holds a core; tiny test batches
    gain nothing from a second thread anyway."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
