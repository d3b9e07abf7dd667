"""Hypothesis strategies shared by the property tests."""

import numpy as np
from hypothesis import strategies as st

finite = st.floats(min_value=-10, max_value=10, allow_nan=False, allow_infinity=False)
quaternions = st.lists(finite, min_size=4, max_size=4).map(np.array)
dual_quaternions = st.lists(finite, min_size=8, max_size=8).map(np.array)
vectors = st.lists(finite, min_size=3, max_size=3).map(np.array)


@st.composite
def unit_quaternions(draw):
    # a draw too close to zero to normalise is discarded (not replaced by the identity,
    # which would silently over-sample one rotation)
    q = draw(quaternions.filter(lambda v: np.linalg.norm(v) >= 1e-3))
    return q / np.linalg.norm(q)


@st.composite
def unit_dual_quaternions(draw):
    from derive import dualquat as dq
    return dq.from_rt(draw(unit_quaternions()), draw(vectors))
