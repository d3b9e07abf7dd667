"""The convention figures of the documentation, drawn by the code (matplotlib's object interface
on the Agg canvas, no pyplot and no display; PNG).

* :func:`frames_figure`: the dual-quaternion convention. Three frames {0}, {1}, {2}; each
  relative pose is "rotate by r, then translate by t", written ``Q = r + eps 1/2 t r``, and the
  poses compose like matrices, ``Q_02 = Q_01 Q_12``. The frames are placed by
  :mod:`derive.algebra.dualquat` itself, so the picture shows what the code computes.
* :func:`dh_figure`: the standard Denavit-Hartenberg parameters of one joint: frames i-1 and i
  with ``T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, and theta, d, a, alpha marked.

``python -m derive.reports.diagrams --out docs/img`` (``make figures``) writes both as
``docs/img/frames.png`` and ``docs/img/dh.png``. The output is deterministic for one
matplotlib version (no dates in the PNG metadata).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from derive.algebra import dualquat as dq

#: Colours of a frame's x, y, z axes.
AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")
#: PNG resolution (dots per inch).
DPI = 120
#: PNG metadata without the date and the matplotlib version, for reproducible files.
_METADATA = {"Software": None}

# The relative poses of the frame figure: {1} is {0} turned by 60 deg about z and moved,
# {2} is {1} turned by -90 deg about its x axis and moved along its own x axis.
_Q01 = dq.mul(dq.translation([1.0, 0.4, 0.5]), dq.rotation([0.0, 0.0, 1.0], math.radians(60)))
_Q12 = dq.mul(dq.translation([0.9, 0.0, 0.0]), dq.rotation([1.0, 0.0, 0.0], math.radians(-90)))


def _frame(ax, m: np.ndarray, label: str, length: float = 0.35, width: float = 2.2,
           sub: str = "") -> None:
    """The x, y, z axes of the 4x4 pose ``m`` as arrows named with the subscript ``sub``, with
    ``label`` at its origin."""
    o = m[:3, 3]
    for k in range(3):
        d = m[:3, k] * length
        ax.quiver(*o, *d, color=AXIS_COLOURS[k], linewidth=width, arrow_length_ratio=0.16)
        name = "xyz"[k] + ("_{" + sub + "}" if sub else "")
        ax.text(*(o + 1.2 * d), "$" + name + "$", color=AXIS_COLOURS[k], fontsize=12,
                ha="center", va="center")
    ax.text(*(o + np.array([-0.06, -0.06, -0.12])), label, fontsize=12, ha="right", va="top",
            fontweight="bold")


def _vector(ax, a, b, label: str, colour: str = "0.25") -> None:
    """A translation arrow from ``a`` to ``b`` with ``label`` at its middle."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ax.quiver(*a, *(b - a), color=colour, linewidth=1.4, linestyle="--", arrow_length_ratio=0.06)
    mid = (a + b) / 2
    ax.text(*(mid + np.array([0.0, 0.0, 0.08])), label, fontsize=11, color=colour, ha="center")


def _equal_3d(ax, points: np.ndarray, pad: float = 0.25) -> None:
    """Equal scale on the three axes around ``points``."""
    lo, hi = points.min(axis=0) - pad, points.max(axis=0) + pad
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI, metadata=_METADATA)
    return path


def frames_figure(path) -> dict:
    """Draw the dual-quaternion convention figure into the PNG ``path``; return the three 4x4
    frame poses it drew (``{"0": ..., "1": ..., "2": ...}``) as computed by
    :mod:`derive.algebra.dualquat`."""
    poses = {"0": np.eye(4), "1": dq.to_matrix(_Q01), "2": dq.to_matrix(dq.mul(_Q01, _Q12))}
    fig = Figure(figsize=(11.0, 6.0))
    ax = fig.add_axes((-0.04, -0.02, 0.62, 1.04), projection="3d")
    for name, m in poses.items():
        _frame(ax, m, "{" + name + "}", length=0.42, sub=name)
    o = {k: m[:3, 3] for k, m in poses.items()}
    _vector(ax, o["0"], o["1"], r"$t_{01}$")
    _vector(ax, o["1"], o["2"], r"$t_{12}$")
    ax.plot(*np.array([o["0"], o["2"]]).T, color="tab:purple", linewidth=1.2, linestyle=":")
    ax.text(*((o["0"] + o["2"]) / 2 + np.array([0.1, 0.0, -0.18])), r"$t_{02}$", fontsize=11,
            color="tab:purple", ha="center")
    _equal_3d(ax, np.array(list(o.values())), pad=0.3)
    ax.view_init(elev=22, azim=-75)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.tick_params(labelsize=7)

    lines = [
        (r"$\bf{A\ pose\ is\ a\ unit\ dual\ quaternion}$", 12),
        (r"$Q = p + \varepsilon\, q,\quad \varepsilon^2 = 0$", 12),
        (r"stored as the 8-vector  [p$_w$ p$_x$ p$_y$ p$_z$, q$_w$ q$_x$ q$_y$ q$_z$]", 10),
        (r"(scalar first: w, x, y, z)", 10),
        ("", 6),
        (r"$\bf{Rotate\ by\ r,\ then\ translate\ by\ t}$", 12),
        (r"$p = r, \quad q = \frac{1}{2}\, t\, r, \quad t = 2\, q\, p^{*}$", 12),
        (r"the pose of frame {1} seen from frame {0}", 10),
        ("", 6),
        (r"$\bf{Poses\ compose\ like\ 4{\times}4\ matrices}$", 12),
        (r"$Q_{02} = Q_{01}\, Q_{12}$", 12),
        (r"$Q\,(1 + \varepsilon v)\,\hat{Q}$ maps a point v of {1} into {0}", 10),
        ("", 6),
        (r"$\bf{Here}$ (radians and metres in every API):", 10),
        (r"$Q_{01}$: Rot(z, 60°), t$_{01}$ = (1, 0.4, 0.5)", 10),
        (r"$Q_{12}$: Rot(x, -90°), t$_{12}$ = (0.9, 0, 0) in {1}", 10),
        (r"x, y, z axes in red, green, blue", 10),
    ]
    y = 0.95
    for text, size in lines:
        fig.text(0.57, y, text, fontsize=size, va="top")
        y -= 0.016 + size * 0.0036
    _save(fig, path)
    return poses


def _arc(centre, u, v, radius: float, angle: float, n: int = 40) -> np.ndarray:
    """Points of the arc of ``radius`` about ``centre`` from unit direction ``u`` towards the unit
    direction ``v`` (orthogonal to ``u``) through ``angle`` radians."""
    s = np.linspace(0.0, angle, n)[:, None]
    return np.asarray(centre) + radius * (np.cos(s) * u + np.sin(s) * v)


def dh_figure(path, theta: float = math.radians(55), d: float = 0.7, a: float = 1.1,
              alpha: float = math.radians(50)) -> dict:
    """Draw the standard-DH parameters figure into the PNG ``path``: frames i-1 and i with
    ``T_i = Rz(theta) Tz(d) Tx(a) Rx(alpha)``; return the two 4x4 frames drawn
    (``{"i-1": ..., "i": ...}``), frame i computed as the dual-quaternion product."""
    Q = dq.mul(dq.mul(dq.rotation([0, 0, 1], theta), dq.translation([0, 0, d])),
               dq.mul(dq.translation([a, 0, 0]), dq.rotation([1, 0, 0], alpha)))
    m0, m1 = np.eye(4), dq.to_matrix(Q)
    o1, x1, z1 = m1[:3, 3], m1[:3, 0], m1[:3, 2]
    foot = np.array([0.0, 0.0, d])                       # where the common normal meets z_(i-1)

    fig = Figure(figsize=(11.0, 6.4))
    ax = fig.add_axes((-0.06, -0.08, 0.72, 1.16), projection="3d")
    # the joint axes: z_(i-1) is joint i's axis, z_i joint i+1's
    ax.plot([0, 0], [0, 0], [-0.35, d + 0.75], color="0.45", linewidth=1, linestyle="-.")
    ax.text(0.0, 0.0, d + 0.82, "joint i axis", fontsize=9, color="0.35", ha="center")
    e = np.array([o1 - 0.55 * z1, o1 + 0.95 * z1])
    ax.plot(e[:, 0], e[:, 1], e[:, 2], color="0.45", linewidth=1, linestyle="-.")
    ax.text(*(o1 - 0.6 * z1), "joint i+1 axis ", fontsize=9, color="0.35", ha="right",
            va="top")
    _frame(ax, m0, "{i-1}", length=0.5, sub="i-1")
    _frame(ax, m1, "{i}", length=0.6, sub="i")

    c_d, c_a, c_t, c_al = "tab:orange", "tab:purple", "tab:brown", "tab:cyan"
    # d: along z_(i-1) from the origin of {i-1} to the foot of the common normal
    off = np.array([-0.1, 0.1, 0.0])
    ax.plot(*np.array([off, foot + off]).T, color=c_d, linewidth=3)
    ax.text(*(foot * 0.62 + off * 3.0), r"$d_i$", color=c_d, fontsize=16, ha="center")
    # a: along x_i, the common normal, from the foot to the origin of {i}
    ax.plot(*np.array([foot, o1]).T, color=c_a, linewidth=3)
    ax.text(*((foot + o1) / 2 + np.array([0, 0, 0.1])), r"$a_i$", color=c_a, fontsize=15,
            ha="center")
    # theta: about z_(i-1), from x_(i-1) (moved up to the foot) to x_i
    xp = np.array([1.0, 0.0, 0.0])
    ax.plot(*np.array([foot, foot + 0.55 * xp]).T, color="tab:red", linewidth=1, linestyle=":")
    arc = _arc(foot, xp, np.array([0.0, 1.0, 0.0]), 0.42, theta)
    ax.plot(arc[:, 0], arc[:, 1], arc[:, 2], color=c_t, linewidth=2.5)
    ax.text(*(_arc(foot, xp, np.array([0.0, 1.0, 0.0]), 0.55, theta / 2)[-1]), r"$\theta_i$",
            color=c_t, fontsize=15, ha="center")
    # alpha: about x_i, from z_(i-1) (moved to the origin of {i}) to z_i
    zp = np.array([0.0, 0.0, 1.0])
    ax.plot(*np.array([o1, o1 + 0.6 * zp]).T, color="tab:blue", linewidth=1, linestyle=":")
    v = np.cross(x1, zp)
    arc = _arc(o1, zp, v, 0.45, alpha)
    ax.plot(arc[:, 0], arc[:, 1], arc[:, 2], color=c_al, linewidth=2.5)
    ax.text(*(_arc(o1, zp, v, 0.62, alpha / 2)[-1]), r"$\alpha_i$", color=c_al, fontsize=16,
            ha="center")

    _equal_3d(ax, np.array([m0[:3, 3], o1, foot, o1 + 0.8 * z1]), pad=0.2)
    ax.view_init(elev=16, azim=-68)
    ax.set_axis_off()

    lines = [
        (r"$\bf{Standard\ DH:\ frame\ i\ from\ frame\ i{-}1}$", 12),
        (r"$T_i = R_z(\theta_i)\ T_z(d_i)\ T_x(a_i)\ R_x(\alpha_i)$", 13),
        ("", 6),
        (r"$\theta_i$: angle from $x_{i-1}$ to $x_i$ about $z_{i-1}$", 11),
        (r"       (the joint variable of a revolute joint)", 9),
        (r"$d_i$: distance along $z_{i-1}$ to the common normal", 11),
        (r"$a_i$: length of the common normal, along $x_i$", 11),
        (r"$\alpha_i$: angle from $z_{i-1}$ to $z_i$ about $x_i$", 11),
        ("", 6),
        (r"$z_{i-1}$ is the axis of joint i; $x_i$ is the common", 10),
        (r"normal of $z_{i-1}$ and $z_i$. Modified (Craig) DH,", 10),
        (r"$R_x(\alpha_{i-1})\,T_x(a_{i-1})\,R_z(\theta_i)\,T_z(d_i)$,", 10),
        (r"is the convention modified_dh.", 10),
        ("", 6),
        (r"Dual quaternion (Kunze eq. 5.7):", 10),
        (r"$Q_{DH} = Q_\theta\, Q_d\, Q_a\, Q_\alpha$", 12),
        (r"Drawn: $\theta$ = 55°, d = 0.7, a = 1.1, $\alpha$ = 50°", 10),
    ]
    y = 0.95
    for text, size in lines:
        fig.text(0.62, y, text, fontsize=size, va="top")
        y -= 0.014 + size * 0.0034
    _save(fig, path)
    return {"i-1": m0, "i": m1}


def write_all(out) -> list[Path]:
    """Write ``frames.png`` and ``dh.png`` into the folder ``out``; return their paths."""
    out = Path(out)
    frames_figure(out / "frames.png")
    dh_figure(out / "dh.png")
    return [out / "frames.png", out / "dh.png"]


def main(argv=None) -> int:
    """``python -m derive.reports.diagrams [--out DIR]``: write the convention figures."""
    parser = argparse.ArgumentParser(prog="python -m derive.reports.diagrams",
                                     description="Write the convention figures (frames.png, dh.png).")
    parser.add_argument("--out", default="docs/img", help="folder for the PNG files (default: docs/img)")
    args = parser.parse_args(argv)
    for p in write_all(args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
