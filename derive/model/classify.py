"""Kinematic classification of a serial arm: which consecutive axes are parallel, perpendicular
or intersecting, whether there is a spherical wrist (and, for 7R arms, a spherical shoulder),
and the class that follows (UR, OPW, spherical wrist, SRS, general).

Everything is computed on the numeric axis-angle chain of the thesis (section 4.2.1,
:func:`derive.model.geometry.numeric_chain`): axis w_i and link l_i in the base frame at the
zero configuration, axis i passing through ``start + l_1 + ... + l_(i-1)``. It needs no
symbolic algebra, so it works for every description, decimal numbers (calibrated arms)
included.

Consecutive axes i, i+1 are both fixed in link i, so their angle and their common-normal
distance do not depend on the configuration (for standard DH they are |alpha_i| folded to
[0, pi/2] and |a_i|). For a prismatic joint only the direction is meaningful (the joint has no
line), so such a pair is reported parallel / perpendicular but never intersecting.

Tolerances (radians for angles, metres for distances):

* :data:`EXACT_TOL` = 1e-9: a property *holds* when its deviation is at most this;
* :data:`NEAR_TOL` = 1e-2: a property that holds within this but not within EXACT_TOL is a
  *near miss* (a calibrated arm: millimetres and tenths of a degree), and its deviation is
  reported. The *nominal class* is the class with every property checked within NEAR_TOL.

Classes (checked in this order, every property within EXACT_TOL; 1-based axis numbers):

* ``"UR"``: 6R, axes 2, 3, 4 parallel, axis 1 perpendicular to axis 2, axes 4 and 5
  perpendicular and intersecting, axes 5 and 6 perpendicular and intersecting: three parallel
  axes and two intersecting wrist pairs, the structure of the Universal Robots solved in closed
  form in thesis section 4.3 (three consecutive parallel axes are Pieper's criterion with the
  common point at infinity).
* ``"OPW"``: 6R with an ortho-parallel base (axis 1 perpendicular to axis 2, axes 2 and 3
  parallel) and a spherical wrist 4-5-6 (Brandstoetter, Angerer, Hofbaur, "An analytical
  solution of the inverse kinematics problem of industrial serial manipulators with an
  ortho-parallel basis and a spherical wrist", 2014).
* ``"spherical wrist"``: 6R whose last three axes meet in one point but not OPW: Pieper's
  criterion (D. L. Pieper, "The kinematics of manipulators under computer control", 1968: a
  6R arm with three consecutive axes meeting in one point has a closed-form IK).
* ``"three parallel"``: 6R, not of the classes above, with axes 2, 3, 4 parallel and axes 5 and 6
  intersecting (axis 1 not parallel to axis 2, axis 5 not parallel to axis 4): the Unitree Z1,
  whose axes 4 and 5 do not meet (IK-Geo's "three parallel, two intersecting": Elias & Wen,
  arXiv:2211.05737, 2022; solved by :mod:`derive.ik.parallel3`). The UR layout has this
  structure too and stays ``"UR"``. Axes 5 and 6 not meeting (and not parallel) is of the class too
  (IK-Geo's "three parallel" with subproblem 6, :func:`derive.ik.parallel3.solve_batch_sp6`).
* ``"SRS"``: 7R with a spherical shoulder (axes 1-2-3 meet in one point) and a spherical wrist
  (axes 5-6-7), the shoulder-revolute-spherical arms such as the KUKA LBR iiwa.
* ``"general"``: anything else, any number and kind of joints.

``closed_form`` says whether dq-derive's closed-form IK (:func:`derive.ik.closed_form.ur_geometry`,
thesis section 4.3.5) applies to the robot exactly. That test lives in a higher layer; this
module repeats its criterion (:func:`thesis_ur_form`: the thesis-form axes z, -y, -y, -y, -z, -y
from the base origin and links (0, 0, d1), (a2, 0, 0), (a3, -d4, 0), (0, 0, -d5), (0, -d6, 0),
0 within 1e-12), and ``tests/test_classify.py`` checks that both agree. Every robot it accepts
is of class ``"UR"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: A property holds when its deviation is at most this (rad for angles, m for distances).
EXACT_TOL = 1e-9
#: A property that holds within this but not within EXACT_TOL is a near miss (rad / m).
NEAR_TOL = 1e-2
#: Tolerance of the thesis-form test of :func:`derive.ik.closed_form.ur_geometry` (m, unit axes).
THESIS_FORM_TOL = 1e-12

#: Axes of the UR chain in thesis form (as :data:`derive.ik.closed_form.UR_AXES`).
UR_AXES = ((0, 0, 1), (0, -1, 0), (0, -1, 0), (0, -1, 0), (0, 0, -1), (0, -1, 0))

CLASSES = ("UR", "OPW", "spherical wrist", "three parallel", "SRS", "general")

_UNIT = {"parallel": "rad", "perpendicular": "rad", "intersecting": "m", "concurrent": "m"}


@dataclass(frozen=True)
class Property:
    """One geometric property and how far the robot is from it.

    deviation: the angle (rad) to parallel / perpendicular, or the distance (m) between the
    lines (intersecting) or from the axes to their common point (concurrent)."""

    name: str
    deviation: float

    @property
    def unit(self) -> str:
        return _UNIT[self.name]

    def within(self, tol: float) -> bool:
        return self.deviation <= tol

    @property
    def holds(self) -> bool:
        """Holds within EXACT_TOL."""
        return self.within(EXACT_TOL)

    @property
    def near(self) -> bool:
        """A near miss: holds within NEAR_TOL but not within EXACT_TOL."""
        return not self.holds and self.within(NEAR_TOL)

    @property
    def tolerance(self) -> float | None:
        """The tolerance that decided it: EXACT_TOL (holds), NEAR_TOL (near miss) or None."""
        return EXACT_TOL if self.holds else NEAR_TOL if self.near else None

    @property
    def status(self) -> str:
        return "yes" if self.holds else "near" if self.near else "no"

    def to_dict(self) -> dict:
        return {"holds": self.holds, "near": self.near, "deviation": self.deviation,
                "unit": self.unit, "tolerance": self.tolerance}


@dataclass(frozen=True)
class PairReport:
    """Consecutive joint axes i and j = i + 1 (1-based).

    angle: between the directions modulo sign, in [0, pi/2] (rad). distance: length of the
    common normal, the least distance between the two lines (m; for parallel lines the distance
    between them, 0 when they coincide); None when a joint is prismatic (no line)."""

    i: int
    j: int
    types: tuple
    angle: float
    distance: float | None
    parallel: Property
    perpendicular: Property
    intersecting: Property | None

    @property
    def properties(self) -> list:
        return [p for p in (self.parallel, self.perpendicular, self.intersecting) if p is not None]

    def to_dict(self) -> dict:
        return {"axes": [self.i, self.j], "types": list(self.types), "angle": self.angle,
                "angle_deg": math.degrees(self.angle), "distance": self.distance,
                "parallel": self.parallel.to_dict(), "perpendicular": self.perpendicular.to_dict(),
                "intersecting": None if self.intersecting is None else self.intersecting.to_dict()}


@dataclass(frozen=True)
class ConcurrencyReport:
    """Do three consecutive revolute axes meet in one point (a spherical wrist or shoulder)?

    point: the least-squares point of the three lines (base frame, m); spread: the largest
    distance from it to the three axes (m), the deviation of ``concurrent``. Not applicable
    (``concurrent`` None) when one of the joints is prismatic; when the three directions are
    parallel within NEAR_TOL there is no unique common point and ``concurrent`` is None too."""

    name: str                   # "wrist" / "shoulder"
    axes: tuple                 # 1-based axis numbers
    point: tuple | None = None
    spread: float | None = None
    concurrent: Property | None = None
    reason: str = ""            # why concurrent is None

    @property
    def spherical(self) -> bool:
        return self.concurrent is not None and self.concurrent.holds

    def to_dict(self) -> dict:
        return {"name": self.name, "axes": list(self.axes),
                "point": None if self.point is None else list(self.point), "spread": self.spread,
                "spherical": self.spherical,
                "concurrent": None if self.concurrent is None else self.concurrent.to_dict(),
                "reason": self.reason}


@dataclass(frozen=True)
class Classification:
    """The kinematic class of a robot (see the module docstring for the tests and tolerances)."""

    robot: str
    n: int
    types: tuple
    pairs: list
    wrist: ConcurrencyReport | None
    shoulder: ConcurrencyReport | None
    cls: str
    test: str                   # the structure test that gave cls (within EXACT_TOL)
    nominal_cls: str
    nominal_test: str           # the same within NEAR_TOL
    near_misses: list
    closed_form: bool
    pieper: list = field(default_factory=list)     # [(axes, "parallel" | "meet in one point")]
    notes: list = field(default_factory=list)
    closed_form_through: dict | None = None       # set by derive.ik.closed_form.classify
    #: why and how the general 6R elimination solves this arm (set by
    #: derive.ik.closed_form.classify for a 6R arm of no special class), else None
    general6r: str | None = None

    def to_dict(self) -> dict:
        return {"robot": self.robot, "n": self.n, "types": list(self.types),
                "tolerances": {"exact": EXACT_TOL, "near": NEAR_TOL},
                "pairs": [p.to_dict() for p in self.pairs],
                "wrist": None if self.wrist is None else self.wrist.to_dict(),
                "shoulder": None if self.shoulder is None else self.shoulder.to_dict(),
                "class": self.cls, "test": self.test,
                "nominal_class": self.nominal_cls, "nominal_test": self.nominal_test,
                "near_misses": list(self.near_misses), "closed_form": self.closed_form,
                "pieper": [{"axes": list(a), "kind": k} for a, k in self.pieper],
                "notes": list(self.notes), "closed_form_through": self.closed_form_through,
                "general6r": self.general6r}

    def report(self) -> str:
        """The text ``dq-derive classify ROBOT`` prints."""
        lines = [(f"{self.robot}: {_joints_phrase(self.types)}; axes at the zero configuration "
                  "(numeric axis-angle chain)"),
                 (f"tolerances: holds within EXACT_TOL = {EXACT_TOL:g} (rad, m); near miss within "
                  f"NEAR_TOL = {NEAR_TOL:g} (rad, m)"), ""]
        if self.pairs:
            lines.append(f"{'axes':<6} {'types':<6} {'angle (rad)':>11} {'angle (deg)':>11} "
                         f"{'distance (m)':>12}  {'parallel':<16} {'perpendicular':<16} intersecting")
            for p in self.pairs:
                dist = "-" if p.distance is None else f"{p.distance:.6f}"
                lines.append(f"{p.i}-{p.j:<4} {' '.join(_LETTER[t] for t in p.types):<6} "
                             f"{p.angle:11.6f} {math.degrees(p.angle):11.4f} {dist:>12}  "
                             f"{_cell(p.parallel):<16} {_cell(p.perpendicular):<16} "
                             f"{_cell(p.intersecting)}")
            lines.append("(near: the deviation in rad for angles, in m for the intersection)")
        else:
            lines.append("no pair of consecutive axes")
        for c in (self.shoulder, self.wrist):
            if c is not None:
                lines.append(_concurrency_line(c))
        if self.pieper:
            lines.append("Pieper's criterion (three consecutive axes parallel or meeting in one "
                         "point): " + "; ".join(f"axes {_axes(a)} {k}" for a, k in self.pieper))
        lines += ["", f"class: {self.cls} ({self.test})",
                  f"nominal class (within NEAR_TOL): {self.nominal_cls}"
                  + ("" if self.nominal_cls == self.cls else f" ({self.nominal_test})"),
                  f"closed form in dq-derive: {'yes' if self.closed_form else 'no'}"
                  + (" (no special class: the general 6R elimination solves it, every solution)"
                     if self.general6r and not self.closed_form else "")]
        lines.append("near misses:" + ("" if self.near_misses else " none"))
        lines += [f"  - {m}" for m in self.near_misses]
        if self.notes:
            lines.append("notes:")
            lines += [f"  - {m}" for m in self.notes]
        return "\n".join(lines)


_LETTER = {"revolute": "R", "prismatic": "P"}


def _joints_phrase(types) -> str:
    n = len(types)
    return f"{n} joint{'s' if n != 1 else ''} ({' '.join(_LETTER[t] for t in types)})"


def _axes(axes) -> str:
    return ", ".join(str(a) for a in axes)


def _cell(p: Property | None) -> str:
    if p is None:
        return "-"
    return f"near {p.deviation:.3g}" if p.near else p.status


def _concurrency_line(c: ConcurrencyReport) -> str:
    head = f"{c.name} (axes {_axes(c.axes)}): "
    if c.concurrent is None:
        return head + c.reason
    verdict = ("spherical (meet in one point)" if c.concurrent.holds else
               "nearly spherical (near miss)" if c.concurrent.near else "not spherical")
    point = ", ".join(f"{v:.6f}" for v in c.point)
    return head + f"{verdict}; largest distance to the least-squares point ({point}) m: {c.spread:.3g} m"


# --------------------------------------------------------------------------- #
# Geometry
# --------------------------------------------------------------------------- #
def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _angle(u, v) -> float:
    """Angle between two directions modulo sign, in [0, pi/2] (rad), accurate near 0 and pi/2."""
    return float(math.atan2(np.linalg.norm(np.cross(u, v)), abs(float(np.dot(u, v)))))


def line_distance(p, u, q, v) -> float:
    """Least distance (m) between the lines p + s u and q + t v (u, v unit): the length of the
    common normal, or for parallel lines (angle within EXACT_TOL) the distance between them."""
    d = np.asarray(q, dtype=float) - np.asarray(p, dtype=float)
    n = np.cross(u, v)
    s = np.linalg.norm(n)
    if math.atan2(s, abs(float(np.dot(u, v)))) <= EXACT_TOL:
        return float(np.linalg.norm(d - np.dot(d, u) * u))
    return float(abs(np.dot(d, n)) / s)


def common_point(points, dirs) -> tuple:
    """Least-squares common point of lines (points p_k, unit directions u_k): it minimises the
    sum of squared distances, sum_k |(I - u_k u_k^T)(x - p_k)|^2. Returns (x (3,), the largest
    distance from x to a line (m)); x is None when the directions are all parallel within
    NEAR_TOL (no unique point)."""
    dirs = [np.asarray(u, dtype=float) for u in dirs]
    if all(_angle(dirs[0], u) <= NEAR_TOL for u in dirs[1:]):
        return None, None
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for p, u in zip(points, dirs):
        proj = np.eye(3) - np.outer(u, u)
        a += proj
        b += proj @ np.asarray(p, dtype=float)
    x = np.linalg.solve(a, b)
    spread = max(float(np.linalg.norm((np.eye(3) - np.outer(u, u)) @ (x - p)))
                 for p, u in zip(points, dirs))
    return x, spread


def thesis_ur_form(chain) -> tuple[bool, str]:
    """The criterion of :func:`derive.ik.closed_form.ur_geometry` (thesis section 4.3.5): a 6R
    chain from the base origin with the thesis-form axes z, -y, -y, -y, -z, -y and links
    (0, 0, d1), (a2, 0, 0), (a3, -d4, 0), (0, 0, -d5), (0, -d6, 0), 0, all within
    THESIS_FORM_TOL = 1e-12. Returns (accepted, why not)."""
    if chain.n != 6 or any(t != "revolute" for t in chain.types):
        return False, "not a 6R chain"
    if not np.allclose(chain.start, 0.0, atol=THESIS_FORM_TOL):
        return False, "axis 1 does not start at the base origin"
    if not all(np.allclose(a, w, atol=THESIS_FORM_TOL) for a, w in zip(chain.axes, UR_AXES)):
        return False, "the axes at the zero configuration are not z, -y, -y, -y, -z, -y"
    links = chain.links
    d1, a2, (a3, md4), md5, md6 = links[0][2], links[1][0], links[2][:2], links[3][2], links[4][1]
    shape = [(0, 0, d1), (a2, 0, 0), (a3, md4, 0), (0, 0, md5), (0, md6, 0), (0, 0, 0)]
    if not all(np.allclose(link, s, atol=THESIS_FORM_TOL) for link, s in zip(links, shape)):
        return False, ("the links are not of the form (0, 0, d1), (a2, 0, 0), (a3, -d4, 0), "
                       "(0, 0, -d5), (0, -d6, 0), 0")
    return True, ""


# --------------------------------------------------------------------------- #
# Classification
# --------------------------------------------------------------------------- #
def _pairs(chain, points) -> list:
    out = []
    for k in range(chain.n - 1):
        u, v = _unit(chain.axes[k]), _unit(chain.axes[k + 1])
        types = (chain.types[k], chain.types[k + 1])
        angle = _angle(u, v)
        distance = intersecting = None
        if types == ("revolute", "revolute"):
            distance = line_distance(points[k], u, points[k + 1], v)
            intersecting = Property("intersecting", distance)
        out.append(PairReport(i=k + 1, j=k + 2, types=types, angle=angle, distance=distance,
                              parallel=Property("parallel", angle),
                              perpendicular=Property("perpendicular", abs(math.pi / 2 - angle)),
                              intersecting=intersecting))
    return out


def _concurrency(name, chain, points, idx) -> ConcurrencyReport:
    axes = tuple(k + 1 for k in idx)
    if any(chain.types[k] != "revolute" for k in idx):
        return ConcurrencyReport(name, axes, reason="not applicable: a prismatic joint among them")
    x, spread = common_point([points[k] for k in idx], [_unit(chain.axes[k]) for k in idx])
    if x is None:
        return ConcurrencyReport(name, axes, reason="not spherical: the three axes are parallel "
                                                    "(no unique common point)")
    return ConcurrencyReport(name, axes, point=tuple(float(c) for c in x), spread=spread,
                             concurrent=Property("concurrent", spread))


def _ok(p: Property | None, tol: float) -> bool:
    return p is not None and p.within(tol)


def _class(n, types, pairs, wrist, shoulder, tol) -> tuple[str, str]:
    """(class, the structure test that gave it) with every property checked within ``tol``."""
    def par(i):      # axes i, i+1 (1-based)
        return _ok(pairs[i - 1].parallel, tol)

    def perp(i):
        return _ok(pairs[i - 1].perpendicular, tol)

    def meet(i):
        return _ok(pairs[i - 1].intersecting, tol)

    def concurrent(c):
        return c is not None and _ok(c.concurrent, tol)

    all_r = all(t == "revolute" for t in types)
    if n == 6 and all_r:
        if par(2) and par(3) and perp(1) and perp(4) and meet(4) and perp(5) and meet(5):
            return "UR", ("6R: axes 2, 3, 4 parallel; axis 1 perpendicular to axis 2; axes 4 and 5, "
                          "and axes 5 and 6, perpendicular and intersecting (thesis section 4.3)")
        if perp(1) and par(2) and concurrent(wrist):
            return "OPW", ("6R: axis 1 perpendicular to axis 2, axes 2 and 3 parallel, axes 4, 5, 6 "
                           "meet in one point (ortho-parallel base, spherical wrist)")
        if concurrent(wrist):
            return "spherical wrist", ("6R: axes 4, 5, 6 meet in one point (Pieper's criterion), "
                                       "base not ortho-parallel")
        if par(2) and par(3) and meet(5) and not par(5) and not par(1) and not par(4):
            return "three parallel", ("6R: axes 2, 3, 4 parallel, axes 5 and 6 intersecting, not "
                                      "the UR layout (IK-Geo's three parallel, two intersecting)")
        if par(2) and par(3) and not meet(5) and not par(5) and not par(1) and not par(4):
            return "three parallel", ("6R: axes 2, 3, 4 parallel, axes 5 and 6 neither intersecting "
                                      "nor parallel (IK-Geo's three parallel, with subproblem 6)")
    if n == 7 and all_r and concurrent(shoulder) and concurrent(wrist):
        return "SRS", "7R: axes 1, 2, 3 meet in one point and axes 5, 6, 7 meet in one point"
    why = ("none of the UR, OPW, spherical-wrist, three-parallel or SRS structures"
           if n in (6, 7) and all_r
           else "the UR, OPW, spherical-wrist and three-parallel classes need 6R, SRS 7R")
    return "general", f"{_joints_phrase(types)}: {why}"


def _pieper(chain, points) -> list:
    out = []
    for k in range(chain.n - 2):
        idx = (k, k + 1, k + 2)
        if any(chain.types[m] != "revolute" for m in idx):
            continue
        u = [_unit(chain.axes[m]) for m in idx]
        axes = tuple(m + 1 for m in idx)
        if _angle(u[0], u[1]) <= EXACT_TOL and _angle(u[1], u[2]) <= EXACT_TOL:
            out.append((axes, "parallel"))
            continue
        _, spread = common_point([points[m] for m in idx], u)
        if spread is not None and spread <= EXACT_TOL:
            out.append((axes, "meet in one point"))
    return out


def _near_misses(pairs, concurrency) -> list:
    out = []
    for p in pairs:
        for prop in p.properties:
            if prop.near:
                out.append(f"axes {p.i} and {p.j}: {prop.name} within {prop.deviation:.4g} "
                           f"{prop.unit} (not within {EXACT_TOL:g})")
    for c in concurrency:
        if c is not None and c.concurrent is not None and c.concurrent.near:
            out.append(f"axes {_axes(c.axes)} ({c.name}): meet in one point within "
                       f"{c.concurrent.deviation:.4g} m (not within {EXACT_TOL:g})")
    return out


def _notes(robot, chain, cls, nominal_cls, closed_form, why_not, pieper, structure: str = "") -> list:
    notes = []
    six_r = chain.n == 6 and all(t == "revolute" for t in chain.types)
    if closed_form:
        notes.append("closed form: derive.reference.ik gives every solution (thesis section "
                     "4.3.5), and the generated kernels carry it (derive.kernels(robot).ik)")
    elif cls == "UR":
        notes.append("the UR structure holds, but the chain is not in the thesis form that "
                     f"derive.ik.closed_form.ur_geometry accepts ({why_not}): derive.refine "
                     "solves its IK numerically")
    elif cls == "three parallel":
        meet56 = "neither intersecting nor parallel" not in structure
        notes.append("Pieper's criterion holds (axes 2, 3, 4 parallel)"
                     + (" and axes 5 and 6 intersect" if meet56 else
                        ", axes 5 and 6 do not meet (IK-Geo's subproblem 6)")
                     + ": the three-parallel class, solved in closed form by derive.ik.parallel3 "
                     "(derive.reference.ik) where its geometry holds within 1e-10")
    elif cls in ("OPW", "spherical wrist"):
        opw = " (the OPW solution of Brandstoetter et al. 2014)" if cls == "OPW" else ""
        notes.append("Pieper's criterion holds (axes 4, 5, 6 meet in one point), so a closed-form "
                     f"IK exists{opw}, but dq-derive implements none for this class: derive.refine "
                     "solves the IK numerically")
    elif cls == "SRS":
        notes.append("7R, redundant: the solutions of a pose form a one-parameter family (the arm "
                     "angle psi); for the SRS arms stretched at the zero pose with the elbow axis "
                     "crossing the shoulder-wrist line (the KUKA iiwa) dq-derive has the closed form "
                     "with psi given (derive.ik.srs; derive.reference.ik(robot, pose, free=psi))")
    elif nominal_cls != cls:
        pass                    # a calibrated arm: the note below says what holds
    elif six_r and pieper:
        triples = "; ".join(f"axes {_axes(a)} {k}" for a, k in pieper)
        notes.append(f"Pieper's criterion holds ({triples}), so a closed-form IK exists, but "
                     "dq-derive implements no special class for this structure: the numpy "
                     "reference (derive.reference.ik) solves a 6R arm by the general 6R elimination "
                     "(derive.ik.general6r, every solution, and its generated kernels: up to 16 solutions), "
                     "derive.refine numerically")
    elif six_r:
        notes.append("no three consecutive axes are parallel or meet in one point (Pieper's "
                     "criterion fails): no special class, up to 16 solutions; the numpy reference "
                     "(derive.reference.ik) solves a 6R arm by the general 6R elimination "
                     "(derive.ik.general6r, every solution, and its generated kernels: up to 16 solutions), "
                     "derive.refine numerically from several starts")
    elif chain.n == 7 and all(t == "revolute" for t in chain.types):
        notes.append("7R, redundant: no closed form in dq-derive for this chain unless it is of "
                     "the Franka Panda class (q7 given, derive.ik.panda), which derive.classify checks; "
                     "with any one joint given the other six are solved by their class or the general "
                     "6R elimination (derive.ik.free_joint; dq-derive ik --free-joint J --free V)")
    else:
        notes.append("no closed form in dq-derive for this chain")
    if nominal_cls == cls:
        return notes
    if nominal_cls == "UR":
        seed = (f"this file names `nominal: {robot.nominal}`, and derive.refine seeds from the "
                f"closed form of {robot.nominal}" if robot.nominal else
                "a `nominal:` key naming the library robot it deviates from lets derive.refine "
                "seed from that robot's closed form")
        notes.append("a calibrated arm: the nominal arm (every property within NEAR_TOL) is of "
                     "class UR, so the closed form holds for the nominal arm, and derive.refine "
                     f"polishes its solutions to this arm; {seed}; derive.classify says whether a "
                     "nominal robot within the tolerances of derive.ik.nearclass gives "
                     "derive.reference.ik the nominal's closed form + Newton polish")
    else:
        notes.append("a calibrated arm: the nominal arm (every property within NEAR_TOL) is of "
                     f"class {nominal_cls}; this arm has that structure only within the near "
                     "misses listed; derive.classify says whether a nominal robot within the "
                     "tolerances of derive.ik.nearclass gives derive.reference.ik the nominal's "
                     "closed form + Newton polish")
    return notes


def classify(robot) -> Classification:
    """Classify ``robot`` (a library name, a description file path or a Robot) kinematically.

    Reports every pair of consecutive axes (angle in rad, common-normal distance in m, and
    whether they are parallel, perpendicular, intersecting within EXACT_TOL = 1e-9, or only
    within NEAR_TOL = 1e-2: a near miss), the wrist (last three axes) and, for 7R arms, the
    shoulder (first three), and the class (see the module docstring). Raises DeriveError for
    a robot that cannot be loaded, or whose path to the default end has a mimic joint."""
    robot = load_robot(robot)
    chain = numeric_chain(robot)
    n = chain.n
    points = [chain.start + chain.links[:k].sum(axis=0) for k in range(n)]
    pairs = _pairs(chain, points)
    wrist = _concurrency("wrist", chain, points, (n - 3, n - 2, n - 1)) if n >= 3 else None
    shoulder = _concurrency("shoulder", chain, points, (0, 1, 2)) if n == 7 else None
    cls, test = _class(n, chain.types, pairs, wrist, shoulder, EXACT_TOL)
    nominal_cls, nominal_test = _class(n, chain.types, pairs, wrist, shoulder, NEAR_TOL)
    closed_form, why_not = thesis_ur_form(chain)
    pieper = _pieper(chain, points)
    return Classification(
        robot=robot.name, n=n, types=chain.types, pairs=pairs, wrist=wrist, shoulder=shoulder,
        cls=cls, test=test + f", within EXACT_TOL = {EXACT_TOL:g}",
        nominal_cls=nominal_cls, nominal_test=nominal_test + f", within NEAR_TOL = {NEAR_TOL:g}",
        near_misses=_near_misses(pairs, (shoulder, wrist)), closed_form=closed_form,
        pieper=pieper, notes=_notes(robot, chain, cls, nominal_cls, closed_form, why_not, pieper, test))
