"""Export of any robot (library, YAML or URDF) as a kinematic URDF or as our YAML.

Both are written from the neutral joint form of :mod:`derive.model.robot` (T_joint = pre
Motion(axis, value + offset) post):

* URDF (:func:`to_urdf`, written by yourdfpy): a link per joint frame (``<joint>_link``, the
  root link ``base_link``) and a fixed joint per end frame (``<end>_joint`` to the link
  ``<end>``); a name that another frame has already gets a trailing ``_``.
  A URDF joint has one origin before its motion and no offset, so each joint's origin is its
  parent's ``post`` times its own ``pre`` times the motion by its offset, multiplied out into
  one 4x4 matrix; revolute joints without limits become ``continuous``; prismatic joints without
  limits get +-``PRISMATIC_RANGE`` (a URDF prismatic joint needs limits). Mimic joints keep
  their relation. Only kinematics: no inertia, geometry or effort limits.
  Each origin's ``rpy`` comes from :func:`rpy_of` (accurate at every pitch; yourdfpy's own
  conversion loses up to 1e-8 near pitch = +-pi/2), and every number is written as the
  shortest text that reads back as the same double (Python's ``repr``, 17 significant digits
  at most).
* YAML (:func:`to_yaml`, convention ``urdf``): the same joints with the operations kept
  one by one (no multiplication, so nothing is rounded): each joint's ``origin`` lists its
  own pre operations and ``after`` its post operations, each end's ``origin`` its operations,
  and the offset stays ``offset``; numbers as ``repr`` writes them. Read back, it is the same
  robot: the same ``Robot.id``, every frame bit for bit.

Round trips (tests/test_export.py, every library robot): the YAML gives the same identity and
FK; the URDF gives the FK of every end frame to 1e-15, and Pinocchio on the exported URDF agrees
(tests/test_urdf.py). A URDF cannot keep the operations one by one, so its robot is another
description of the same end frames (joint frames at the joint origins, another identity).
"""

from __future__ import annotations

import math

import numpy as np
import yaml
from lxml import etree

from derive.model.geometry import op_matrix
from derive.model.robot import Op, Robot, load_robot

#: Limits (m) written for a prismatic joint that has none.
PRISMATIC_RANGE = 10.0


def _matrix(ops) -> np.ndarray:
    m = np.eye(4)
    for op in ops:
        m = m @ op_matrix(op)
    return m


def rpy_of(m) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a rotation (3x3 or 4x4) with R = Rz(yaw) Ry(pitch) Rx(roll), the
    URDF ``rpy``. Roll and pitch come from the third row (r31, r32, r33) = (-sin p, cos p sin r,
    cos p cos r), yaw from R (Ry(pitch) Rx(roll))^T = Rz(yaw): each step is well conditioned,
    so the rotation rebuilt from the three angles is R to rounding at every pitch, also at
    +-pi/2, where the textbook formula (yaw from r21, r11) divides by cos p."""
    r = np.asarray(m, dtype=float)[:3, :3]
    roll = math.atan2(r[2, 1], r[2, 2])
    pitch = math.atan2(-r[2, 0], math.hypot(r[2, 1], r[2, 2]))
    cr, sr, cp, sp_ = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    ry_rx = np.array([[cp, sp_ * sr, sp_ * cr], [0.0, cr, -sr], [-sp_, cp * sr, cp * cr]])
    rest = r @ ry_rx.T
    yaw = math.atan2(rest[1, 0], rest[0, 0])
    return roll + 0.0, pitch + 0.0, yaw + 0.0


def _motion(j, value: float) -> Op:
    if j.type == "revolute":
        return Op("R", axis=j.axis, angle=value)
    return Op("T", vector=value * j.axis)


def _urdf_names(robot: Robot) -> tuple[str, list, dict, dict]:
    """Names of the root link, of each joint's child link, and of each end's link and fixed
    joint, none equal to another frame's name (Pinocchio and ROS need them distinct)."""
    used = {j.name for j in robot.joints}

    def fresh(name):
        while name in used:
            name += "_"
        used.add(name)
        return name

    root = fresh("base_link")
    links = [fresh(f"{j.name}_link") for j in robot.joints]
    end_links = {e: fresh(e) for e in robot.ends}
    end_joints = {e: fresh(f"{e}_joint") for e in robot.ends}
    return root, links, end_links, end_joints


def to_urdf(robot) -> str:
    """A kinematic URDF of ``robot`` (module docstring), as text."""
    # yourdfpy imports trimesh (1.2 s here): loaded when a URDF is first written
    from yourdfpy import URDF, Joint, Limit, Link, Mimic
    from yourdfpy import Robot as URDFRobot

    robot = load_robot(robot)
    root, links, end_links, end_joints = _urdf_names(robot)
    names = [j.name for j in robot.joints]
    joints, origins = [], {}
    for j in robot.joints:
        parent_post = robot.joints[j.parent].post if j.parent >= 0 else ()
        origin = _matrix((*parent_post, *j.pre, _motion(j, float(j.offset))))
        kind = j.type
        limit = None
        if j.limits is not None:
            limit = Limit(effort=0.0, velocity=0.0, lower=float(j.limits[0]), upper=float(j.limits[1]))
        elif kind == "revolute":
            kind = "continuous"
        else:
            limit = Limit(effort=0.0, velocity=0.0, lower=-PRISMATIC_RANGE, upper=PRISMATIC_RANGE)
        mimic = None
        if j.is_mimic:
            mimic = Mimic(joint=names[next(i for i, k in enumerate(robot.joints)
                                           if not k.is_mimic and k.variable == j.variable)],
                          multiplier=float(j.multiplier), offset=float(j.mimic_offset))
        origins[j.name] = origin
        joints.append(Joint(name=j.name, type=kind, parent=root if j.parent < 0 else links[j.parent],
                            child=links[names.index(j.name)], origin=origin,
                            axis=np.asarray(j.axis, dtype=float), limit=limit, mimic=mimic))
    for name, e in robot.ends.items():
        origin = _matrix((*robot.joints[e.parent].post, *e.ops))
        origins[end_joints[name]] = origin
        joints.append(Joint(name=end_joints[name], type="fixed", parent=links[e.parent],
                            child=end_links[name], origin=origin))
    all_links = [root] + links + list(end_links.values())
    urdf = URDF(robot=URDFRobot(name=robot.name, links=[Link(name=n) for n in all_links], joints=joints),
                build_scene_graph=False, load_meshes=False)
    xml = urdf.write_xml()
    for el in xml.getroot().iter("joint"):       # the origins written here (module docstring)
        o = el.find("origin")
        if o is not None:
            m = origins[el.get("name")]
            o.set("xyz", " ".join(repr(float(x) + 0.0) for x in m[:3, 3]))
            o.set("rpy", " ".join(repr(x) for x in rpy_of(m)))
    text = etree.tostring(xml, xml_declaration=True, pretty_print=True, encoding="utf-8")
    return text.decode("utf-8").rstrip("\n") + "\n"


def _op_entry(op) -> dict:
    if op.kind == "T":
        return {"translation": [float(x) for x in op.vector]}
    return {"rotation": {"axis": [float(x) for x in op.axis], "angle": float(op.angle)}}


def to_yaml(robot) -> str:
    """``robot`` as a description file of convention ``urdf`` (module docstring), as text."""
    robot = load_robot(robot)
    joints = []
    for i, j in enumerate(robot.joints):
        entry = {"name": j.name, "type": j.type}
        if j.parent != i - 1:
            entry["parent"] = "base" if j.parent < 0 else robot.joints[j.parent].name
        entry["origin"] = [_op_entry(op) for op in j.pre]
        entry["axis"] = [float(x) for x in j.axis]
        if j.post:
            entry["after"] = [_op_entry(op) for op in j.post]
        if float(j.offset) != 0.0:
            entry["offset"] = float(j.offset)
        if j.limits is not None:
            entry["limits"] = [float(j.limits[0]), float(j.limits[1])]
        if j.is_mimic:
            src = next(k for k in robot.joints if not k.is_mimic and k.variable == j.variable)
            entry["mimic"] = {"joint": src.name, "multiplier": float(j.multiplier),
                              "offset": float(j.mimic_offset)}
        joints.append(entry)
    ends = {name: {"parent": robot.joints[e.parent].name, "origin": [_op_entry(op) for op in e.ops]}
            for name, e in robot.ends.items()}
    data = {"name": robot.name, "title": robot.title,
            "source": f"exported by dq-derive from {robot.source or robot.path}",
            "convention": "urdf", "joints": joints, "ends": ends, "default_end": robot.default_end}
    if robot.nominal:
        data["nominal"] = robot.nominal
    header = (f"# {robot.title}: exported by dq-derive (convention urdf: each joint's origin is a list\n"
              "# of fixed transforms, then the motion along its axis, then those of after). Metres and radians.\n")
    return header + yaml.safe_dump(data, sort_keys=False, width=100, default_flow_style=None)


def write(robot, urdf_path=None, yaml_path=None) -> list:
    """Write the URDF and/or YAML export of ``robot``; returns the paths written."""
    written = []
    for path, fn in ((urdf_path, to_urdf), (yaml_path, to_yaml)):
        if path is not None:
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(fn(robot))
            written.append(path)
    return written


