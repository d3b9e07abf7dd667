"""``derive.kernels(robot, backend, free="qK")``: a seven-joint arm's IK with any joint K given.

The solver is :mod:`derive.ik.free_joint` (the class's closed form where holding joint K leaves
one, else the general 6R with a numeric per-value construction of the elimination). No code is
emitted for it yet: the "python" and "numpy" backends run that numpy solver for ``ik``,
``ik_sweep`` and ``nearest``, and the backend's generated kernels for ``fk`` (and every other
kernel: ``with_tool``, ``jacobian``, ...); the "c" backend has no such IK kernel
(``derive.kernels`` raises InputError naming the numpy kernels). The calling convention is that of :class:`derive.codegen.loader.Kernels` with the
7R ``free=`` argument: ``ik(P, free=values)`` -> (solutions (n, 16, 7) NaN-padded, counts (n,)),
``ik_sweep(P, n)`` over joint K's range, ``nearest(P, q_seed)`` with joint K chosen for the path.
"""

from __future__ import annotations

import numpy as np

from derive.algebra import dualquat as dq
from derive.errors import DeriveError, InputError
from derive.ik import free_joint, redundant, select
from derive.kinematics.pose import as_pose_batch


class FreeJointKernels:
    """The kernels of a 7R arm whose IK takes the value of joint K (``free="qK"``)."""

    def __init__(self, robot, backend: str, joint: int, fk_kernels):
        self.robot = robot
        self.backend = backend
        self.dof = 7
        self.joint = joint
        #: the free parameter's name, as :attr:`derive.codegen.loader.Kernels.free`
        self.free = f"q{joint}"
        #: which solver holds the joint: "srs", "panda" or "general" (:func:`derive.ik.free_joint.route`)
        self.route = free_joint.route(robot, joint)
        if self.route == "general":
            free_joint.plan(robot, joint)            # DeriveError now for a geometry it cannot solve
        self._fk = fk_kernels
        self._tool = None

    def __getattr__(self, name):
        # fk, jacobian, ... of the backend's generated kernels (not the IK: defined below)
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._fk, name)

    def __repr__(self) -> str:
        return f"<FreeJointKernels {self.robot.name} {self.backend} free=q{self.joint} ({self.route})>"

    @property
    def has_ik(self) -> bool:
        return True

    def with_tool(self, tool) -> "FreeJointKernels":
        """The same kernels for the end frame moved by a fixed tool transform (as
        :meth:`derive.codegen.loader.Kernels.with_tool`)."""
        import copy

        k = copy.copy(self)
        k._fk = self._fk.with_tool(tool)
        k._tool = k._fk._tool
        return k

    def fk(self, Q):
        return self._fk.fk(Q)

    def _poses(self, P):
        poses, single = as_pose_batch(P)
        if self._tool is not None:
            poses = dq._mul(poses, dq.conj_quaternion(self._tool)[None])
        return np.ascontiguousarray(poses, dtype=np.float64), single

    def _need(self, free):
        if free is None:
            lo, hi = free_joint.joint_range(self.robot, self.joint)
            raise InputError(f"{self.robot.name}: these kernels solve with joint {self.joint} given and need "
                             f"free= (q{self.joint}, rad, in [{lo:.4g}, {hi:.4g}]), a number or one per pose")

    def ik(self, P, within_limits: bool = False, details: bool = False, free=None):
        """Every solution with joint K held at ``free`` (rad, a number or one per pose):
        (solutions (n, 16, 7) NaN-padded, valid rows first, counts (n,)); one pose gives
        ((16, 7), count). ``details``: also (branch (n, 16): the class's branch ids, -1 on the
        general route; singular (n, 16)). ``within_limits``: every in-limit winding of each
        solution (:func:`derive.ik.select.within_limits`)."""
        self._need(free)
        poses, single = self._poses(P)
        r = free_joint.solve(self.robot, poses, self.joint, redundant.free_values(free, len(poses)))
        sols, counts, branch, sing = r.q, r.counts, r.branch, r.singular
        if within_limits:
            sols, counts, branch, sing = select.within_limits(sols, counts, self.robot.limits, self.robot.revolute,
                                                              branch, sing)
        if single:
            sols, counts, branch, sing = sols[0], int(counts[0]), branch[0], sing[0]
        return (sols, counts, branch, sing) if details else (sols, counts)

    def _solver(self, poses, f):
        r = free_joint.solve(self.robot, poses, self.joint, f)
        return r.q, r.counts, r.branch, r.singular

    def ik_sweep(self, P, n: int, within_limits: bool = True) -> redundant.Sweep:
        """The solutions at ``n`` values of joint K over its range
        (:func:`derive.ik.free_joint.ik_sweep`)."""
        poses, single = self._poses(P)
        return free_joint.ik_sweep(self.robot, poses[0] if single else poses, self.joint, n,
                                   within_limits=within_limits)

    def nearest(self, P, q_seed, tol=None) -> select.Nearest:
        """Per pose the solution nearest to the seed along a path, joint K chosen by the 1-D
        search of :func:`derive.ik.free_joint.nearest`."""
        poses, single = self._poses(P)
        return free_joint.nearest(self.robot, poses[0] if single else poses, self.joint, q_seed, tol=tol)


def free_joint_kernels(robot, backend: str, joint: int, fk_kernels) -> FreeJointKernels:
    """:class:`FreeJointKernels`; DeriveError for the "c" backend (no emitted IK for a joint
    given outside a class's own choice yet)."""
    if backend == "c":
        raise DeriveError(f"{robot.name}: no C kernel for the IK with q{joint} given yet (the general "
                          "6R with a joint held is solved by derive.ik.free_joint in numpy); use "
                          f"derive.kernels({robot.name!r}, 'numpy', free='q{joint}')")
    return FreeJointKernels(robot, backend, joint, fk_kernels)
