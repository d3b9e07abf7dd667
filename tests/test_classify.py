"""Kinematic classification (derive.model.classify, `dq-derive classify`): every library robot,
the documented deviations of ur5-calibrated, a hand-built 7R SRS arm, and the CLI."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

import derive
from derive.cli import main
from derive.errors import DeriveError
from derive.ik.closed_form import ur_geometry
from derive.model.classify import EXACT_TOL, NEAR_TOL, Classification, classify

ROBOTS = Path(derive.__file__).resolve().parent / "robots"
UR = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e", "ur3-thesis")
DEG = math.pi / 180


def _write(tmp_path, name, text) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


def _ur_geometry_accepts(robot) -> bool:
    try:
        ur_geometry(robot)
    except DeriveError:
        return False
    return True


def _pair(c: Classification, i: int):
    (p,) = [p for p in c.pairs if p.i == i]
    assert p.j == i + 1
    return p


# --------------------------------------------------------------------------- #
# The library
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", UR)
def test_every_ur_robot_is_ur_with_closed_form(name):
    c = derive.classify(name)
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("UR", "UR", True, [])
    assert c.n == 6 and c.types == ("revolute",) * 6
    # the UR pattern: 1 perp 2 (meeting), 2 || 3 || 4, 4 perp 5 and 5 perp 6, both meeting
    assert [p.parallel.holds for p in c.pairs] == [False, True, True, False, False]
    assert [p.perpendicular.holds for p in c.pairs] == [True, False, False, True, True]
    assert [p.intersecting.holds for p in c.pairs] == [True, False, False, True, True]
    r = derive.load_robot(name)
    a2, a3 = (r.parameters["a2"], r.parameters["a3"])
    assert _pair(c, 2).distance == pytest.approx(abs(a2), abs=1e-12)    # upper arm
    assert _pair(c, 3).distance == pytest.approx(abs(a3), abs=1e-12)    # forearm
    assert not c.wrist.spherical and c.wrist.spread > NEAR_TOL          # d5 apart: no spherical wrist
    assert c.pieper == [((2, 3, 4), "parallel")]
    assert "derive.reference.ik" in c.notes[0]


@pytest.mark.parametrize("name", derive.list_robots())
def test_closed_form_is_what_ur_geometry_accepts_and_implies_ur(name):
    c = classify(name)
    assert c.closed_form == _ur_geometry_accepts(name)
    if c.closed_form:
        assert c.cls == "UR"


def test_irb120_is_opw_with_the_wrist_point_of_its_file():
    c = classify("irb120")
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("OPW", "OPW", False, [])
    # axes z, y, y, x, y, x through (0,0,0), (0,0,.29), (0,0,.56), (0,0,.63), (.302,0,.63), (.374,0,.63)
    assert _pair(c, 1).perpendicular.holds and _pair(c, 1).intersecting.holds
    assert _pair(c, 2).parallel.holds and _pair(c, 2).distance == pytest.approx(0.270, abs=1e-12)
    assert _pair(c, 3).perpendicular.holds and _pair(c, 3).distance == pytest.approx(0.070, abs=1e-12)
    assert c.wrist.axes == (4, 5, 6) and c.wrist.spherical
    assert c.wrist.spread < 1e-12
    np.testing.assert_allclose(c.wrist.point, (0.302, 0.0, 0.630), atol=1e-12)
    assert c.pieper == [((4, 5, 6), "meet in one point")]


def test_irb1600_is_opw_with_its_shoulder_offset():
    c = classify("irb1600")
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("OPW", "OPW", False, [])
    one = _pair(c, 1)
    assert one.perpendicular.holds and not one.intersecting.holds
    assert one.distance == pytest.approx(0.150, abs=1e-12)              # a1 of the OPW parameters
    assert _pair(c, 2).parallel.holds and _pair(c, 2).distance == pytest.approx(0.700, abs=1e-12)
    assert c.wrist.spherical
    np.testing.assert_allclose(c.wrist.point, (0.0, 0.750, 1.181), atol=1e-12)


def test_general_6r_is_general_without_near_misses():
    c = classify("general-6r")
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("general", "general", False, [])
    assert c.pieper == [] and not c.wrist.spherical and not c.wrist.concurrent.near
    # standard DH: the angle between axes i and i+1 is alpha_i folded to [0, pi/2], the common
    # normal is |a_i| (general-6r.yaml)
    alpha = [1.2, -0.4, 1.9, -1.1, 0.8]
    a = [0.10, 0.50, 0.05, 0.02, 0.03]
    for p, al, ai in zip(c.pairs, alpha, a):
        assert p.angle == pytest.approx(min(abs(al), math.pi - abs(al)), abs=1e-12)
        assert p.distance == pytest.approx(ai, abs=1e-12)
    assert any("Pieper's criterion fails" in n for n in c.notes)


def _documented_deviations() -> dict:
    """The deviations in the header of ur5-calibrated.yaml (SI: m and rad), keyed by parameter."""
    header = "\n".join(line for line in (ROBOTS / "ur5-calibrated.yaml").read_text().splitlines()
                       if line.startswith("#"))
    out = {k: float(v) * 1e-3 for k, v in re.findall(r"\b([ad]\d) ([+-][\d.]+) mm", header)}
    out.update({k: float(v) * DEG for k, v in re.findall(r"\b(alpha\d) ([+-][\d.]+) deg", header)})
    return out


def test_ur5_calibrated_near_misses_are_the_documented_deviations():
    dev = _documented_deviations()
    assert dev["alpha1"] == pytest.approx(0.2 * DEG) and dev["a4"] == pytest.approx(2.5e-3)
    c = classify("ur5-calibrated")
    assert (c.cls, c.nominal_cls, c.closed_form) == ("general", "UR", False)
    # nominal twists pi/2, 0, 0, pi/2, -pi/2: perpendicular, parallel, parallel, perpendicular,
    # perpendicular; the angle deviation of each pair is |delta alpha_i|
    kinds = ["perpendicular", "parallel", "parallel", "perpendicular", "perpendicular"]
    for i, kind in enumerate(kinds, start=1):
        prop = getattr(_pair(c, i), kind)
        assert prop.near and not prop.holds and prop.tolerance == NEAR_TOL
        assert prop.deviation == pytest.approx(abs(dev[f"alpha{i}"]), abs=1e-12)
    # the pairs that meet in the UR (1-2, 4-5, 5-6) miss by |a_i|: the documented a1, a4, a5
    for i in (1, 4, 5):
        prop = _pair(c, i).intersecting
        assert prop.near and prop.deviation == pytest.approx(abs(dev[f"a{i}"]), abs=1e-12)
    # the upper arm and forearm: the nominal a2, a3 plus the documented deviations
    nominal = derive.load_robot("ur5").parameters
    for i in (2, 3):
        assert _pair(c, i).distance == pytest.approx(abs(nominal[f"a{i}"] + dev[f"a{i}"]), abs=1e-12)
    assert len(c.near_misses) == 8
    assert (f"axes 2 and 3: parallel within {abs(dev['alpha2']):.4g} rad (not within 1e-09)"
            in c.near_misses)
    assert f"axes 4 and 5: intersecting within {abs(dev['a4']):.4g} m (not within 1e-09)" in c.near_misses
    assert any("closed form holds for the nominal arm" in n and "derive.refine" in n
               and "nominal: ur5" in n for n in c.notes)


# --------------------------------------------------------------------------- #
# Hand-built arms
# --------------------------------------------------------------------------- #
IIWA = """
name: iiwa-like
convention: standard_dh
units: {length: m, angle: rad}
joints:
  - {name: a1, d: 0.34,  a: 0, alpha: -pi/2}
  - {name: a2, d: 0,     a: 0, alpha: pi/2}
  - {name: a3, d: 0.4,   a: 0, alpha: pi/2}
  - {name: a4, d: 0,     a: 0, alpha: -pi/2}
  - {name: a5, d: 0.4,   a: A5, alpha: -pi/2}
  - {name: a6, d: 0,     a: 0, alpha: pi/2}
  - {name: a7, d: 0.126, a: 0, alpha: 0}
"""


def test_iiwa_like_7r_is_srs(tmp_path):
    c = classify(_write(tmp_path, "iiwa", IIWA.replace("A5", "0")))
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("SRS", "SRS", False, [])
    assert c.n == 7 and c.shoulder.axes == (1, 2, 3) and c.wrist.axes == (5, 6, 7)
    assert c.shoulder.spherical and c.wrist.spherical
    np.testing.assert_allclose(c.shoulder.point, (0, 0, 0.34), atol=1e-12)
    np.testing.assert_allclose(c.wrist.point, (0, 0, 0.34 + 0.4 + 0.4), atol=1e-12)
    assert all(p.perpendicular.holds and p.intersecting.holds for p in c.pairs)


def test_7r_with_an_offset_wrist_is_general_and_a_small_offset_is_a_near_miss(tmp_path):
    c = classify(_write(tmp_path, "offset", IIWA.replace("A5", "0.05")))
    assert (c.cls, c.nominal_cls) == ("general", "general")
    assert c.shoulder.spherical and not c.wrist.spherical
    c = classify(_write(tmp_path, "near", IIWA.replace("A5", "0.004")))
    assert (c.cls, c.nominal_cls) == ("general", "SRS")
    assert _pair(c, 5).intersecting.deviation == pytest.approx(0.004, abs=1e-12)
    assert c.wrist.concurrent.near and 0 < c.wrist.spread <= 0.004 + 1e-12
    assert "axes 5 and 6: intersecting within 0.004 m (not within 1e-09)" in c.near_misses


UR5_AXIS_ANGLE = """
name: ur5-variant
convention: axis_angle
units: {length: m, angle: rad}
joints:
  - {name: j1, axis: [0, 0, 1],  link: [A1, 0, 0.089159]}
  - {name: j2, axis: [0, AY, 0], link: [-0.425, 0, 0]}
  - {name: j3, axis: [0, AY, 0], link: [-0.39225, -0.10915, 0]}
  - {name: j4, axis: [0, AY, 0], link: [0, 0, -0.09465]}
  - {name: j5, axis: [0, 0, -1], link: [0, -0.0823, 0]}
  - {name: j6, axis: [0, AY, 0], link: [0, 0, 0]}
"""


@pytest.mark.parametrize("a1, ay, closed_form", [
    ("0", "-1", True),          # ur5 in thesis form
    ("0", "1", False),          # the same lines, axes 2, 3, 4, 6 reversed: not the thesis form
    ("0.05", "-1", False),      # a shoulder offset: the UR pattern, not the thesis form
])
def test_ur_pattern_outside_the_thesis_form(tmp_path, a1, ay, closed_form):
    path = _write(tmp_path, "variant", UR5_AXIS_ANGLE.replace("A1", a1).replace("AY", ay))
    c = classify(path)
    assert c.cls == "UR" and c.nominal_cls == "UR"
    assert c.closed_form == closed_form == _ur_geometry_accepts(path)
    assert _pair(c, 1).distance == pytest.approx(float(a1), abs=1e-12)
    if not closed_form:
        assert "not in the thesis form" in c.notes[0]


def test_small_shoulder_offset_is_a_near_miss_of_the_intersection(tmp_path):
    c = classify(_write(tmp_path, "a1", UR5_AXIS_ANGLE.replace("A1", "0.003").replace("AY", "-1")))
    assert (c.cls, c.closed_form) == ("UR", False)
    assert c.near_misses == ["axes 1 and 2: intersecting within 0.003 m (not within 1e-09)"]


def test_seed_arm_is_general_with_its_prismatic_joints():
    c = classify("seed-arm")
    assert (c.cls, c.nominal_cls, c.closed_form, c.near_misses) == ("general", "general", False, [])
    assert c.types == ("prismatic", "revolute", "prismatic", "revolute")
    assert "4 joints (P R P R)" in c.test
    # z, z, x, x: only directions for prismatic joints, no line, no intersection
    assert [p.parallel.holds for p in c.pairs] == [True, False, True]
    assert [p.perpendicular.holds for p in c.pairs] == [False, True, False]
    assert all(p.intersecting is None and p.distance is None for p in c.pairs)
    assert c.wrist.concurrent is None and "prismatic" in c.wrist.reason
    assert c.shoulder is None


def test_kunze_2r_two_parallel_axes():
    c = classify("kunze-2r")
    assert (c.cls, c.n, c.wrist, c.shoulder) == ("general", 2, None, None)
    (p,) = c.pairs
    assert p.parallel.holds and not p.intersecting.holds


def test_tolerances_and_angle_folding(tmp_path):
    assert (EXACT_TOL, NEAR_TOL) == (1e-9, 1e-2)
    # twist 179.5 deg: parallel within 0.5 deg (directions modulo sign)
    text = ("name: fold\nconvention: standard_dh\nunits: {length: m, angle: deg}\njoints:\n"
            "  - {name: j1, d: 0, a: 0.2, alpha: 179.5}\n  - {name: j2, d: 0, a: 0, alpha: 0}\n")
    (p,) = classify(_write(tmp_path, "fold", text)).pairs
    assert p.angle == pytest.approx(0.5 * DEG, abs=1e-12)
    assert p.parallel.near and p.parallel.tolerance == NEAR_TOL
    assert p.distance == pytest.approx(0.2, abs=1e-12)


def test_report_and_dict():
    c = classify("ur5-calibrated")
    text = c.report()
    assert "class: general" in text and "nominal class (within NEAR_TOL): UR" in text
    assert "angle (rad)" in text and "distance (m)" in text and "near 0.00524" in text
    d = json.loads(json.dumps(c.to_dict()))
    assert (d["class"], d["nominal_class"], d["closed_form"]) == ("general", "UR", False)
    assert d["pairs"][1]["parallel"]["deviation"] == pytest.approx(0.3 * DEG, abs=1e-12)
    assert d["tolerances"] == {"exact": 1e-9, "near": 1e-2}


def test_accepts_a_robot_object():
    assert classify(derive.load_robot("ur5")).cls == "UR"


# --------------------------------------------------------------------------- #
# Command line
# --------------------------------------------------------------------------- #
def test_cli_prints_the_class(capsys):
    assert main(["classify", "irb120"]) == 0
    out = capsys.readouterr().out
    assert "class: OPW" in out and "wrist (axes 4, 5, 6): spherical" in out


def test_cli_json_parses(capsys):
    assert main(["classify", "ur5", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert (d["robot"], d["class"], d["closed_form"], d["n"]) == ("ur5", "UR", True, 6)


def test_cli_unknown_robot_exits_2(capsys):
    assert main(["classify", "ur99"]) == 2
    assert "unknown robot 'ur99'" in capsys.readouterr().err
