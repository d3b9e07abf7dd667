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

With several tips (``tip`` a list of links) the description is the tree of their paths from
``base``: a joint's parent is the nearest moving joint above it, and each tip is an end frame
(the first is the default end).

Each origin is kept as the file writes it: its ``xyz`` as a translation, its ``rpy`` as the
rotations Rz(yaw) Ry(pitch) Rx(roll) (the URDF specification's R = Rz Ry Rx), the numbers read
from the file's text, so that a URDF written by :mod:`derive.model.export` reads back as the
numbers it was written from (:mod:`derive.model.origins`). URDF is in metres and radians.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path

import numpy as np
from lxml import etree

from derive.errors import RobotFileError

MOVING = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic"}


def _origins(root) -> dict:
    """{joint name: (xyz, rpy)} of the file's ``<origin>`` elements, as written (3 numbers each,
    0 where missing)."""
    out = {}
    for el in root.findall("joint"):
        o = el.find("origin")
        texts = ("0 0 0", "0 0 0") if o is None else (o.get("xyz", "0 0 0"), o.get("rpy", "0 0 0"))
        try:
            out[el.get("name")] = tuple([float(v) for v in t.split()] for t in texts)
        except ValueError:
            raise RobotFileError(f"joint {el.get('name')!r}: <origin xyz={texts[0]!r} rpy={texts[1]!r}> "
                                 "is not numeric") from None
    return out


def _origin(xyz_rpy, where: str) -> dict:
    """{translation, rotation: {rpy}} of an origin (rotation omitted when its rpy is 0 0 0).
    An angle beyond 2 pi (not one a file means; the description refuses it as degrees) is
    taken modulo 2 pi."""
    xyz, rpy = xyz_rpy
    if len(xyz) != 3 or len(rpy) != 3:
        raise RobotFileError(f"{where}: the origin needs 3 numbers in xyz and in rpy")
    if not all(math.isfinite(x) for x in (*xyz, *rpy)):
        raise RobotFileError(f"{where}: the origin is not finite (nan or inf in xyz or rpy)")
    out = {"translation": [x + 0.0 for x in xyz]}
    if any(a != 0.0 for a in rpy):
        out["rotation"] = {"rpy": [a if abs(a) <= 2.0 * math.pi else math.fmod(a, 2.0 * math.pi)
                                   for a in rpy]}
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
    """(yourdfpy's model, the lxml root) of a URDF text."""
    root = _parse_xml(name, text)
    if root.tag != "robot":
        raise RobotFileError(f"{name}: the top element is <{root.tag}>, a URDF has <robot>")
    # yourdfpy imports trimesh (1.2 s here): loaded when a URDF is first read, not with derive
    import yourdfpy
    try:
        with np.errstate(invalid="ignore"):      # nan / inf origins are reported below, by joint
            urdf = yourdfpy.URDF.load(io.BytesIO(text.encode("utf-8")), build_scene_graph=False,
                                      load_meshes=False, build_collision_scene_graph=False,
                                      load_collision_meshes=False)
    except ValueError as exc:
        where = _non_numeric(root)
        raise RobotFileError(f"{name}: {where or f'not a valid URDF ({exc})'}") from None
    except Exception as exc:        # yourdfpy raises assorted errors for malformed URDFs
        raise RobotFileError(f"{name}: not a valid URDF ({type(exc).__name__}: {exc})") from None
    return urdf, root


def _tree(name: str, robot, base: str | None, tip) -> tuple[str, list, list]:
    """(base, tips, joints): the joints on the paths from ``base`` to each tip, parents before
    children, in the file's order otherwise."""
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
    tips = [tip] if isinstance(tip, str) else list(tip)
    if not tips or len(set(tips)) != len(tips) or not all(isinstance(t, str) for t in tips):
        raise RobotFileError(f"{name}: tip must be a link name or a list of distinct link names, got {tip!r}")
    for role, link in [("base", base)] + [("tip", t) for t in tips]:
        if link not in links:
            raise RobotFileError(f"{name}: {role} link {link!r} is not a link of the file "
                                 f"(links: {', '.join(sorted(links))})")
    on_paths = set()
    for t in tips:
        k = t
        while k != base:
            if k not in by_child:
                raise RobotFileError(f"{name}: tip link {t!r} is not below base link {base!r}")
            on_paths.add(by_child[k].name)
            k = by_child[k].parent
    joints = [j for j in robot.joints if j.name in on_paths]      # file order
    placed, ordered = set(), []

    def place(j):
        if j.name in placed:
            return
        if j.parent != base:
            place(by_child[j.parent])
        placed.add(j.name)
        ordered.append(j)

    for j in joints:
        place(j)
    return base, tips, ordered


def _fixed_above(link: str, base: str, by_child: dict) -> tuple[str | None, list]:
    """(the nearest moving joint above ``link``, or None at the base; the fixed joints between,
    top first)."""
    fixed, k = [], link
    while k != base and by_child[k].type == "fixed":
        fixed.append(by_child[k])
        k = by_child[k].parent
    return (None if k == base else by_child[k].name), fixed[::-1]


def urdf_description(path: str, text: str, base: str | None = None, tip=None) -> dict:
    """The description (a dict for :func:`derive.model.robot.robot_from_dict`, convention
    ``urdf``) of the chain from ``base`` to ``tip`` of the URDF ``text`` read from ``path``
    (``tip`` a list of links: the tree of their chains, each tip an end frame)."""
    name = Path(path).name
    urdf, root = _load(name, text)
    base, tips, tree = _tree(name, urdf.robot, base, tip)
    by_child = {j.child: j for j in urdf.robot.joints}
    try:
        written = _origins(root)
    except RobotFileError as exc:
        raise RobotFileError(f"{name}: {exc}") from None
    chain_text = f"{base} -> {', '.join(tips)}"

    def origins(fixed, where):
        return [_origin(written.get(f.name, ([0.0] * 3, [0.0] * 3)), f"{name}: joint {f.name!r}{where}")
                for f in fixed]

    joints, moving = [], [j.name for j in tree if j.type != "fixed"]
    previous = None
    for j in tree:
        where = f"{name}: joint {j.name!r}"
        if j.type == "fixed":
            continue
        if j.type not in MOVING:
            raise RobotFileError(f"{where}: type {j.type!r} is not supported on the chain "
                                 "(revolute, continuous, prismatic and fixed joints are)")
        parent, fixed = _fixed_above(j.parent, base, by_child)
        axis = [float(x) for x in (j.axis if j.axis is not None else (1.0, 0.0, 0.0))]
        n = math.sqrt(sum(x * x for x in axis))
        if not math.isfinite(n) or n == 0.0:
            raise RobotFileError(f"{where}: axis {axis} is not a direction (zero, nan or inf)")
        entry = {"name": j.name, "type": MOVING[j.type], "origin": origins(fixed + [j], ""),
                 # a unit axis as written (the description normalises it the way a YAML's is)
                 "axis": axis if abs(n - 1.0) <= 1e-9 else [x / n for x in axis]}
        if parent != previous:
            entry["parent"] = parent or "base"
        previous = j.name
        if j.type != "continuous" and j.limit is not None and j.limit.lower is not None \
                and j.limit.upper is not None and j.limit.lower < j.limit.upper:
            entry["limits"] = [float(j.limit.lower), float(j.limit.upper)]
        if j.mimic is not None:
            if j.mimic.joint not in moving:
                raise RobotFileError(f"{where}: mimics joint {j.mimic.joint!r}, which is not on the "
                                     f"chain {chain_text}")
            entry["mimic"] = {"joint": j.mimic.joint,
                              "multiplier": float(j.mimic.multiplier if j.mimic.multiplier is not None else 1.0),
                              "offset": float(j.mimic.offset or 0.0)}
        joints.append(entry)
    if not joints:
        raise RobotFileError(f"{name}: the chain {chain_text} has no moving joint")
    ends = {}
    for t in tips:
        parent, fixed = _fixed_above(t, base, by_child)
        if parent is None:
            raise RobotFileError(f"{name}: no moving joint between base link {base!r} and tip link {t!r}")
        ends[t] = {"origin": origins(fixed, "")}
        if parent != joints[-1]["name"]:
            ends[t]["parent"] = parent
    # the robot is named after the file (ur5_robot.urdf -> ur5_robot), which keeps its outputs
    # apart from a library robot of the URDF's <robot name> (often ur5, panda)
    robot_name = re.sub(r"[^A-Za-z0-9_.-]", "-", Path(path).name.removesuffix(".urdf")).lstrip("-.") or "urdf"
    data = {
        "name": robot_name, "title": f"{urdf.robot.name or robot_name} (URDF {name}, {chain_text})",
        "source": f"URDF file {path}, chain {chain_text}", "convention": "urdf",
        "joints": joints, "ends": ends, "default_end": tips[0],
    }
    return data
