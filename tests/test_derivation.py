"""Symbolic derivation of M_i = N_i: structure, thesis forms, verification, emission."""

import filecmp
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import sympy as sp

import derive
from derive import DeriveError, reference
from derive import dualquat as DQ
from derive import quaternion as Q
from derive.symbolic.chain import chain_from_robot, products
from derive.symbolic.equations import (
    POSES,
    derive_equations,
    derive_set,
    verify_numeric,
)
from derive.symbolic.trig import _factor, half_angle_normal_form

#: one pytest-xdist worker runs the tests of group "ur-derivation" (make test: --dist loadgroup),
#: so the symbolic work they share (the UR family's equations, memoised in the process) is done once
pytestmark = pytest.mark.xdist_group("ur-derivation")

ROOT = Path(__file__).resolve().parent.parent
GENERATED = ROOT / "generated"
S = sp.Symbol
t1, t2, t3, t4, t5, t6 = (S(f"theta{k}", real=True) for k in range(1, 7))
d1, a2, a3, d4, d5, d6 = (S(n, real=True) for n in "d1 a2 a3 d4 d5 d6".split())
w, a, b, c, x, y, z = POSES["B"]
w4, a4, b4, c4, x4, y4, z4 = POSES["C"]
x5, y5 = POSES["W"][4:6]


@pytest.fixture(scope="module")
def ur3():
    return derive_equations("ur3")


def by_id(sets):
    return {e.id: e for s in sets for e in s.equations}


def test_ur3_dh_becomes_the_thesis_chain():
    dh = chain_from_robot("ur3")
    thesis = chain_from_robot("ur3-thesis")
    assert [(j.axis, j.link) for j in dh.joints] == [(j.axis, j.link) for j in thesis.joints]
    assert dh.joints[2].link == (a3, -d4, 0)            # thesis Q3: < a3 c3 i - d4 j + a3 s3 k >
    rot, trans = dh.end_transform
    assert [float(v) for v in rot] == pytest.approx([math.sqrt(0.5), math.sqrt(0.5), 0, 0])
    assert thesis.end_transform[0] == (1, 0, 0, 0)
    assert chain_from_robot("ur5").joints == dh.joints   # one derivation for the family


def test_set_sizes_and_ids(ur3):
    _, sets = ur3
    assert [(s.key, len(s.equations)) for s in sets] == [("B", 42), ("W", 35), ("C", 21)]
    ids = by_id(sets)
    assert ids["B.1"].product == "M6 = N6" and ids["B.1"].term == 1
    assert ids["B.13"].product == "M5 = N5" and ids["B.13"].term == 6
    assert ids["B.29"].product == "M2 = N2" and ids["B.42"].product == "M1 = N1"
    assert ids["C.1"].product == "M4 = N4" and ids["C.19"].product == "M2 = N2" and ids["C.19"].term == 5
    assert all(e.symbolic and e.numeric_error < 1e-12 for e in ids.values())


@pytest.mark.parametrize("eid, lhs, rhs", [
    # printed in the thesis and correct there: B.13 = 4.12, C.19 = 4.35, C.21 = 4.36,
    # C.12 = 4.39, C.14 = 4.40, C.1 = 4.42, W.6 = 4.9 (frame-5 coordinates)
    ("B.13", -d6 * sp.cos(t5), y * sp.cos(t1) - x * sp.sin(t1) + d4),
    ("C.19", a3 * sp.cos(t2 + t3) + a2 * sp.cos(t2), x4),
    ("C.21", a3 * sp.sin(t2 + t3) + a2 * sp.sin(t2), z4),
    ("C.12", a3 * sp.cos(t3), -a2 + x4 * sp.cos(t2) + z4 * sp.sin(t2)),
    ("C.14", a3 * sp.sin(t3), -x4 * sp.sin(t2) + z4 * sp.cos(t2)),
    ("C.1", sp.cos(t4 / 2), w4 * sp.cos((t2 + t3) / 2) - b4 * sp.sin((t2 + t3) / 2)),
    ("W.6", sp.Integer(0), y5 * sp.cos(t1) - x5 * sp.sin(t1) + d4),
    ("B.1", sp.cos(t6 / 2), w * sp.cos((t2 + t3 + t4) / 2) * sp.cos((t1 - t5) / 2)
     + a * sp.sin((t2 + t3 + t4) / 2) * sp.sin((t1 + t5) / 2)
     - b * sp.sin((t2 + t3 + t4) / 2) * sp.cos((t1 + t5) / 2)
     + c * sp.cos((t2 + t3 + t4) / 2) * sp.sin((t1 - t5) / 2)),
    ("B.29", sp.cos(t5 / 2) * sp.cos((t2 + t3 + t4 + t6) / 2), w * sp.cos(t1 / 2) + c * sp.sin(t1 / 2)),
])
def test_thesis_forms_are_reproduced_literally(ur3, eid, lhs, rhs):
    e = by_id(ur3[1])[eid]
    assert sp.expand(e.lhs - lhs) == 0
    assert sp.expand(e.rhs - rhs) == 0


def test_symbolic_check_rejects_a_wrong_side(ur3):
    chain, sets = ur3
    eset = sets[2]
    wrong = eset.equations[11]                    # C.12: a3 cos t3 = -a2 + x4 cos t2 + z4 sin t2
    thetas = [j.theta for j in chain.joints]
    assert half_angle_normal_form(wrong.rhs - eset.raw["C.12"][1], thetas) == 0
    assert half_angle_normal_form(wrong.rhs + 2 * a2 - eset.raw["C.12"][1], thetas) != 0
    assert half_angle_normal_form(sp.cos(t2 + t3) - sp.cos(t2 - t3), thetas) != 0


def test_factor_is_sympy_factor():
    """The cheap factorisation gives sympy's expression, also where it falls back to sympy."""
    c1, s1, c5, s5 = sp.cos(t1 / 2), sp.sin(t1 / 2), sp.cos(t5 / 2), sp.sin(t5 / 2)
    irreducible = c1 * c5 + s1 * s5 * d1 - a2
    cases = [
        sp.expand(-2 * (c1 * c5 - s1 * s5) * (c1 * s5 + s1 * c5) * a2),    # two factors, content -2
        sp.expand(irreducible),
        sp.expand(3 * c1 * s1**2 * (c5 + s5) ** 2),                      # squares: sympy's factor_list
        sp.expand(6 * (c1 + s1) * a2),                                   # a lone sum keeps 6 outside
        -d1, sp.Integer(0), sp.Integer(5),
        sp.expand((c1 + s1) * (c5 - s5) / 2),                            # rational: sympy
        sp.expand(sp.sqrt(2) * (c1 + s1) * (c5 - s5)),                   # algebraic: sympy
        (c1 + s1) * sp.expand((c5 - s5) * (c1 - s5)) * d1,               # a product of sums
    ]
    for e in cases:
        assert sp.srepr(_factor(e)) == sp.srepr(sp.factor(e)), e


def test_numeric_check_rejects_a_wrong_equation():
    chain = chain_from_robot("ur3")
    eset = derive_set(chain, "C", 2, 4, True)
    e = eset.equations[11]
    e.rhs_terms = [(g, -co) if g == x4 else (g, co) for g, co in e.rhs_terms]   # flip a sign
    verify_numeric(chain, eset)
    assert e.numeric_error > 1e-3
    assert all(o.numeric_error < 1e-12 for o in eset.equations if o is not e)


def test_json_parses_back_and_holds_for_the_real_ur3_fk(rng):
    # An independent use of the emitted strings: sympify them, take the pose from the
    # standard-DH FK of `ur3` times G^-1 as documented, and evaluate.
    data = json.loads((GENERATED / "ur3" / "equations.json").read_text())
    assert data["robot"] == "ur3"
    g = np.array([float(sp.sympify(v)) for v in data["end_transform"]["rotation"]])
    names = {n: S(n, real=True) for n in
             "theta1 theta2 theta3 theta4 theta5 theta6 d1 a2 a3 d4 d5 d6 w a b c x y z".split()}
    params = {names[k]: v for k, v in data["parameters"].items()}
    bset = next(s for s in data["sets"] if s["key"] == "B")
    assert len(bset["equations"]) == 42
    q = rng.uniform(-math.pi, math.pi, size=(5, 6))
    fk = reference.fk("ur3", q)
    ginv = DQ.from_rt(Q.conj(g), np.zeros(3))
    chain_pose = DQ.mul(fk, ginv)
    m1 = sp.lambdify(list(names.values())[:6], [sp.sympify(bset["equations"][-7 + k]["lhs"], locals=names)
                                                 .subs(params) for k in range(7)])
    for qi, pose in zip(q, chain_pose):
        m = np.array(m1(*qi), dtype=float)
        qv = pose[:4] if np.dot(pose[:4], m[:4]) >= 0 else -pose[:4]
        vals = {**params, **dict(zip((names[n] for n in "w a b c".split()), qv)),
                **dict(zip((names[n] for n in "x y z".split()), DQ.to_rt(pose)[1])),
                **{names[f"theta{k + 1}"]: qi[k] for k in range(6)}}
        for eq in bset["equations"]:
            lhs = float(sp.sympify(eq["lhs"], locals=names).subs(vals))
            rhs = float(sp.sympify(eq["rhs"], locals=names).subs(vals))
            assert abs(lhs - rhs) < 1e-12, eq["id"]


def test_json_records_verification():
    for robot in ("ur3", "ur5"):
        data = json.loads((GENERATED / robot / "equations.json").read_text())
        eqs = [e for s in data["sets"] for e in s["equations"]]
        assert len(eqs) == 98
        assert all(e["verified"] == {"symbolic": True, "numeric": True} for e in eqs)
        assert [s["key"] for s in data["sets"]] == ["B", "W", "C"]


def test_generated_is_byte_identical_to_a_fresh_regeneration(tmp_path, capsys):
    """`make generate` run again writes exactly the committed generated/ tree: the same files
    (appendices, IK reports, kernels, CasADi functions, manifests), byte for byte."""
    from derive.cli import main
    assert main(["generate", "--out", str(tmp_path), "--class-data", str(tmp_path.parent / "ik_classes.json"),
                 "--general6r-data", str(tmp_path.parent / "general6r.json")]) == 0
    capsys.readouterr()
    # the general arms' shipped decisions, derived again (the same arms, identities and decisions;
    # the round-off figures in their notes may differ between machines)
    fresh_g6 = json.loads((tmp_path.parent / "general6r.json").read_text())
    shipped_g6 = json.loads((ROOT / "derive" / "data" / "general6r.json").read_text())
    assert fresh_g6["format"] == shipped_g6["format"] and fresh_g6["robots"].keys() == shipped_g6["robots"].keys()
    for key, d in shipped_g6["robots"].items():
        assert {k: v for k, v in fresh_g6["robots"][key].items() if k != "notes"} == \
            {k: v for k, v in d.items() if k != "notes"}, "derive/data/general6r.json differs: run make generate"
    # the classes' symbolic IK shipped in derive/data, derived again (issue 30, fast first use)
    assert filecmp.cmp(tmp_path.parent / "ik_classes.json", ROOT / "derive" / "data" / "ik_classes.json",
                       shallow=False), "derive/data/ik_classes.json differs: run make generate"
    fresh = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(GENERATED) for p in GENERATED.rglob("*") if p.is_file())
    assert fresh == committed, "generated/ has other files than a regeneration: run make generate"
    for rel in fresh:
        assert filecmp.cmp(tmp_path / rel, GENERATED / rel, shallow=False), \
            f"generated/{rel} differs: run make generate"
    for rel in (r for r in fresh if r.name == "manifest.json"):
        data = json.loads((GENERATED / rel).read_text())
        assert data["id"] == derive.load_robot(rel.parent.name).id
        assert all((GENERATED / rel.parent / f).is_file() for f in data["files"].values())


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex not installed")
@pytest.mark.parametrize("robot", ["ur3", "irb120"])
def test_latex_appendix_compiles(tmp_path, robot):
    for name in ("appendix", "ik"):
        shutil.copy(GENERATED / robot / f"{name}.tex", tmp_path)
        res = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", f"{name}.tex"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stdout[-2000:]
        assert (tmp_path / f"{name}.pdf").stat().st_size > 10000


@pytest.mark.parametrize("robot, keys", [("kunze-2r", ["B"]), ("seed-arm", ["B"])])
def test_other_robots_derive_and_verify(robot, keys):
    chain, sets = derive_equations(robot)
    assert [s.key for s in sets] == keys
    assert all(e.symbolic and e.numeric_error < 1e-12 for s in sets for e in s.equations)


def test_seed_arm_prismatic_joint_enters_linearly():
    chain, sets = derive_equations("seed-arm")
    l1 = chain.joints[0].theta
    e = by_id(sets)[f"B.{7 * 3 + 7}"]   # M1 = N1, z term: M1 z = l1 + ...
    assert sp.diff(e.lhs, l1) == 1


def test_derivation_refuses_mimic_joints_on_the_path(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_text("name: m\nconvention: axis_angle\njoints:\n"
                 "  - {name: j1, axis: [0, 0, 1], link: [1, 0, 0]}\n"
                 "  - {name: j2, axis: [0, 0, 1], link: [1, 0, 0], mimic: {joint: j1}}\n")
    with pytest.raises(DeriveError, match="mimics"):
        chain_from_robot(p)


def test_products_compose(rng):
    # M_i = Q_i M_(i+1) evaluated numerically agrees with the reference FK of the sub-chain
    chain = chain_from_robot("ur3-thesis")
    m, _ = products(chain, 1, 6, POSES["B"])
    vals = dict(chain.parameters)
    q = rng.uniform(-3, 3, 6)
    vals.update({j.theta: q[k] for k, j in enumerate(chain.joints)})
    m1 = np.array([float(e.subs(vals)) for e in m[1].terms])
    fk = reference.fk("ur3-thesis", q)
    quat = fk[:4] if np.dot(fk[:4], m1[:4]) > 0 else -fk[:4]
    assert np.allclose(m1[:4], quat, atol=1e-14)
    assert np.allclose(m1[4:], DQ.to_rt(fk)[1], atol=1e-14)


def test_cli_appendix(tmp_path, capsys):
    from derive.cli import main
    assert main(["appendix", "kunze-2r", "--out", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "appendix.md" in out and (tmp_path / "kunze-2r" / "equations.json").exists()
