"""URDF input: the serial chain between two links of a URDF, as a description of convention
``urdf`` (:mod:`derive.model.robot`).

The file is parsed by yourdfpy (a maintained URDF library; lxml reads the XML first, so a
syntax error is reported with its line). The chain is the path of joints from ``base`` to
``tip`` (defaults: the root link, and the single leaf link; with several leaves the error
names them). Along it:

* ``revolute``, ``continuous`` (a revolute joint without limits) and ``prismatic`` joints are
  the joints of the description, named as in the URDF, with their ``axis`` and ``limit``;
  ``mimic`` joints keep their relation (joint, multiplier, offset);
* ``fixed`` joints are folded in: their origins join the origin list of the next moving joint
  (so the links before the first moving joint become part of its origin: the base transform),
  and those after the last moving joint become the end frame named after ``tip`` (the tool);
* ``floating`` and ``planar`` joints are refused.

Each origin is written as a translation (``xyz``) and a rotation about one axis (from the
origin's rotation matrix via its quaternion, which is accurate at every angle, unlike an
``rpy`` triple read back near pitch = +-pi/2). URDF is in metres and radians.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path

import numpy as np
from lxml import etree

from derive.algebra import quaternion as quat
from derive.errors import RobotFileError

MOVING = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic"}


def _origin(matrix, where: str) -> dict:
    """{translation, rotation} of a 4x4 origin (rotation omitted when it is the identity)."""
    m = np.asarray(matrix, dtype=float)
    if not np.all(np.isfinite(m)):
        raise RobotFileError(f"{where}: the origin is not finite (nan or inf in xyz or rpy)")
    out = {"translation": [float(x) for x in m[:3, 3]]}
    q = quat.from_matrix(m[:3, :3])
    q = -q if q[0] < 0 else q
    vn = float(np.linalg.norm(q[1:]))
    if vn > 0.0:
        angle = 2.0 * math.atan2(vn, float(q[0]))
        out["rotation"] = {"axis": [float(x) / vn for x in q[1:]], "angle": angle}
    return out


def _parse_xml(name: str, text: str):
    try:
        return etree.fromstring(text.encode("utf-8"))
    except etree.XMLSyntaxError as exc:
        raise RobotFileError(f"{name}: not valid XML ({exc})") from None


def _non_numeric(root) -> str:
    """Where a numeric attribute of the URDF does not read as numbers (for the error)."""
    for el in root.iter("joint", "link"):
        owner = f"{el.tag} {el.get('name')!r}"
        for sub in el.iter("origin", "axis", "limit", "mimic"):
            for key, value in sub.attrib.items():
                if key in ("xyz", "rpy", "lower", "upper", "multiplier", "offset"):
                    try:
                        [float(v) for v in value.split()]
                    except ValueError:
                        return f"{owner}: <{sub.tag} {key}={value!r}> is not numeric"
    return ""


def _load(name: str, text: str):
    root = _parse_xml(name, text)
    if root.tag != "robot":
        raise RobotFileError(f"{name}: the top element is <{root.tag}>, a URDF has <robot>")
    # yourdfpy imports trimesh (1.2 s here): loaded when a URDF is first read, not with derive
    import yourdfpy
    try:
        with np.errstate(invalid="ignore"):      # nan / inf origins are reported below, by joint
            return yourdfpy.URDF.load(io.BytesIO(text.encode("utf-8")), build_scene_graph=False,
                                      load_meshes=False, build_collision_scene_graph=False,
                                      load_collision_meshes=False)
    except ValueError as exc:
        where = _non_numeric(root)
        raise RobotFileError(f"{name}: {where or f'not a valid URDF ({exc})'}") from None
    except Exception as exc:        # yourdfpy raises assorted errors for malformed URDFs
        raise RobotFileError(f"{name}: not a valid URDF ({type(exc).__name__}: {exc})") from None


def _chain(name: str, robot, base: str | None, tip: str | None) -> tuple[str, str, list]:
    links = {link.name for link in robot.links}
    for j in robot.joints:
        for role in ("parent", "child"):
            if getattr(j, role) not in links:
                raise RobotFileError(f"{name}: joint {j.name!r}: {role} link {getattr(j, role)!r} "
                                     "is not a link of the file")
    by_child = {j.child: j for j in robot.joints}
    parents = {j.parent for j in robot.joints}
    roots = sorted(links - set(by_child))
    leaves = sorted(links - parents)
    if base is None:
        if len(roots) != 1:
            raise RobotFileError(f"{name}: several root links {roots}; choose one with base= (--base)"
                                 if roots else f"{name}: no root link (the file has no links, or a cycle)")
        base = roots[0]
    if tip is None:
        if len(leaves) != 1:
            raise RobotFileError(f"{name}: several leaf links {leaves}; choose the tip with tip= (--tip)")
        tip = leaves[0]
    for role, link in (("base", base), ("tip", tip)):
        if link not in links:
            raise RobotFileError(f"{name}: {role} link {link!r} is not a link of the file "
                                 f"(links: {', '.join(sorted(links))})")
    path, k = [], tip
    while k != base:
        if k not in by_child:
            raise RobotFileError(f"{name}: tip link {tip!r} is not below base link {base!r}")
        path.append(by_child[k])
        k = by_child[k].parent
    return base, tip, path[::-1]


def urdf_description(path: str, text: str, base: str | None = None, tip: str | None = None) -> dict:
    """The description (a dict for :func:`derive.model.robot.robot_from_dict`, convention
    ``urdf``) of the chain from ``base`` to ``tip`` of the URDF ``text`` read from ``path``."""
    name = Path(path).name
    urdf = _load(name, text)
    base, tip, chain = _chain(name, urdf.robot, base, tip)
    joints, pending = [], []
    on_chain = {j.name for j in chain}
    for j in chain:
        where = f"{name}: joint {j.name!r}"
        origin = _origin(j.origin if j.origin is not None else np.eye(4), where)
        if j.type == "fixed":
            pending.append(origin)
            continue
        if j.type not in MOVING:
            raise RobotFileError(f"{where}: type {j.type!r} is not supported on the chain "
                                 "(revolute, continuous, prismatic and fixed joints are)")
        axis = [float(x) for x in (j.axis if j.axis is not None else (1.0, 0.0, 0.0))]
        n = math.sqrt(sum(x * x for x in axis))
        if not math.isfinite(n) or n == 0.0:
            raise RobotFileError(f"{where}: axis {axis} is not a direction (zero, nan or inf)")
        entry = {"name": j.name, "type": MOVING[j.type], "origin": pending + [origin],
                 "axis": [x / n for x in axis]}
        pending = []
        if j.type != "continuous" and j.limit is not None and j.limit.lower is not None \
                and j.limit.upper is not None and j.limit.lower < j.limit.upper:
            entry["limits"] = [float(j.limit.lower), float(j.limit.upper)]
        if j.mimic is not None:
            if j.mimic.joint not in on_chain:
                raise RobotFileError(f"{where}: mimics joint {j.mimic.joint!r}, which is not on the "
                                     f"chain {base} -> {tip}")
            entry["mimic"] = {"joint": j.mimic.joint,
                              "multiplier": float(j.mimic.multiplier if j.mimic.multiplier is not None else 1.0),
                              "offset": float(j.mimic.offset or 0.0)}
        joints.append(entry)
    if not joints:
        raise RobotFileError(f"{name}: the chain {base} -> {tip} has no moving joint")
    # the robot is named after the file (ur5_robot.urdf -> ur5_robot), which keeps its outputs
    # apart from a library robot of the URDF's <robot name> (often ur5, panda)
    robot_name = re.sub(r"[^A-Za-z0-9_.-]", "-", Path(path).name.removesuffix(".urdf")).lstrip("-.") or "urdf"
    data = {
        "name": robot_name, "title": f"{urdf.robot.name or robot_name} (URDF {name}, {base} -> {tip})",
        "source": f"URDF file {path}, chain {base} -> {tip}", "convention": "urdf",
        "joints": joints, "ends": {tip: {"origin": pending}}, "default_end": tip,
    }
    return data
