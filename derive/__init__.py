"""dq-derive: dual-quaternion kinematics of serial robot arms.

Quick start::

    import derive
    robot = derive.load_robot("ur5")
    Q = derive.reference.fk(robot, [0, -1.57, 1.57, 0, 1.57, 0])   # unit dual quaternion (8,)
    T = derive.reference.fk_matrix(robot, [0, -1.57, 1.57, 0, 1.57, 0])  # 4x4 matrix
    k = derive.kernels(robot, "c")                                  # generated C kernels
    sols, count = k.ik(Q)
    best = k.nearest(Q, q_seed=[0, -1.5, 1.5, 0, 1.5, 0])          # .q, .found, .branch ...
    P = derive.pose.from_position_quaternion([0.4, 0.1, 0.3], [1, 0, 0, 0], order="xyzw")

The package is in layers whose imports point one way (see docs/architecture.md):
algebra -> model -> kinematics -> symbolic -> ik -> codegen -> refinement -> reports / apps ->
bench -> cli.
"""

from derive import reference
from derive._version import __version__
from derive.apps.reach import place, reach
from derive.algebra import dualquat, quaternion
from derive.apps.path import path
from derive.codegen.loader import kernels
from derive.errors import DeriveError, InputError, RobotFileError, UnknownRobotError
from derive.ik.nearclass import classify
from derive.kinematics import pose
from derive.model.robot import Robot, list_robots, load_robot

__all__ = [
    "DeriveError", "InputError", "RobotFileError", "UnknownRobotError",
    "Robot", "list_robots", "load_robot", "kernels", "refine", "classify",
    "dualquat", "quaternion", "reference", "pose", "path", "reach", "place", "__version__",
]


def __getattr__(name: str):
    """The public names whose modules are heavy, imported on first use (PEP 562): ``refine``
    (CasADi). ``import derive`` and loading shipped or cached kernels import neither sympy,
    CasADi, jinja2 nor yourdfpy (docs/architecture.md, "Light import")."""
    if name == "refine":
        from derive.refinement.solver import refine
        globals()["refine"] = refine
        return refine
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
