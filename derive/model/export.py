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
* YAML (:func:`to_yaml`, convention ``urdf``): the same joints with the operations kept
  one by one (no multiplication, so nothing is rounded): each joint's ``origin`` lists its
  parent's post operations and its own pre operations, and its offset stays ``offset``.

Round trips keep the forward kinematics to rounding (tests: FK to 1e-12, and Pinocchio on the
exported URDF).
"""

from __future__ import annotations

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
    joints = []
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
        joints.append(Joint(name=j.name, type=kind, parent=root if j.parent < 0 else links[j.parent],
                            child=links[names.index(j.name)], origin=origin,
                            axis=np.asarray(j.axis, dtype=float), limit=limit, mimic=mimic))
    for name, e in robot.ends.items():
        origin = _matrix((*robot.joints[e.parent].post, *e.ops))
        joints.append(Joint(name=end_joints[name], type="fixed", parent=links[e.parent],
                            child=end_links[name], origin=origin))
    all_links = [root] + links + list(end_links.values())
    urdf = URDF(robot=URDFRobot(name=robot.name, links=[Link(name=n) for n in all_links], joints=joints),
                build_scene_graph=False, load_meshes=False)
    text = etree.tostring(urdf.write_xml(), xml_declaration=True, pretty_print=True, encoding="utf-8")
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
        parent_post = robot.joints[j.parent].post if j.parent >= 0 else ()
        entry = {"name": j.name, "type": j.type}
        if j.parent != i - 1:
            entry["parent"] = "base" if j.parent < 0 else robot.joints[j.parent].name
        entry["origin"] = [_op_entry(op) for op in (*parent_post, *j.pre)]
        entry["axis"] = [float(x) for x in j.axis]
        if float(j.offset) != 0.0:
            entry["offset"] = float(j.offset)
        if j.limits is not None:
            entry["limits"] = [float(j.limits[0]), float(j.limits[1])]
        if j.is_mimic:
            src = next(k for k in robot.joints if not k.is_mimic and k.variable == j.variable)
            entry["mimic"] = {"joint": src.name, "multiplier": float(j.multiplier),
                              "offset": float(j.mimic_offset)}
        joints.append(entry)
    ends = {name: {"parent": robot.joints[e.parent].name,
                   "origin": [_op_entry(op) for op in (*robot.joints[e.parent].post, *e.ops)]}
            for name, e in robot.ends.items()}
    data = {"name": robot.name, "title": robot.title,
            "source": f"exported by dq-derive from {robot.source or robot.path}",
            "convention": "urdf", "joints": joints, "ends": ends, "default_end": robot.default_end}
    if robot.nominal:
        data["nominal"] = robot.nominal
    header = (f"# {robot.title}: exported by dq-derive (convention urdf: each joint's origin is a list\n"
              "# of fixed transforms, then the motion along its axis). Metres and radians.\n")
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


