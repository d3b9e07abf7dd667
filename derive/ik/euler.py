"""The one ZYZ Euler decomposition of the IK layer, with a free angle at its singularity: the
wrists of the spherical-wrist class (:mod:`derive.ik.spherical`), the shoulders and wrists of
the SRS class (:mod:`derive.ik.srs`) and the shoulder of the Panda class (:mod:`derive.ik.panda`)
in numpy (:func:`zyz`), and the same steps as IK-program statements for the 7R programs
(:func:`zyz_plus`, :func:`zyz_signed`, used by :mod:`derive.ik.program7`).

m = Rz(a) Ry(b) Rz(c) (Shimizu et al. 2008, sec. III; Faria et al. 2018, GC2 / GC6; Brandstoetter
et al. 2014, sec. 3 for the wrist):

* |sin b| = hypot(m02, m12); b = atan2(sign |sin b|, m22) for the branch sign(sin b) = ``sign``;
* a = atan2(sign m12, sign m02);
* c from Rz(c) = Ry(b)^T Rz(a)^T m, column 0: c = atan2(ca m10 - sa m00,
  cb (ca m00 + sa m10) - sb m20) (equal to atan2(sign m21, -sign m20), but consistent with the
  rounded a and b, which keeps the product exact near sin b = 0);
* below :data:`derive.ik.tolerances.WRIST_SINGULAR` (|sin b|) only a + c (b = 0) or a - c
  (b = pi) is fixed: a is the given free value and c takes the rest; the result is flagged.

The module imports numpy only; the program helpers import sympy when called.
"""

from __future__ import annotations

import numpy as np

from derive.ik.tolerances import WRIST_SINGULAR


def zyz_matrix(a, b, c):
    """Rz(a) Ry(b) Rz(c), written out (batches of angles of one shape)."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    m = np.empty(np.shape(a) + (3, 3))
    m[..., 0, 0] = ca * cb * cc - sa * sc
    m[..., 0, 1] = -ca * cb * sc - sa * cc
    m[..., 0, 2] = ca * sb
    m[..., 1, 0] = sa * cb * cc + ca * sc
    m[..., 1, 1] = -sa * cb * sc + ca * cc
    m[..., 1, 2] = sa * sb
    m[..., 2, 0] = -sb * cc
    m[..., 2, 1] = sb * sc
    m[..., 2, 2] = cb
    return m


def zyz(m, sign, free, tol: float = WRIST_SINGULAR):
    """ZYZ angles (a, b, c) of rotations m (..., 3, 3) for the branch sign(sin b) = ``sign``
    (+-1, broadcast), and the singular flag (module docstring); ``free``: the first angle a
    where |sin b| < ``tol`` (broadcast). Returns a, b, c, singular, all of the broadcast shape."""
    sb = np.hypot(m[..., 0, 2], m[..., 1, 2])
    sing = sb < tol
    b = np.where(sing, np.where(m[..., 2, 2] >= 0, 0.0, np.pi), np.arctan2(sign * sb, m[..., 2, 2]))
    a = np.where(sing, free, np.arctan2(sign * m[..., 1, 2], sign * m[..., 0, 2]))
    ca, sa = np.cos(a), np.sin(a)
    # rows 1 and 0 of Ry(b)^T Rz(a)^T, applied to column 0 of m
    c = np.arctan2(ca * m[..., 1, 0] - sa * m[..., 0, 0],
                   np.cos(b) * (ca * m[..., 0, 0] + sa * m[..., 1, 0]) - np.sin(b) * m[..., 2, 0])
    return a, b, c, np.broadcast_to(sing, np.shape(c))


# --------------------------------------------------------------------------- #
# The same decomposition as IK-program statements (derive.ik.ir.Builder)
# --------------------------------------------------------------------------- #
def zyz_plus(bld, m, stem: str, flag: str, trig: bool):
    """Before the sign branch: the decomposition m = Rz(a) Ry(b) Rz(c) with sin b >= 0
    (:func:`zyz` with sign +1): |sin b| = hypot(m02, m12), the flag ``flag``
    (below WRIST_SINGULAR: a is free and set to 0), a = atan2(m12, m02), b = atan2(|sin b|, m22),
    c from Ry(b)^T Rz(a)^T m; with ``trig`` also the cosines and sines (ca, sa, cb, sb, cc, sc)
    for a later product. Returns (a, b, c, the offset of a and c on the - branch (pi, or 0 on the
    singular set), trig)."""
    import sympy as sp

    from derive.ik.ir import sgn
    hs = bld.let(f"{stem}_hs", sp.sqrt(m[0][2] ** 2 + m[1][2] ** 2))
    sing = bld.flag(flag, hs < WRIST_SINGULAR)
    a = bld.select(f"{stem}_a", sing, 0, sp.atan2(m[1][2], m[0][2]))
    b_sing = bld.select(f"{stem}_bs", m[2][2] >= 0, 0, sp.pi)
    b = bld.select(f"{stem}_b", sing, b_sing, sp.atan2(hs, m[2][2]))
    cb = bld.select(f"{stem}_cb", sing, sgn(m[2][2]), m[2][2])
    off = bld.select(f"{stem}_off", sing, 0, sp.pi)
    if not trig:
        # Rz(c) = Ry(b)^T Rz(a)^T m, column 0 (cos c, sin c, 0), with cos a = m02 / hs, sin a =
        # m12 / hs, sin b = hs, all times hs > 0 (atan2 does not see the scale): no division
        ny = bld.select(f"{stem}_ny", sing, m[1][0], m[0][2] * m[1][0] - m[1][2] * m[0][0])
        nx = bld.select(f"{stem}_nx", sing, cb * m[0][0],
                        m[2][2] * (m[0][2] * m[0][0] + m[1][2] * m[1][0]) - hs * hs * m[2][0])
        return a, b, bld.let(f"{stem}_c", sp.atan2(ny, nx)), off, None
    safe = bld.select(f"{stem}_hd", sing, 1, hs)
    ca = bld.select(f"{stem}_ca", sing, 1, m[0][2] / safe)
    sa = bld.select(f"{stem}_sa", sing, 0, m[1][2] / safe)
    sb = bld.select(f"{stem}_sb", sing, 0, hs)
    # Rz(c) = Ry(b)^T Rz(a)^T m, column 0: (cos c, sin c, 0)
    ny = bld.let(f"{stem}_ny", -sa * m[0][0] + ca * m[1][0])
    nx = bld.let(f"{stem}_nx", cb * (ca * m[0][0] + sa * m[1][0]) - sb * m[2][0])
    c = bld.let(f"{stem}_c", sp.atan2(ny, nx))
    nn = bld.let(f"{stem}_nn", sp.sqrt(nx * nx + ny * ny))
    return a, b, c, off, (ca, sa, cb, sb, bld.let(f"{stem}_cc", nx / nn), bld.let(f"{stem}_sc", ny / nn))


def zyz_signed(bld, plus, sign, names: tuple):
    """After the sign branch (sign = +-1, the sign of sin b): the decomposition of that sign,
    (a + pi, -b, c + pi) for - (the same rotation: Rz(a + pi) Ry(-b) Rz(c + pi) = Rz(a) Ry(b)
    Rz(c), with cosines and sines negated exactly), so the atan2 are taken once; on the singular
    set a stays 0 and both signs give the same solution (merged)."""
    a, b, c, off, _ = plus
    na, nb, nc = names
    half = (1 - sign) / 2                       # 0 on the + branch, 1 on the -
    return bld.let(na, a + half * off), bld.let(nb, sign * b), bld.let(nc, c + half * off)
