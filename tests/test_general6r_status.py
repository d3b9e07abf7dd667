"""What `dq-derive robots` and `classify` say of a six-revolute arm of no special class comes from
the same decision as its kernels: the general 6R derivation's genericity check
(derive.ik.general6r.plan: _check_generic in both directions, then _check_cut), read from the
cache without deriving (derive.ik.general6r.status). An arm whose elimination degenerates in
every direction and cut (a 6R with two coincident axes, secretly a five-degree-of-freedom chain)
gets FK-only kernels and the tables say so; the library's general arms get IK kernels and the
tables say FK+IK."""

import numpy as np
import pytest
import yaml

import derive
from derive import cli, reference
from derive.cache import clear_memory
from derive.codegen import emit
from derive.errors import DeriveError
from derive.ik import general6r

#: joints 2 and 3 turn about the same line (axis y through the same point): their two angles
#: only ever act as their sum, so the chain has five degrees of freedom; no other pair of axes is
#: parallel or meets, so no special class applies
COINCIDENT = {
    "name": "coincident-6r", "convention": "urdf",
    "joints": [
        {"name": "j1", "origin": {"translation": [0.0, 0.0, 0.3]}, "axis": [0, 0, 1]},
        {"name": "j2", "origin": {"translation": [0.05, 0.1, 0.2]}, "axis": [0, 1, 0]},
        {"name": "j3", "origin": {"translation": [0.0, 0.12, 0.0]}, "axis": [0, 1, 0]},
        {"name": "j4", "origin": {"translation": [0.3, 0.07, 0.25]}, "axis": [1, 0, 0]},
        {"name": "j5", "origin": {"translation": [0.2, -0.04, 0.1]}, "axis": [0, 0, 1]},
        {"name": "j6", "origin": {"translation": [0.1, 0.06, -0.05]}, "axis": [0, 1, 0]},
    ],
    "tool": {"translation": [0.05, 0.0, 0.1]},
}


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty user cache and no plans in memory: what a new machine sees."""
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(tmp_path / "cache"))
    clear_memory()
    yield tmp_path
    clear_memory()


def test_coincident_axes_arm_degenerates_and_every_table_says_so(fresh_cache):
    path = fresh_cache / "coincident-6r.yaml"
    path.write_text(yaml.safe_dump(COINCIDENT))
    robot = derive.load_robot(str(path))
    # the construction: the geometric Jacobian (6 x 6, plain 4x4 matrices) has rank 5 everywhere
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (6, 6))
    for qq in q:
        h = 1e-6
        cols = []
        for k in range(6):
            d = np.zeros(6)
            d[k] = h
            a, b = reference.fk_matrix(robot, qq + d), reference.fk_matrix(robot, qq - d)
            w = (a[:3, :3] - b[:3, :3]) @ reference.fk_matrix(robot, qq)[:3, :3].T / (2 * h)
            cols.append(np.concatenate([(a[:3, 3] - b[:3, 3]) / (2 * h), [w[2, 1], w[0, 2], w[1, 0]]]))
        sv = np.linalg.svd(np.array(cols).T, compute_uv=False)
        assert sv[4] > 1e-3 * sv[0] and sv[5] < 1e-7 * sv[0]
    assert derive.classify(robot).cls == "general"

    # before the derivation: nothing is claimed beyond what is known
    assert general6r.status(robot) == "unchecked"
    row = cli._robot_row(str(path))
    assert row["kernels"].startswith("FK+IK (elimination unchecked)")
    assert "not checked yet" in general6r.describe(robot)

    # the derivation: degenerate in both directions and at both cuts
    with pytest.raises(DeriveError) as info:
        general6r.plan(robot, progress=False)
    text = str(info.value)
    for part in ("forward chain", "reversed chain", "cut at joint 2", "cut at joint 1"):
        assert part in text
    assert emit._general_ik_context(robot) is None                # the kernels' decision: no IK
    with pytest.raises(DeriveError):
        reference.ik(robot, reference.fk(robot, q[0]))           # nor the numpy reference

    # in this process and in a fresh one (the stored decision), every table agrees
    for forget in (False, True):
        if forget:
            clear_memory()
        assert general6r.status(robot) == "degenerate"
        row = cli._robot_row(str(path))
        assert row["kernels"].startswith("FK, ") and row["ik"].startswith("no: refine")
        assert ", ik" not in row["casadi"]
        c = derive.classify(robot)
        assert not c.closed_form and c.general6r is None
        assert "closed form in dq-derive: no\n" in c.report() + "\n"
        assert not any("solves it" in n or "derive.ik.general6r, every solution" in n for n in c.notes)
        assert any("does not solve it" in n and "refine" in n for n in c.notes)
        with pytest.raises(DeriveError, match="degenerates in both directions"):
            general6r.plan(robot, progress=False)
    assert not derive.kernels(robot, "numpy").has_ik               # the emitted kernels: FK only


@pytest.mark.parametrize("name", ["crx10ia", "xarm6", "jaco2-6dof", "general-6r"])
def test_library_general_arms_label_is_the_kernels_decision(name):
    robot = derive.load_robot(name)
    pl = general6r.plan(robot, progress=False)                     # derived (or cached) here
    assert general6r.status(robot) == "kernels"
    clear_memory(["general6r-plan"])                               # as a fresh process: the artifact
    assert general6r.status(robot) == "kernels"
    row = cli._robot_row(name)
    assert row["ik"] == "general 6R elimination"
    assert row["kernels"].startswith("FK+IK, ") and "unchecked" not in row["kernels"]
    # the same decision as the kernels': their IK context exists, with the plan's formulation
    ctx = emit._general_ik_context(robot)
    assert ctx is not None and ctx["ik"]["general"]["max_solutions"] == 16
    assert (ctx["ik"]["general"]["mode"]["kind"] == "cut") == bool(pl.cut)
    c = derive.classify(robot)
    assert c.general6r and "not checked yet" not in c.general6r
    assert ("loop is cut at joint" in c.general6r) == bool(pl.cut)


# --------------------------------------------------------------------------- #
# The decisions shipped for the library's general arms (derive/data/general6r.json)
# --------------------------------------------------------------------------- #
LIBRARY_GENERAL = {"crx10ia": 2, "xarm6": None, "jaco2-6dof": 2, "general-6r": None}   # the cut joint


def _masked(decision: dict) -> dict:
    """A decision with the floating-point figures of its notes (singular values, round-off of
    the genericity check) replaced, so two machines' derivations compare equal."""
    import re
    return {**decision, "notes": [re.sub(r"\d\.\de[-+]\d+", "#", n) for n in decision.get("notes", [])]}


def test_shipped_decisions_are_the_derivations():
    """The shipped file holds exactly the library's general arms, each under its identity, with
    the decision the derivation makes now (derived or read from this code's cache)."""
    shipped = general6r.shipped_decisions()
    assert sorted(d["robot"] for d in shipped.values()) == sorted(LIBRARY_GENERAL)
    for key, d in shipped.items():
        robot = derive.load_robot(d["robot"])
        assert key == robot.id
        fresh = general6r.decision(robot)
        assert _masked(fresh) == _masked(d), d["robot"]
        assert d["rank_q"] == 8 and d["cut"] == LIBRARY_GENERAL[d["robot"]]
    # the xArm6's forward pencil is singular for every q3 (docs/ik.md): solved as the reversed chain
    assert shipped[derive.load_robot("xarm6").id]["reverse"] is True


def test_fresh_install_labels_the_library_arms_without_deriving(fresh_cache, monkeypatch):
    """An empty user cache (a fresh install, or any change of the code, which changes the cache
    folder): `robots` and `classify` give every library arm its derivation's label from the
    shipped decision, and nothing is derived or stored to do so."""
    def no_derivation(*args, **kwargs):
        raise AssertionError("derived while labelling")
    monkeypatch.setattr(general6r, "_plan", no_derivation)
    monkeypatch.setattr(general6r, "derive_elimination", no_derivation)
    rows = {name: cli._robot_row(name) for name in cli.list_robots()}
    assert not any("unchecked" in row["kernels"] for row in rows.values())
    for name, cut in LIBRARY_GENERAL.items():
        assert general6r.status(name) == "kernels"
        assert rows[name]["ik"] == "general 6R elimination"
        assert rows[name]["kernels"].startswith("FK+IK, ")
        c = derive.classify(name)
        assert c.general6r and "not checked yet" not in c.general6r
        assert ("loop is cut at joint 2" in c.general6r) == (cut == 2)
    assert "solved as the reversed chain" in derive.classify("xarm6").general6r
    assert not (fresh_cache / "cache").exists() or not any((fresh_cache / "cache").rglob("general6r.json"))


def test_a_changed_copy_of_a_library_arm_is_unchecked(fresh_cache):
    """The shipped decision is keyed by the robot's identity (its kinematics), not its name: a
    copy of crx10ia.yaml under another name is the CRX (the decision applies), a copy with one
    length changed by 1 mm is another arm, unchecked until it is derived."""
    from importlib import resources
    text = (resources.files("derive.robots") / "crx10ia.yaml").read_text()
    same = fresh_cache / "my-crx.yaml"
    same.write_text(text.replace("name: crx10ia", "name: my-crx"))
    assert derive.load_robot(str(same)).id == derive.load_robot("crx10ia").id
    assert general6r.status(str(same)) == "kernels"
    assert cli._robot_row(str(same))["kernels"].startswith("FK+IK, ")

    changed = fresh_cache / "my-crx-changed.yaml"
    assert "l_5: 0.150," in text
    changed.write_text(text.replace("l_5: 0.150,", "l_5: 0.151,").replace("name: crx10ia", "name: my-crx-changed"))
    robot = derive.load_robot(str(changed))
    assert robot.id != derive.load_robot("crx10ia").id and derive.classify(robot).cls == "general"
    assert general6r.status(robot) == "unchecked"
    assert cli._robot_row(str(changed))["kernels"].startswith("FK+IK (elimination unchecked)")
