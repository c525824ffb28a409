"""The ladder's fixtures (tests/conftest.py's are not seen from here)."""
import pytest


@pytest.fixture(scope="session")
def lpips_net():
    from eval.lpips.net import load_lpips
    return load_lpips()
