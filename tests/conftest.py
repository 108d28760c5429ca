import sys
from pathlib import Path

import drjit as dr
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

BACKENDS = ["llvm"] + (["cuda"] if dr.has_backend(dr.JitBackend.CUDA) else [])


@pytest.fixture(params=BACKENDS)
def backend(request):
    """Every test that takes ``backend`` runs on LLVM, and on CUDA when a GPU is present."""
    return request.param


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a render that takes more than a few seconds")
