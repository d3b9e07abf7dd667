"""Hypothesis strategies shared by the property tests."""

import numpy as np
from hypothesis import strategies as st

finite = st.floats(min_value=-10, max_value=10, allow_nan=False, allow_infinity=False)
quaternions = st.lists(finite, min_size=4, max_size=4).map(np.array)
dual_quaternions = st.lists(finite, min_size=8, max_size=8).map(np.array)
vectors = st.lists(finite, min_size=3, max_size=3).map(np.array)


@st.composite
def unit_quaternions(draw):
    q = draw(quaternions)
    n = np.linalg.norm(q)
    if n < 1e-3:
        q, n = np.array([1.0, 0, 0, 0]), 1.0
    return q / n


@st.composite
def unit_dual_quaternions(draw):
    from derive import dualquat as dq
    return dq.from_rt(draw(unit_quaternions()), draw(vectors))
