"""Export of any robot (library, YAML or URDF) as a kinematic URDF or as our YAML.

Both are written from the neutral joint form of :mod:`derive.model.robot` (T_joint = pre
Motion(axis, value + offset) post):

* URDF (:func:`to_urdf`, written by yourdfpy): a link per joint frame (``<joint>_link``, the
  root link ``base_link``) and a fixed joint per end frame (``<end>_joint`` to the link
  ``<end>``); a name that another frame has already gets a trailing ``_``.
  A URDF joint has one origin before its motion and no offset, so each joint's origin is its
  parent's ``post``, its own ``pre`` and the motion by its offset, as one ``xyz`` and one
  ``rpy`` (:func:`derive.model.origins.urdf_form`: multiplied out, rpy by :func:`rpy_of`,
  accurate at every pitch, where yourdfpy's own conversion loses up to 1e-8 near pitch =
  +-pi/2; an origin that is already one translation and rpy rotations is written as it is);
  revolute joints without limits become ``continuous``; prismatic joints without
  limits get +-``PRISMATIC_RANGE`` (a URDF prismatic joint needs limits). Mimic joints keep
  their relation. Only kinematics: no inertia, geometry or effort limits.
  Every number (origin, axis, limits, mimic) is written as the shortest text that reads back
  as the same double (Python's ``repr``, 17 significant digits at most).
* YAML (:func:`to_yaml`, convention ``urdf``): the same joints with the operations kept
  one by one (no multiplication, so nothing is rounded): each joint's ``origin`` lists its
  own pre operations and ``after`` its post operations, each end's ``origin`` its operations,
  and the offset stays ``offset``; numbers as ``repr`` writes them. Read back, it is the same
  robot: the same ``Robot.id``, every frame bit for bit.

Round trips (tests/test_export.py, every library robot): the YAML gives the same identity and
FK; the URDF, read back with every end frame as a tip, gives the FK of every end frame to
1e-15 and the same identity (Pinocchio on the exported URDF agrees, tests/test_urdf.py). A URDF
cannot keep the operations one by one, so its robot is another description of the same
kinematics (joint frames at the joint origins); the identity sees the joint origins in the
form the URDF writes (:mod:`derive.model.identity`), so it is the same robot.
"""

from __future__ import annotations

import numpy as np
import yaml
from lxml import etree

from derive.model.origins import rpy_of, urdf_form
from derive.model.robot import Robot, load_robot

__all__ = ["PRISMATIC_RANGE", "rpy_of", "to_urdf", "to_yaml", "write"]

#: Limits (m) written for a prismatic joint that has none.
PRISMATIC_RANGE = 10.0


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
    joint_origins, end_origins = urdf_form(robot.joints, robot.ends)
    joints, origins, numbers = [], {}, {}
    for j, origin in zip(robot.joints, joint_origins):
        kind = j.type
        limit = None
        if j.limits is not None:
            limit = (float(j.limits[0]), float(j.limits[1]))
        elif kind == "revolute":
            kind = "continuous"
        else:
            limit = (-PRISMATIC_RANGE, PRISMATIC_RANGE)
        mimic = None
        if j.is_mimic:
            mimic = Mimic(joint=names[next(i for i, k in enumerate(robot.joints)
                                           if not k.is_mimic and k.variable == j.variable)],
                          multiplier=float(j.multiplier), offset=float(j.mimic_offset))
        origins[j.name] = origin
        numbers[j.name] = (tuple(float(a) for a in j.axis), limit, mimic)
        joints.append(Joint(name=j.name, type=kind, parent=root if j.parent < 0 else links[j.parent],
                            child=links[names.index(j.name)], origin=np.eye(4),
                            axis=np.asarray(j.axis, dtype=float),
                            limit=None if limit is None else Limit(effort=0.0, velocity=0.0,
                                                                   lower=limit[0], upper=limit[1]),
                            mimic=mimic))
    for name, e in robot.ends.items():
        origins[end_joints[name]] = end_origins[name]
        joints.append(Joint(name=end_joints[name], type="fixed", parent=links[e.parent],
                            child=end_links[name], origin=np.eye(4)))
    all_links = [root] + links + list(end_links.values())
    urdf = URDF(robot=URDFRobot(name=robot.name, links=[Link(name=n) for n in all_links], joints=joints),
                build_scene_graph=False, load_meshes=False)
    xml = urdf.write_xml()
    for el in xml.getroot().iter("joint"):       # the numbers, as repr writes them (module docstring)
        xyz, rpy = origins[el.get("name")]
        o = el.find("origin")
        if o is None:
            o = etree.SubElement(el, "origin")
            el.insert(0, o)
        o.set("xyz", _text(xyz))
        o.set("rpy", _text(rpy))
        if el.get("name") not in numbers:
            continue
        axis, limit, mimic = numbers[el.get("name")]
        el.find("axis").set("xyz", _text(axis))
        if limit is not None:
            el.find("limit").set("lower", _text(limit[:1]))
            el.find("limit").set("upper", _text(limit[1:]))
        if mimic is not None:       # yourdfpy (0.0.60) does not write <mimic>: written here
            m = el.find("mimic")
            if m is None:
                m = etree.SubElement(el, "mimic")
            m.set("joint", mimic.joint)
            m.set("multiplier", _text([mimic.multiplier]))
            m.set("offset", _text([mimic.offset]))
    text = etree.tostring(xml, xml_declaration=True, pretty_print=True, encoding="utf-8")
    return text.decode("utf-8").rstrip("\n") + "\n"


def _text(numbers) -> str:
    """Numbers as the shortest text that reads back as the same doubles (repr; -0.0 as 0.0)."""
    return " ".join(repr(float(x) + 0.0) for x in numbers)


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


