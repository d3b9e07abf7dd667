"""dq-derive: dual-quaternion kinematics of serial robot arms.

Quick start::

    import derive
    robot = derive.load_robot("ur5")
    Q = derive.reference.fk(robot, [0, -1.57, 1.57, 0, 1.57, 0])   # unit dual quaternion (8,)
    T = derive.reference.fk_matrix(robot, [0, -1.57, 1.57, 0, 1.57, 0])  # 4x4 matrix
"""

from . import dualquat, quaternion, reference
from .errors import DeriveError, InputError, RobotFileError, UnknownRobotError
from .robot import Robot, list_robots, load_robot


def kernels(robot, backend: str = "numpy"):
    """Generated FK kernels of ``robot`` ("python", "numpy" or "c"); see :mod:`derive.loader`."""
    from .loader import kernels as _kernels
    return _kernels(robot, backend)


def refine(robot, pose, q0=None, **options):
    """IK refinement with CasADi on the robot's actual model; see :mod:`derive.refinement`."""
    from .refinement import refine as _refine
    return _refine(robot, pose, q0, **options)


__version__ = "0.1.0"

__all__ = [
    "DeriveError", "InputError", "RobotFileError", "UnknownRobotError",
    "Robot", "list_robots", "load_robot", "kernels", "refine",
    "dualquat", "quaternion", "reference", "__version__",
]
