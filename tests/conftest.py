import os
import shutil
import subprocess

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


def assert_compiles_strict(src, what=""):
    """The C source file ``src`` compiles with warnings as errors (-Wall -Wextra -Werror) as C99
    with -Wpedantic and as C++17, with each compiler that is installed (gcc, g++)."""
    for cmd in (["gcc", "-std=c99", "-Wpedantic", "-O1", "-c", "-o", "/dev/null"],
                ["g++", "-std=c++17", "-x", "c++", "-fsyntax-only"]):
        if shutil.which(cmd[0]) is None:
            continue
        res = subprocess.run([*cmd, "-Wall", "-Wextra", "-Werror", str(src)], capture_output=True, text=True)
        assert res.returncode == 0, (what, cmd, res.stderr[-3000:])
