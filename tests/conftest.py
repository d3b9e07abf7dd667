import numpy as np
import pytest
from hypothesis import settings

settings.register_profile("ci", max_examples=60, deadline=None, derandomize=True)
settings.load_profile("ci")


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
