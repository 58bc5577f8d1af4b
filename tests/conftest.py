"""Shared fixtures. Tests render in-process (workers=0) with small images."""

import os
import time

import numpy as np
import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")

SESSION_START = pytest.StashKey[float]()


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


def pytest_configure(config):
    config.addinivalue_line("markers", "after_notebooks: reads what the notebooks' smoke runs wrote; runs last")
    config.stash[SESSION_START] = time.time()


def pytest_collection_modifyitems(session, config, items):
    """Tests marked ``after_notebooks`` run after every other item (the nbval notebook runs included)."""
    items.sort(key=lambda item: item.get_closest_marker("after_notebooks") is not None)  # stable: order kept


@pytest.fixture(scope="session")
def session_start(request) -> float:
    """Wall time (time.time()) at which this pytest session started."""
    return request.config.stash[SESSION_START]
