"""The serial chain of a robot in the thesis's axis-angle form, computed numerically.

The same construction as :func:`derive.symbolic.chain.chain_from_robot` (thesis section
4.2.1: each joint's axis w_i and link vector l_i in the base frame at the zero pose, the
axis passing through the end of the previous link, and the constant end transform G), in
floating point. It needs no symbolic algebra, so it serves every description, decimal
numbers included: the closed-form IK's structure test (:func:`derive.ik.closed_form.ur_geometry`),
and the structure report of a robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from derive.errors import DeriveError
from derive.model.robot import Robot, load_robot


@dataclass(frozen=True)
class NumericChain:
    """A robot's path to its default end in axis-angle form (floats, SI units)."""

    robot: str
    names: tuple            # joint names along the path
    types: tuple            # "revolute" / "prismatic"
    variables: tuple        # index into q of each path joint
    axes: np.ndarray        # (n, 3) unit axes, base frame at the zero pose
    links: np.ndarray       # (n, 3) link vectors, base frame at the zero pose
    start: np.ndarray       # (3,) a point of axis 1 (the base origin for a chain that starts there)
    end_rotation: np.ndarray     # (3, 3) G: robot end frame in the chain end frame
    end_translation: np.ndarray  # (3,)

    @property
    def n(self) -> int:
        return len(self.names)


def _rot(axis, angle) -> np.ndarray:
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def _homog(r, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = t
    return m


def op_matrix(op) -> np.ndarray:
    if op.kind == "R":
        return _homog(_rot(op.axis, op.angle), np.zeros(3))
    return _homog(np.eye(3), op.vector)


def path_to_end(robot: Robot) -> list[int]:
    """Joint indices from the base to the default end's parent, in order."""
    end = robot.ends[robot.default_end]
    path, k = [], end.parent
    while k >= 0:
        path.append(k)
        k = robot.joints[k].parent
    return path[::-1]


def numeric_chain(robot) -> NumericChain:
    """The axis-angle chain of ``robot`` along the path to its default end (see module docstring).

    Raises DeriveError for a mimic joint on the path (its value is not an independent variable)."""
    robot = load_robot(robot)
    path = path_to_end(robot)
    frame = np.eye(4)
    axes, origins, shifts = [], [], []
    for k in path:
        j = robot.joints[k]
        if j.is_mimic:
            raise DeriveError(f"{robot.name}: joint {j.name!r} mimics another joint; the chain "
                              "form needs independent joints")
        pre = frame
        for op in j.pre:
            pre = pre @ op_matrix(op)
        axis = pre[:3, :3] @ j.axis
        origin = pre[:3, 3].copy()
        motion = (_homog(_rot(j.axis, float(j.offset)), np.zeros(3)) if j.type == "revolute"
                  else _homog(np.eye(3), float(j.offset) * j.axis))
        f = pre @ motion
        shift = np.zeros(3)
        for op in j.post:          # leading translations along the joint axis (DH: Tz(d))
            if op.kind != "T":
                break
            v = op.vector
            if np.any(v != 0) and np.linalg.norm(np.cross(v, j.axis)) <= 1e-12 * np.linalg.norm(v):
                shift += f[:3, :3] @ v
                continue
            break
        for op in j.post:
            f = f @ op_matrix(op)
        axes.append(axis)
        origins.append(origin)
        shifts.append(shift)
        frame = f
    n = len(path)
    points = [origins[0]] + [origins[i] + shifts[i] for i in range(1, n)] + [frame[:3, 3]]
    links = np.array([points[i + 1] - points[i] for i in range(n)]).reshape(n, 3)
    end = robot.ends[robot.default_end]
    end_frame = frame
    for op in end.ops:
        end_frame = end_frame @ op_matrix(op)
    return NumericChain(
        robot=robot.name, names=tuple(robot.joints[k].name for k in path),
        types=tuple(robot.joints[k].type for k in path),
        variables=tuple(robot.joints[k].variable for k in path),
        axes=np.array(axes).reshape(n, 3), links=links, start=np.asarray(origins[0]),
        end_rotation=end_frame[:3, :3].copy(), end_translation=end_frame[:3, 3] - points[-1])
