"""Figures of the reachability and placement maps (matplotlib, Agg, PNG; docs/reach.md):
three slices through the centre of the reach and a 3-D view of the reachable voxels; the
placement heat map (best yaw per position) with the best placements and the targets marked."""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure

from derive.algebra import dualquat as dq

DPI = 110


def _save(fig, out) -> None:
    fig.savefig(out, dpi=DPI, metadata={"Software": None})   # no version string: same bytes each run


def reach_figure(m, out, title: str | None = None) -> None:
    """Write a reachability map (:class:`derive.apps.reach.ReachMap`) as a PNG: the slices
    z = const, y = const, x = const through the voxel holding the bound's centre, coloured by
    the fraction of reachable orientations, and a 3-D scatter of the voxels with a fraction > 0."""
    r = np.asarray(m.reach, dtype=float)
    c = np.clip(np.floor((np.asarray(m.centre) - m.origin) / m.voxel).astype(int), 0, np.array(r.shape) - 1)
    lo = m.origin
    hi = m.origin + np.array(r.shape) * m.voxel
    fig = Figure(figsize=(12.0, 10.5), layout="constrained")
    slices = [("z", r[:, :, c[2]].T, (lo[0], hi[0], lo[1], hi[1]), "x (m)", "y (m)", m.origin[2] + (c[2] + .5) * m.voxel),
              ("y", r[:, c[1], :].T, (lo[0], hi[0], lo[2], hi[2]), "x (m)", "z (m)", m.origin[1] + (c[1] + .5) * m.voxel),
              ("x", r[c[0], :, :].T, (lo[1], hi[1], lo[2], hi[2]), "y (m)", "z (m)", m.origin[0] + (c[0] + .5) * m.voxel)]
    image = None
    for i, (axis, img, ext, xl, yl, at) in enumerate(slices):
        ax = fig.add_subplot(2, 2, i + 1)
        image = ax.imshow(np.ma.masked_invalid(img), origin="lower", extent=ext, vmin=0.0, vmax=1.0,
                          cmap="viridis", interpolation="nearest")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(f"slice {axis} = {at:.3f} m", fontsize=10)
        ax.set_aspect("equal")
    fig.colorbar(image, ax=fig.axes[:3], shrink=0.5, label="fraction of orientations reachable")
    ax = fig.add_subplot(2, 2, 4, projection="3d")
    idx = np.argwhere(np.nan_to_num(r) > 0)
    if len(idx):
        # at most 20000 points, every k-th in index order (deterministic)
        idx = idx[:: max(1, math.ceil(len(idx) / 20000))]
        # the half of the reach with y <= the centre's, so that the inside shows
        keep = idx[:, 1] <= c[1]
        idx = idx[keep]
        p = m.origin + (idx + 0.5) * m.voxel
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], c=r[tuple(idx.T)], vmin=0.0, vmax=1.0, cmap="viridis",
                   s=4, marker="s", linewidths=0, alpha=0.6)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=20, azim=-60)
    ax.set_title("reachable voxels, the half y <= centre", fontsize=10)
    a = m.attrs
    fig.suptitle(title or f"{a.get('robot', '')}: reachability, voxel {m.voxel * 100:g} cm, "
                          f"{m.orientations} orientations per voxel", fontsize=12)
    _save(fig, out)


def place_figure(p, out, best: int = 5, title: str | None = None) -> None:
    """Write a placement map (:class:`derive.apps.reach.Placement`) as a PNG: per candidate
    position the fraction of targets reachable at its best yaw, the ``best`` placements marked
    (numbered, with their yaw as an arrow) and the targets' positions as crosses."""
    val = np.nanmax(np.asarray(p.placement, dtype=float), axis=2) if np.any(np.isfinite(p.placement)) \
        else np.full(p.placement.shape[:2], np.nan)
    fig = Figure(figsize=(8.0, 7.0), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    dx = (p.xs[1] - p.xs[0]) if len(p.xs) > 1 else 1.0
    dy = (p.ys[1] - p.ys[0]) if len(p.ys) > 1 else 1.0
    ext = (p.xs[0] - dx / 2, p.xs[-1] + dx / 2, p.ys[0] - dy / 2, p.ys[-1] + dy / 2)
    image = ax.imshow(np.ma.masked_invalid(val.T), origin="lower", extent=ext, vmin=0.0, vmax=1.0,
                      cmap="magma", interpolation="nearest")
    fig.colorbar(image, ax=ax, shrink=0.8, label="fraction of targets reachable (best yaw)")
    t = dq.to_rt(np.asarray(p.targets, dtype=float))[1]
    ax.scatter(t[:, 0], t[:, 1], marker="x", c="tab:cyan", s=25, label="targets")
    arrow = 0.6 * min(abs(dx), abs(dy)) if len(p.xs) > 1 or len(p.ys) > 1 else 0.1
    for n, (x, y, _, yaw, f) in enumerate(p.best(best)):
        ax.plot([x], [y], "o", mfc="none", mec="tab:green", ms=12, mew=2)
        ax.annotate("", xy=(x + arrow * math.cos(yaw), y + arrow * math.sin(yaw)), xytext=(x, y),
                    arrowprops=dict(arrowstyle="->", color="tab:green", lw=1.5))
        ax.text(x, y, f" {n + 1}", color="white", fontsize=9, va="bottom")
    ax.plot([], [], "o", mfc="none", mec="tab:green", label="best placements (arrow: yaw)")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("base x (m)")
    ax.set_ylabel("base y (m)")
    ax.set_aspect("equal")
    a = p.attrs
    ax.set_title(title or f"{a.get('robot', '')}: base placement, {len(p.targets)} targets, z = {p.z:g} m, "
                          f"{len(p.yaws)} yaws", fontsize=11)
    _save(fig, out)
