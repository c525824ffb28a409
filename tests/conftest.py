"""Shared fixtures: built in code, nothing downloaded."""
from pathlib import Path

import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def single_torch_thread():
    """Tests use tiny tensors: one intra-op thread is fastest and reproducible, and avoids
    OpenMP spin-waiting (measured 100x slow-downs) when the 2 cores are shared."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def lpips_net():
    from eval.lpips_net import load_lpips
    return load_lpips()


@pytest.fixture(scope="session")
def sphere_dataset(tmp_path_factory) -> Path:
    """Two analytic sphere scenes (48 px, 3 test views) in the canonical layout."""
    from tests.fixtures import make_dataset
    return make_dataset(tmp_path_factory.mktemp("gt"), num_scenes=2, size=48)


def pytest_collection_modifyitems(config, items):
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA GPU")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def micro_dataset(tmp_path_factory) -> Path:
    """2 training scenes + 1 test scene at 32 px made by gspi-data (tests/run_helpers.py)."""
    from tests.run_helpers import make_micro_dataset
    return make_micro_dataset(tmp_path_factory.mktemp("micro") / "data")
