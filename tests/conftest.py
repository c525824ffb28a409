"""Shared fixtures: built in code, nothing downloaded."""
import logging
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


def _is_pytest_handler(handler: logging.Handler) -> bool:
    return type(handler).__module__.startswith("_pytest")


def _all_loggers() -> list[logging.Logger]:
    return [logging.getLogger()] + [lg for lg in logging.root.manager.loggerDict.values()
                                    if isinstance(lg, logging.Logger)]


@pytest.fixture(autouse=True)
def isolated_logging():
    """A CLI run in-process under @hydra.main configures logging: a StreamHandler on the test's
    captured stdout, closed when the test ends, which later tests' log calls then hit ("Logging
    error ... I/O operation on closed file"). Put the loggers back as they were after each test
    (pytest's own capture handlers come and go per test phase and are left to pytest)."""
    saved = {lg: ([h for h in lg.handlers if not _is_pytest_handler(h)], lg.level, lg.propagate,
                  lg.disabled) for lg in _all_loggers()}
    yield
    for lg in _all_loggers():
        handlers, level, propagate, disabled = saved.get(lg, ([], logging.NOTSET, True, False))
        for handler in lg.handlers:
            if handler not in handlers and not _is_pytest_handler(handler):
                handler.close()
        lg.handlers[:] = [h for h in lg.handlers if _is_pytest_handler(h)] + handlers
        lg.setLevel(level)
        lg.propagate, lg.disabled = propagate, disabled


@pytest.fixture(scope="session")
def lpips_net():
    from eval.lpips.net import load_lpips
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
