"""Symbolic serial chains and their dual-quaternion products M_i and N_i.

A robot of the library is brought to the form the thesis uses (seed 004,
section 4.2.1): every joint i is the pair

    Q_i = ([cos(t_i/2), sin(t_i/2) w_i], q_i l_i q_i^-1)      (revolute)
    Q_i = ([1, <0, 0, 0>], t_i w_i + l_i)                      (prismatic)

with w_i the joint axis and l_i the link vector, both in the base frame at the
zero pose, the axis passing through the end of the previous link. For an
``axis_angle`` description these are the file's axes and links. For a DH
description they are computed exactly from the DH numbers at q = 0: the point
that ends link i is the origin of frame i moved along axis i+1 by the
translation that the DH transform of joint i+1 makes along that axis (d_(i+1)),
which reproduces the thesis's links for the UR family. The geometric
parameters stay symbols (d1, a2, ...), so one derivation serves a whole family.

The chain's end frame has the base orientation at the zero pose. The robot's
own end frame differs from it by a constant transform G (for the UR family's DH
frame 6, G = Rx(pi/2)); the pose written ([w, <a, b, c>], <x, y, z>) in the
equations is the chain end frame, i.e. the robot's FK pose times G^-1.

Products (thesis eq. 4.2-4.3): M_n = Q_n, M_i = Q_i M_(i+1); N_1 = the pose,
N_(i+1) = Q_i^-1 N_i; M_i = N_i for every i. Consecutive rotations about
parallel axes are merged before expanding (q2 q3 q4 = one rotation by
t2 + t3 + t4), which keeps the half-angle sums of the thesis together.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from derive.algebra.quaternion import hamilton
from derive.errors import DeriveError
from derive.model import exact
from derive.model.robot import Robot, load_robot, robot_from_dict

Vec = tuple  # 3 sympy expressions


@dataclass(frozen=True)
class SymJoint:
    index: int            # 1-based joint number along the chain
    name: str
    type: str             # "revolute" or "prismatic"
    axis: Vec             # exact unit axis, base frame at the zero pose
    link: Vec             # exact link vector, base frame at the zero pose
    theta: sp.Symbol      # the joint variable (theta_i)


@dataclass(frozen=True)
class SymChain:
    """A robot in the thesis's axis-angle form, with symbolic geometry."""

    robot: str
    family: str                     # robots with the same symbolic chain share a family
    joints: tuple
    parameters: dict                # parameter Symbol -> value (SI) for this robot
    end_transform: tuple            # (quaternion, translation) G: robot end frame in chain end frame

    @property
    def n(self) -> int:
        return len(self.joints)


# --------------------------------------------------------------------------- #
# Exact 4x4 helpers (only used to place the axes at the zero pose)
# --------------------------------------------------------------------------- #
def _rot_matrix(axis: Vec, angle) -> sp.Matrix:
    x, y, z = axis
    k = sp.Matrix([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return sp.eye(3) + sp.sin(angle) * k + (1 - sp.cos(angle)) * k * k


def _homog(r: sp.Matrix, t) -> sp.Matrix:
    m = sp.eye(4)
    m[:3, :3] = r
    m[:3, 3] = sp.Matrix(t)
    return m


def _op_matrix(op) -> sp.Matrix:
    if op.kind == "R":
        axis, angle = exact.op_form(op)
        return _homog(_rot_matrix(axis, angle), (0, 0, 0))
    return _homog(sp.eye(3), exact.op_form(op))


def _simplify_vec(v) -> Vec:
    return tuple(sp.nsimplify(sp.simplify(e)) for e in v)


def _matrix_to_quaternion(r: sp.Matrix) -> tuple:
    """Exact unit quaternion (w >= 0) of an exact rotation matrix with a clean form."""
    tr = sp.simplify(r.trace())
    w = sp.sqrt(sp.simplify(1 + tr)) / 2
    if sp.simplify(w) != 0:
        x = sp.simplify((r[2, 1] - r[1, 2]) / (4 * w))
        y = sp.simplify((r[0, 2] - r[2, 0]) / (4 * w))
        z = sp.simplify((r[1, 0] - r[0, 1]) / (4 * w))
        return tuple(sp.radsimp(sp.simplify(e)) for e in (w, x, y, z))
    # half turn: axis from the diagonal
    x = sp.sqrt(sp.simplify((1 + r[0, 0]) / 2))
    y = sp.sqrt(sp.simplify((1 + r[1, 1]) / 2))
    z = sp.sqrt(sp.simplify((1 + r[2, 2]) / 2))
    if x != 0:
        y, z = sp.sign(r[0, 1]) * y, sp.sign(r[0, 2]) * z
    elif y != 0:
        z = sp.sign(r[1, 2]) * z
    return (sp.Integer(0), x, y, z)


def _family(robot: Robot) -> str:
    keys = sorted(robot.parameters)
    return f"{robot.convention}:{len(robot.joints)}:{','.join(keys)}"


def chain_from_robot(robot) -> SymChain:
    """The thesis-form chain of ``robot`` along the path to its default end."""
    robot = load_robot(robot)
    end = robot.ends[robot.default_end]
    path = []
    k = end.parent
    while k >= 0:
        path.append(k)
        k = robot.joints[k].parent
    path.reverse()
    for k in path:
        if robot.joints[k].is_mimic:
            raise DeriveError(f"{robot.name}: joint {robot.joints[k].name!r} mimics another joint; "
                              "the symbolic derivation needs independent joints")

    frame = sp.eye(4)                     # frame of the previous joint at q = 0
    axes, points_on_axis, shifts = [], [], []
    for k in path:
        j = robot.joints[k]
        pre = frame
        for op in j.pre:
            pre = pre * _op_matrix(op)
        joint_axis = exact.joint_axis(j)
        offset = exact.value(j.offset)
        axis_world = _simplify_vec(pre[:3, :3] * sp.Matrix(joint_axis))
        origin = _simplify_vec(pre[:3, 3])
        motion = (_homog(_rot_matrix(joint_axis, offset), (0, 0, 0)) if j.type == "revolute"
                  else _homog(sp.eye(3), tuple(offset * a for a in joint_axis)))
        f = pre * motion
        # leading translations of the post operations along the joint axis (DH: Tz(d))
        shift = sp.zeros(3, 1)
        for op in j.post:
            if op.kind != "T":
                break
            v = sp.Matrix(exact.op_form(op))
            if any(e != 0 for e in v) and all(sp.simplify(e) == 0 for e in v.cross(sp.Matrix(joint_axis))):
                shift += f[:3, :3] * v
                continue
            break
        for op in j.post:
            f = f * _op_matrix(op)
        axes.append(axis_world)
        points_on_axis.append(origin)
        shifts.append(_simplify_vec(shift))
        frame = f

    n = len(path)
    # P_0 = a point of axis 1 (must be the base origin); P_i = point of axis i+1 moved by its
    # leading parallel translation; P_n = origin of the last joint frame.
    if any(e != 0 for e in points_on_axis[0]):
        raise DeriveError(f"{robot.name}: the first joint axis does not pass through the base origin; "
                          "the symbolic derivation needs a chain that starts at the base")
    points = [points_on_axis[0]]
    for i in range(1, n):
        points.append(_simplify_vec(tuple(o + s for o, s in zip(points_on_axis[i], shifts[i]))))
    points.append(_simplify_vec(frame[:3, 3]))

    joints = []
    for i, k in enumerate(path):
        j = robot.joints[k]
        link = _simplify_vec(tuple(b - a for a, b in zip(points[i], points[i + 1])))
        joints.append(SymJoint(index=i + 1, name=j.name, type=j.type, axis=axes[i], link=link,
                               theta=sp.Symbol(f"theta{i + 1}", real=True)))

    # end transform G = (chain end frame at zero)^-1 (robot end frame at zero)
    end_frame = frame
    for op in end.ops:
        end_frame = end_frame * _op_matrix(op)
    g_rot = end_frame[:3, :3].applyfunc(sp.simplify)
    g_trans = _simplify_vec(tuple(e - p for e, p in zip(end_frame[:3, 3], points[-1])))
    params = {sp.Symbol(k, real=True): v for k, v in robot.parameters.items()}
    return SymChain(robot=robot.name, family=_family(robot), joints=tuple(joints), parameters=params,
                    end_transform=(_matrix_to_quaternion(g_rot), g_trans))


# --------------------------------------------------------------------------- #
# Products
# --------------------------------------------------------------------------- #
def _parallel(u: Vec, v: Vec) -> int:
    """+1 if u == v, -1 if u == -v, 0 otherwise (exact unit axes)."""
    if all(sp.simplify(a - b) == 0 for a, b in zip(u, v)):
        return 1
    if all(sp.simplify(a + b) == 0 for a, b in zip(u, v)):
        return -1
    return 0


def merge_runs(runs) -> list:
    """Merge consecutive rotations about parallel axes: R(u, a) R(u, b) = R(u, a + b)."""
    out: list = []
    for axis, angle in runs:
        if out:
            s = _parallel(out[-1][0], axis)
            if s:
                out[-1] = (out[-1][0], out[-1][1] + s * angle)
                continue
        out.append((axis, angle))
    return [(a, t) for a, t in out if t != 0]


def runs_quaternion(runs) -> tuple:
    """Expanded quaternion of a product of axis rotations (half angles)."""
    q = (sp.Integer(1), sp.Integer(0), sp.Integer(0), sp.Integer(0))
    for axis, angle in merge_runs(runs):
        r = (sp.cos(angle / 2),) + tuple(sp.sin(angle / 2) * a for a in axis)
        q = tuple(sp.expand(e) for e in hamilton(q, r))
    return q


def runs_matrix(runs) -> sp.Matrix:
    """Rotation matrix (full angles) of a product of axis rotations."""
    m = sp.eye(3)
    for axis, angle in merge_runs(runs):
        m = m * _rot_matrix(axis, angle)
    return m.applyfunc(sp.expand)


@dataclass(frozen=True)
class Product:
    """One side of M_i = N_i: the quaternion terms (4) and translation terms (3)."""

    name: str          # "M5" or "N5"
    terms: tuple       # 7 expanded sympy expressions


def products(chain: SymChain, first: int, last: int, pose: tuple, zero_last_link: bool = False):
    """M_i and N_i for i = first..last (1-based, inclusive).

    ``pose`` is the 7 symbols ([w, <a, b, c>], <x, y, z>) of N_first. With
    ``zero_last_link`` the last joint keeps only its rotation (thesis sections
    4.3.3 and 4.3.4, 'M5 = Q5 with the translation set to zero').
    """
    js = chain.joints[first - 1:last]
    links = [j.link for j in js]
    if zero_last_link:
        links[-1] = (sp.Integer(0),) * 3

    def run(j, sign=1):
        return [(j.axis, sign * j.theta)] if j.type == "revolute" else []

    def own_translation(j, link):
        if j.type == "prismatic":
            return sp.Matrix(link) + j.theta * sp.Matrix(j.axis)
        return sp.Matrix(link)

    m_side: dict[int, Product] = {}
    rot_runs: list = []
    trans = sp.zeros(3, 1)
    for k in range(len(js) - 1, -1, -1):
        j = js[k]
        rot_runs = run(j) + rot_runs
        r = runs_matrix(run(j))
        trans = (r * (own_translation(j, links[k]) + trans)).applyfunc(sp.expand)
        i = first + k
        m_side[i] = Product(f"M{i}", runs_quaternion(rot_runs) + tuple(trans))

    w, a, b, c, x, y, z = pose
    n_side: dict[int, Product] = {first: Product(f"N{first}", (w, a, b, c, x, y, z))}
    inv_runs: list = []
    trans = sp.Matrix([x, y, z])
    for k in range(len(js) - 1):
        j = js[k]
        inv_runs = run(j, -1) + inv_runs
        r = runs_matrix(run(j))
        trans = (r.T * trans - own_translation(j, links[k])).applyfunc(sp.expand)
        q = tuple(sp.expand(e) for e in hamilton(runs_quaternion(inv_runs), (w, a, b, c)))
        i = first + k + 1
        n_side[i] = Product(f"N{i}", q + tuple(trans))
    return m_side, n_side


def numeric_robot(chain: SymChain, values: dict, first: int = 1, last: int | None = None,
                  zero_last_link: bool = False):
    """The sub-chain first..last as a numeric ``axis_angle`` description (parameters from
    ``values``), for the independent reference FK."""

    last = chain.n if last is None else last
    joints = []
    for j in chain.joints[first - 1:last]:
        link = [float(sp.sympify(v).subs(values)) for v in j.link]
        if zero_last_link and j.index == last:
            link = [0.0, 0.0, 0.0]
        joints.append({"name": j.name, "type": j.type, "axis": [float(a) for a in j.axis], "link": link})
    return robot_from_dict({"name": f"{chain.robot}-numeric", "convention": "axis_angle", "joints": joints})
