"""Figures of an arm drawn by the code (matplotlib's object interface on the Agg canvas, no pyplot and no display; PNG).

* :func:`arm_figure`: the arm at one configuration as a 3-D stick figure through the frame
  origins of :func:`derive.reference.joint_positions` (base, every joint frame, every end
  frame), each joint's motion axis (a dashed line through the point it passes, in the
  direction it has at that configuration) and the x, y, z axes of the base and end frames
  (red, green, blue);
* :func:`ik_figure`: every closed-form IK solution (:func:`derive.reference.ik`) of the pose of
  one configuration, side by side on the same scale, with the target frame.

Both return what they drew (the frame origins, and the solutions), so that a test can compare
the figure with the reference. Lengths in metres; angles in radians unless ``deg`` is set,
which changes only the labels.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from derive import reference
from derive.algebra import dualquat as dq
from derive.model.geometry import op_matrix
from derive.model.robot import load_robot

#: Colours of a frame's x, y, z axes.
AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")
#: PNG resolution (dots per inch).
DPI = 110


def joint_axes(robot, q) -> tuple[np.ndarray, np.ndarray]:
    """(points (n_joints, 3), unit directions (n_joints, 3)) of every joint's motion axis in the
    base frame at configuration ``q``: the axis leaves the parent frame after the joint's fixed
    motions ``pre`` (a point on it is that frame's origin)."""
    robot = load_robot(robot)
    frames = [dq.to_matrix(f) for f in reference.frame_poses(robot, q)]   # base, joints, ends
    points, dirs = [], []
    for j in robot.joints:
        m = frames[j.parent + 1]                  # index 0 is the base
        for op in j.pre:
            m = m @ op_matrix(op)
        points.append(m[:3, 3])
        dirs.append(m[:3, :3] @ np.asarray(j.axis, dtype=float))
    return np.array(points), np.array(dirs)


def _value_text(robot, q, deg: bool) -> str:
    """Joint values as "name=value unit" for titles."""
    parts = []
    for j, v in zip((j for j in robot.joints if not j.is_mimic), q):
        if j.type == "prismatic":
            parts.append(f"{j.name}={_clean(v, 3)} m")
        elif deg:
            parts.append(f"{j.name}={_clean(math.degrees(v), 1)}°")
        else:
            parts.append(f"{j.name}={_clean(v, 3)}")
    return ", ".join(parts) + ("" if deg else " (rad, m)")


def _vector_text(robot, q, deg: bool) -> str:
    """Joint values as one tuple "q = (a, b, ...) unit" (in joint order) for panel titles."""
    vals = [_clean(v, 3) if j.type == "prismatic" or not deg else _clean(math.degrees(v), 1)
            for j, v in zip((j for j in robot.joints if not j.is_mimic), q)]
    prismatic = any(j.type == "prismatic" for j in robot.joints if not j.is_mimic)
    unit = ("deg" if deg else "rad") + (", m" if prismatic else "")
    return f"q = ({', '.join(vals)}) {unit}"


def _clean(x: float, prec: int) -> str:
    """x with ``prec`` decimals, never "-0.0"."""
    return f"{round(float(x), prec) + 0.0:.{prec}f}"


def _wrap(text: str, width: int) -> str:
    """Break a comma-separated text into lines of at most ``width`` characters."""
    lines, line = [], ""
    for part in text.split(", "):
        cand = part if not line else f"{line}, {part}"
        if len(cand) > width and line:
            lines.append(line + ",")
            line = part
        else:
            line = cand
    return "\n".join(lines + [line])


def _scale(points: np.ndarray) -> float:
    """A length for axis arrows: a tenth of the figure's extent (at least 1 cm)."""
    ext = np.max(np.ptp(points.reshape(-1, 3), axis=0))
    return max(0.1 * float(ext), 0.01)


def _equal_limits(ax, points: np.ndarray) -> None:
    """The same scale on x, y and z: a cube around every drawn point."""
    pts = points.reshape(-1, 3)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    half = 0.5 * float(np.max(np.ptp(pts, axis=0))) * 1.08 + 1e-3
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")


def _triad(ax, pose: np.ndarray, length: float, width: float = 1.6) -> None:
    m = dq.to_matrix(pose)
    o = m[:3, 3]
    for k in range(3):
        e = o + length * m[:3, k]
        ax.plot(*zip(o, e), color=AXIS_COLOURS[k], linewidth=width)


def draw_arm(ax, robot, q, *, length: float, labels: bool = True, colour: str = "0.25",
             axes: bool = True) -> np.ndarray:
    """Draw the arm at ``q`` into a 3-D axes: links through the frame origins, frame origins as
    dots, joint axes (dashed, ``axes``), base and end frames; each joint's name at the end of its
    axis when ``labels`` (in DH conventions a joint's frame sits at the far end of its link, so
    the name goes with the axis, not the frame). Returns the
    drawn frame origins (m, 3), in the order of ``robot.frame_names``."""
    robot = load_robot(robot)
    pos = reference.joint_positions(robot, q)
    poses = reference.frame_poses(robot, q)
    nj = len(robot.joints)
    for i, j in enumerate(robot.joints):                    # link from the parent frame
        a, b = pos[j.parent + 1], pos[i + 1]
        ax.plot(*zip(a, b), color=colour, linewidth=3.0, solid_capstyle="round")
    for k, e in enumerate(robot.ends.values()):             # end frames after their joint
        a, b = pos[e.parent + 1], pos[nj + 1 + k]
        ax.plot(*zip(a, b), color=colour, linewidth=2.0)
    ax.scatter(*pos[1:nj + 1].T, color="black", s=14, depthshade=False)
    points, dirs = joint_axes(robot, q)
    if axes:
        for p, d in zip(points, dirs):
            ax.plot(*zip(p - 1.1 * length * d, p + 1.1 * length * d), color="tab:purple",
                    linewidth=1.5, linestyle="--")
    _triad(ax, poses[0], 1.2 * length)
    for k in range(len(robot.ends)):
        _triad(ax, poses[nj + 1 + k], length)
    if labels:
        for i, (p, d, j) in enumerate(zip(points, dirs, robot.joints)):   # at its axis, not its frame
            end = p + (1.2 if i % 2 == 0 else -1.2) * length * d        # alternate ends: less overlap
            ax.text(*end, j.name, fontsize=7, color="0.1")
        ax.text(*(pos[0] - 0.4 * length * np.array([0, 0, 1])), "base", fontsize=7, color="0.15")
    return pos


def _legend(fig, axes: bool = True) -> None:
    handles = [Line2D([], [], color="0.25", linewidth=3, label="links (frame origins)")]
    if axes:
        handles.append(Line2D([], [], color="tab:purple", linestyle="--", label="joint axes"))
    handles += [Line2D([], [], color=c, label=f"frame {a}") for c, a in zip(AXIS_COLOURS, "xyz")]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)


def _save(fig, out) -> None:
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=DPI, metadata={"Software": None})   # no version string: same bytes each run


def arm_figure(robot, q, out, *, deg: bool = False) -> np.ndarray:
    """Write the arm at ``q`` (rad, m) as a PNG to ``out``; returns the drawn frame origins (m, 3)
    (equal to :func:`derive.reference.joint_positions`). ``deg``: angles in the title in degrees."""
    robot = load_robot(robot)
    pos = reference.joint_positions(robot, q)                  # checks q
    q = np.asarray(q, dtype=float)
    fig = Figure(figsize=(7.0, 7.0))
    ax = fig.add_subplot(projection="3d")
    ax.view_init(elev=22, azim=-58)
    drawn = draw_arm(ax, robot, q, length=_scale(pos))
    _equal_limits(ax, drawn)
    ax.set_title(f"{robot.name} ({robot.title})\n" + _wrap(_value_text(robot, q, deg), 70), fontsize=9)
    _legend(fig)
    _save(fig, out)
    return drawn


def ik_figure(robot, q, out, *, deg: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Write every closed-form IK solution of the pose of ``q`` side by side as a PNG to ``out``.

    Returns (solutions (k, dof), drawn frame origins (k, m, 3)); an unreachable pose cannot
    occur (the pose is that of ``q``), and a robot without a closed form raises DeriveError."""
    robot = load_robot(robot)
    pose = reference.fk(robot, q)                               # checks q
    sols = reference.ik(robot, pose, q_ref=q)
    k = len(sols)
    ncols = min(4, max(k, 1))
    nrows = max(1, math.ceil(k / ncols))
    q = np.asarray(q, dtype=float)
    fig = Figure(figsize=(3.9 * ncols, 3.9 * nrows + 1.0))
    all_pos = np.array([reference.joint_positions(robot, s) for s in sols]).reshape(k, -1, 3)
    length = _scale(all_pos if k else reference.joint_positions(robot, q))
    drawn = []
    for i, s in enumerate(sols):
        ax = fig.add_subplot(nrows, ncols, i + 1, projection="3d")
        ax.view_init(elev=22, azim=-58)
        drawn.append(draw_arm(ax, robot, s, length=length, labels=False, axes=False))
        _triad(ax, pose, 1.4 * length, width=2.6)
        _equal_limits(ax, all_pos)
        ax.tick_params(labelsize=6, pad=0)
        for label in (ax.xaxis.label, ax.yaxis.label, ax.zaxis.label):
            label.set_fontsize(7)
        note = " (wrist singular)" if sols.singular[i] else ""
        ax.set_title(f"solution {i + 1}{note}\n{_vector_text(robot, s, deg)}", fontsize=8, pad=0)
    names = ", ".join(robot.variable_names)
    fig.suptitle(f"{robot.name}: the {k} closed-form IK solution(s) of the pose of "
                 f"{_vector_text(robot, q, deg)}\njoints in order: {names}; target frame drawn thick"
                 + ("" if k else f"\n{sols.reason}"), fontsize=10)
    _legend(fig, axes=False)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.06, top=1 - 0.9 / (3.9 * nrows + 1.0),
                        wspace=0.08, hspace=0.12)
    _save(fig, out)
    return np.asarray(sols).reshape(k, robot.dof), np.array(drawn).reshape(k, -1, 3)
