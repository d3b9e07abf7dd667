"""Cartesian path to joint path: one configuration per pose, chained along the path, and the
robot program that drives it (docs/path.md).

Each pose's configuration is the IK solution nearest to the previous one
(:meth:`derive.codegen.loader.Kernels.nearest`: inside the joint limits, every 2 pi winding
considered, the least largest single-joint move, then the least summed move); the first is
nearest to ``q_start``. For a seven-joint arm the free parameter and the branch are chosen by the
same ``nearest`` (:func:`derive.ik.redundant.nearest`, a 1-D search from the previous
configuration's own free value). What happens along the way is reported with the pose's index
(:class:`PathEvent`): a pose without any solution (``unreachable``, with the reason), a pose whose
solutions all lie outside the joint limits (``limit``), a change of the closed form's branch
(``branch``), a stretch of singular configurations (``singular``) and a step larger than
``max_step`` (``jump``). A pose without a configuration leaves its row NaN, and the next pose is
chained from the last configuration found.

:func:`urscript` writes the joint path as a URScript program of ``movej`` (Universal Robots'
script manual: joint positions in rad, ``a`` joint acceleration in rad/s^2, ``v`` joint speed in
rad/s, ``r`` blend radius in m). :func:`read_poses` reads poses from CSV or JSON files.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from derive import reference
from derive.codegen.loader import kernels
from derive.errors import DeriveError, InputError, as_finite_array
from derive.kinematics.pose import as_pose_batch, from_position_quaternion
from derive.model.robot import load_robot

EVENT_KINDS = ("unreachable", "limit", "branch", "singular", "jump")

#: A step above this (rad, or m for a prismatic joint) between consecutive configurations is
#: reported as a ``jump`` (the path is not continuous there at its sampling).
MAX_STEP = 0.5

#: URScript ``movej`` defaults of Universal Robots' script manual: joint acceleration (rad/s^2)
#: and speed (rad/s); blend radius 0 (m): the arm stops at every configuration.
UR_ACCEL, UR_SPEED, UR_BLEND = 1.4, 1.05, 0.0

#: The columns of a pose file: position (m) and unit quaternion in scipy / ROS order.
POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")


@dataclass(frozen=True)
class PathEvent:
    """Something along the path, at pose ``index`` (0-based): ``kind`` one of
    :data:`EVENT_KINDS`, and a sentence."""

    index: int
    kind: str
    message: str

    def __str__(self) -> str:
        return f"pose {self.index}: {self.kind}: {self.message}"


@dataclass(frozen=True)
class JointPath:
    """The joint path of a Cartesian path: ``q`` (n, dof) in rad (m for prismatic joints), NaN
    rows where a pose has no configuration; per pose ``found``, ``branch`` (the closed form's
    branch index, -1 where none), ``singular`` and ``step`` (the largest single-joint move from
    the previous configuration found, for pose 0 from ``q_start``; NaN where none); and the
    ``events`` in pose order."""

    robot: str
    joint_names: tuple
    q: np.ndarray
    found: np.ndarray
    branch: np.ndarray
    singular: np.ndarray
    step: np.ndarray
    events: tuple = field(default_factory=tuple)

    @property
    def complete(self) -> bool:
        """Whether every pose has its configuration."""
        return bool(np.all(self.found))

    def events_of(self, kind: str) -> list:
        return [e for e in self.events if e.kind == kind]

    def to_dict(self) -> dict:
        """JSON-ready: numbers (NaN as null), names and units."""
        def clean(a):
            return [None if isinstance(x, float) and not math.isfinite(x) else x for x in a]
        return {"robot": self.robot, "joints": list(self.joint_names), "units": "rad (prismatic joints: m)",
                "q": [clean(row) for row in self.q.tolist()], "found": self.found.tolist(),
                "branch": self.branch.tolist(), "singular": self.singular.tolist(),
                "step": clean(self.step.tolist()), "complete": self.complete,
                "events": [{"index": e.index, "kind": e.kind, "message": e.message} for e in self.events]}


def path(robot, poses, q_start, backend: str = "c", max_step: float = MAX_STEP) -> JointPath:
    """The joint path of ``poses`` (unit dual quaternions (n, 8) or 4x4 matrices (n, 4, 4) of
    the robot's default end frame in its base frame), starting nearest to ``q_start`` (dof,):
    see the module docstring. ``backend``: the kernels that solve it (:func:`derive.kernels`);
    ``max_step``: steps above it are reported as ``jump`` events. A robot without IK
    kernels raises :class:`~derive.errors.DeriveError`; an unreachable pose does not (an event)."""
    robot = load_robot(robot)
    if not (isinstance(max_step, (int, float)) and not isinstance(max_step, bool)
            and math.isfinite(max_step) and max_step > 0):
        raise InputError(f"max_step: expected a finite number > 0 (rad or m), got {max_step!r}")
    P, _ = as_pose_batch(poses)           # (n, 8), a single pose as n = 1
    if len(P) == 0:
        raise InputError("poses: the path has no poses")
    seed = as_finite_array(q_start, "q_start", last_dim=robot.dof)
    if seed.shape != (robot.dof,):
        raise InputError(f"q_start: expected {robot.dof} joint values, got shape {seed.shape}")
    k = kernels(robot, backend)
    if not k.has_ik:
        raise DeriveError(f"{robot.name}: no IK kernels, so no path (derive.refine solves single poses)")
    n, dof = len(P), robot.dof
    q = np.full((n, dof), np.nan)
    found = np.zeros(n, dtype=bool)
    branch = np.full(n, -1, dtype=int)
    singular = np.zeros(n, dtype=bool)
    step = np.full(n, np.nan)
    events: list[PathEvent] = []
    last_branch = -1
    for i in range(n):
        res = k.nearest(P[i], seed)
        if not bool(res.found):
            events.append(_failure(robot, k, P[i], i))
            continue
        q[i], found[i], branch[i], singular[i] = res.q, True, int(res.branch), bool(res.singular)
        step[i] = float(np.max(np.abs(res.q - seed)))
        if last_branch >= 0 and branch[i] != last_branch:
            events.append(PathEvent(i, "branch", f"IK branch {last_branch} -> {branch[i]}"
                                                 f"{_labels(k, last_branch, branch[i])}"))
        if step[i] > max_step:
            j = int(np.argmax(np.abs(res.q - seed)))
            events.append(PathEvent(i, "jump", f"joint {robot.variable_names[j]} moves "
                                               f"{res.q[j] - seed[j]:+.4g} (more than {max_step:g})"))
        seed, last_branch = res.q, branch[i]
    events += _singular_stretches(singular)
    events.sort(key=lambda e: (e.index, EVENT_KINDS.index(e.kind)))
    return JointPath(robot.name, robot.variable_names, q, found, branch, singular, step, tuple(events))


def _labels(k, a: int, b: int) -> str:
    """Which closed-form steps changed root between branch ids a and b (their bits)."""
    labels = k.branch_labels
    if not labels:
        return ""
    width = len(labels)
    if min(a, b) < 0 or max(a, b) >= 1 << width:
        # a solution outside the closed form's branches (a near-class arm's seeded extra slot,
        # derive.codegen.polish.polish_width; a general arm's -1): no steps to name
        return " (a solution found by a seed, outside the closed form's branches)"
    changed = [labels[bit] for bit in range(width) if (a >> (width - 1 - bit)) & 1 != (b >> (width - 1 - bit)) & 1]
    return f" ({', '.join(changed)})" if changed else ""


def _failure(robot, k, pose, i: int) -> PathEvent:
    """Why pose i has no configuration: no solution at all, or none inside the limits."""
    if k.free:           # seven joints: solutions anywhere along the free parameter?
        sweep = k.ik_sweep(pose, 36, within_limits=False)
        if int(np.sum(sweep.counts)) == 0:
            return PathEvent(i, "unreachable", "no solution at any value of the free parameter")
        return PathEvent(i, "limit", "solutions exist, none inside the joint limits at any value "
                                     "of the free parameter")
    _, count = k.ik(pose)
    if int(np.ravel(count)[0]) == 0:
        try:
            why = reference.ik(robot, pose).reason
        except DeriveError:
            why = ""
        return PathEvent(i, "unreachable", why.removeprefix("unreachable: ") or "the IK has no solution")
    return PathEvent(i, "limit", f"{int(np.ravel(count)[0])} solution(s), none inside the joint limits")


def _singular_stretches(singular: np.ndarray) -> list:
    out, i, n = [], 0, len(singular)
    while i < n:
        if singular[i]:
            j = i
            while j + 1 < n and singular[j + 1]:
                j += 1
            where = f"pose {i}" if i == j else f"poses {i}-{j}"
            out.append(PathEvent(i, "singular", f"singular configuration at {where} (a joint the "
                                                f"singularity leaves free keeps its previous value)"))
            i = j + 1
        else:
            i += 1
    return out


# --------------------------------------------------------------------------- #
# Input: pose files
# --------------------------------------------------------------------------- #
def read_poses(file) -> np.ndarray:
    """Unit dual quaternions (n, 8) from a pose file: CSV with the header ``x,y,z,qx,qy,qz,qw``
    (position in m, unit quaternion in scipy / ROS order) and one pose per line, or JSON: a list
    of such 7-number rows or of objects with those keys. Raises
    :class:`~derive.errors.InputError` naming the line or entry of a malformed pose."""
    file = Path(file)
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{file}: cannot be read ({exc.strerror})") from None
    rows = _json_rows(file, text) if text.lstrip().startswith("[") else _csv_rows(file, text)
    if not rows:
        raise InputError(f"{file}: no poses")
    poses = []
    for where, row in rows:
        try:
            poses.append(from_position_quaternion(row[:3], row[3:], order="xyzw"))
        except InputError as exc:
            raise InputError(f"{file}: {where}: {exc}") from None
    return np.stack(poses)


def _number(text, where: str) -> float:
    try:
        x = float(text)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(x) or isinstance(text, bool):
        raise InputError(f"{where}: {text!r} is not a finite number")
    return x


def _csv_rows(file: Path, text: str) -> list:
    lines = list(csv.reader(io.StringIO(text)))
    lines = [(k + 1, [c.strip() for c in line]) for k, line in enumerate(lines) if any(c.strip() for c in line)]
    if not lines or [c.lower() for c in lines[0][1]] != list(POSE_COLUMNS):
        got = ",".join(lines[0][1]) if lines else "an empty file"
        raise InputError(f"{file}: line 1: expected the header {','.join(POSE_COLUMNS)}, got {got!r}")
    out = []
    for k, cells in lines[1:]:
        where = f"{file}: line {k}"
        if len(cells) != len(POSE_COLUMNS):
            raise InputError(f"{where}: expected {len(POSE_COLUMNS)} values, got {len(cells)}")
        out.append((f"line {k}", [_number(c, where) for c in cells]))
    return out


def _json_rows(file: Path, text: str) -> list:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{file}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, list):
        raise InputError(f"{file}: expected a JSON list of poses")
    out = []
    for k, entry in enumerate(data):
        where = f"{file}: entry {k}"
        if isinstance(entry, dict):
            if set(entry) != set(POSE_COLUMNS):
                raise InputError(f"{where}: expected the keys {', '.join(POSE_COLUMNS)}, got {', '.join(map(str, entry))}")
            entry = [entry[c] for c in POSE_COLUMNS]
        if not isinstance(entry, list) or len(entry) != len(POSE_COLUMNS):
            raise InputError(f"{where}: expected [{', '.join(POSE_COLUMNS)}] or an object with those keys")
        out.append((f"entry {k}", [_number(x, where) for x in entry]))
    return out


# --------------------------------------------------------------------------- #
# Output: CSV and URScript
# --------------------------------------------------------------------------- #
def to_csv(jp: JointPath) -> str:
    """The joint path as CSV: a header ``index,<joint names>`` and one row per pose (rad, m;
    ``nan`` where a pose has no configuration), numbers in round-trip precision."""
    lines = ["index," + ",".join(jp.joint_names)]
    lines += [f"{i}," + ",".join(repr(float(x)) for x in row) for i, row in enumerate(jp.q)]
    return "\n".join(lines) + "\n"


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_program_options(name: str = "dq_path", accel: float = UR_ACCEL, speed: float = UR_SPEED,
                          blend: float = UR_BLEND) -> None:
    """Raise :class:`~derive.errors.InputError` unless ``name`` is a URScript identifier,
    ``accel`` and ``speed`` finite and > 0 and ``blend`` finite and >= 0."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise InputError(f"name: {name!r} is not a URScript identifier (letters, digits, '_')")
    for what, value, strict in (("accel", accel, True), ("speed", speed, True), ("blend", blend, False)):
        if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                and (value > 0 if strict else value >= 0)):
            raise InputError(f"{what}: expected a finite number {'> 0' if strict else '>= 0'}, got {value!r}")


def urscript(jp: JointPath, name: str = "dq_path", accel: float = UR_ACCEL, speed: float = UR_SPEED,
             blend: float = UR_BLEND) -> str:
    """A URScript program ``def <name>(): ... end`` that moves through the joint path with one
    ``movej([q1, ..., q6], a=accel, v=speed, r=blend)`` per pose: joint positions in rad, ``a``
    the joint acceleration (rad/s^2), ``v`` the joint speed (rad/s), ``r`` the blend radius (m;
    0 stops at every configuration), as Universal Robots' script manual defines them. Only for
    six-joint arms and a complete path (:class:`~derive.errors.DeriveError` otherwise). The
    joint values are the description's: for the library UR robots, described by Universal
    Robots' published DH parameters, the controller's joint angles."""
    check_program_options(name, accel, speed, blend)
    if len(jp.joint_names) != 6:
        raise DeriveError(f"URScript drives six-joint arms; {jp.robot} has {len(jp.joint_names)} joints")
    if not jp.complete:
        missing = np.nonzero(~jp.found)[0]
        raise DeriveError(f"no URScript program: pose(s) {', '.join(map(str, missing[:10]))}"
                          f"{' ...' if len(missing) > 10 else ''} have no configuration")
    lines = [f"def {name}():",
             f"  # dq-derive: joint path of {jp.robot}, {len(jp.q)} poses; joints "
             f"{', '.join(jp.joint_names)} in rad",
             f"  # a = {accel!r} rad/s^2, v = {speed!r} rad/s, r = {blend!r} m"]
    for row in jp.q:
        lines.append(f"  movej([{', '.join(repr(float(x)) for x in row)}], a={accel!r}, v={speed!r}, r={blend!r})")
    lines.append("end")
    return "\n".join(lines) + "\n"
