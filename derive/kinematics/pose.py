"""Pose input: unit dual quaternions or 4x4 matrices, checked and brought to one form."""

from __future__ import annotations

import numpy as np

from derive.algebra import dualquat as dq
from derive.errors import InputError, as_finite_array


def as_pose_batch(pose) -> tuple:
    """Unit dual quaternions (n, 8) from (8,), (n, 8), (4, 4) or (n, 4, 4) input; single flag."""
    arr = as_finite_array(pose, "pose", ndim_min=1)
    if arr.shape[-2:] == (4, 4):
        single = arr.ndim == 2
        m = arr[None] if single else arr
        r = m[:, :3, :3]
        err = np.max(np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3)), axis=(1, 2))
        if np.any(err > 1e-6) or np.any(np.linalg.det(r) < 0):
            raise InputError(f"pose: the 3x3 block is not a rotation matrix "
                             f"(max |R^T R - I| = {float(np.max(err)):.3g})")
        return dq.from_matrix(m), single
    if arr.shape[-1] != 8 or arr.ndim > 2:
        raise InputError(f"pose: expected a dual quaternion (8,) / (n, 8) or a matrix (4, 4) / "
                         f"(n, 4, 4), got shape {arr.shape}")
    single = arr.ndim == 1
    return dq.check_unit(arr[None] if single else arr, "pose"), single
