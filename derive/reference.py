"""The numeric reference of dq-derive: forward kinematics two independent ways and the
closed-form IK, the check every generated kernel is tested against.

* :func:`fk`, :func:`fk_matrix`, :func:`frame_poses`, :func:`joint_positions`, :func:`fk_pair`,
  :func:`pose_error`: :mod:`derive.kinematics.fk` (dual-quaternion products, Kunze eq. 1.8 and
  5.28, and plain 4x4 matrices, Kunze eq. 5.1-5.4, sharing no code);
* :func:`ik`, :func:`ik_batch`: :mod:`derive.ik.closed_form` (the UR family's closed form in
  numpy, written by hand after the thesis's section 4.3.5 and kept independent of the IK
  program that the kernels and the CasADi ``ik`` are generated from).
"""

from derive.ik.closed_form import IKSolutions, ik, ik_batch
from derive.kinematics.fk import (
           fk,
           fk_matrix,
           fk_pair,
           frame_poses,
           joint_positions,
           pose_error,
)

__all__ = ["fk", "fk_matrix", "fk_pair", "frame_poses", "joint_positions", "pose_error",
           "ik", "ik_batch", "IKSolutions"]
