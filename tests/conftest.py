import os

import numpy as np
import pytest
from hypothesis import settings

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True)
settings.load_profile("ci")


@pytest.fixture(scope="session")
def run_folder(tmp_path_factory):
    """A folder of this test run shared by all its processes: under pytest-xdist (``make test``
    runs ``pytest -n logical``) the workers' base folders are children of the run's folder."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


def random_unit_dq(rng, n):
    """n random unit dual quaternions (translations up to 2 m)."""
    from derive import dualquat as dq
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = rng.uniform(-2, 2, size=(n, 3))
    return dq.from_rt(q, t)
