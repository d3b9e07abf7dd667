"""The C kernels of a seven-joint arm with a joint given on the general route (issue 31, item 4):
``derive.kernels(robot, "c", free="qK")`` (templates/free_joint.c.j2, derive.codegen.free_joint)
against the numpy reference :func:`derive.ik.free_joint.solve`, the plain 4x4-matrix FK
(``reference.fk_matrix``) and the generating configuration. The SRS class routes (the class's
IK program in C): tests/test_free_joint_srs_c.py."""

import math
import re
import shutil
import subprocess

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

import derive
from derive import reference
from derive.codegen import free_joint as cfree
from derive.codegen.loader import _compile
from derive.ik import free_joint
from conftest import assert_compiles_strict

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _wrapped(d):
    return np.abs((np.asarray(d) + math.pi) % (2 * math.pi) - math.pi)


def _inside(robot, n, rng):
    lim = np.where(np.isfinite(robot.limits), robot.limits, np.array([-math.pi, math.pi]))
    return rng.uniform(np.maximum(lim[:, 0], -math.pi), np.minimum(lim[:, 1], math.pi), (n, 7))


def _same_set(a, b, tol=1e-6):
    """Every row of a within tol (every joint, modulo 2 pi) of a row of b, and back."""
    if len(a) != len(b):
        return False
    if not len(a):
        return True
    d = _wrapped(a[:, None] - b[None]).max(-1)
    return bool(np.all(d.min(1) < tol) and np.all(d.min(0) < tol))


@pytest.mark.parametrize("name,k", [("xarm7", 2), ("xarm7", 4), ("gen3", 2), ("gen3", 3)])
def test_c_free_joint_matches_the_reference(name, k):
    """100 configurations inside the limits, joint k held at its generating value and at two
    other values in its range: the C kernel's solution sets equal free_joint.solve's (counts
    and every solution within 1e-6 rad) and so do the singular flags of matching solutions
    (the C skips its own test where Newton's bound cleared a solution); every C solution
    reproduces the pose within 1e-10 by the plain matrix FK and holds joint k; the generating
    configuration is among them at its value; nothing but the padding is NaN. (gen3 q3: the C
    kernel's plan is another cut than the reference's, derive.codegen.free_joint._fewest_suspects.)"""
    robot = derive.load_robot(name)
    assert free_joint.route(robot, k) == "general"
    rng = np.random.default_rng(31 + k)
    q = _inside(robot, 100, rng)
    lo, hi = free_joint.joint_range(robot, k)
    values = np.stack([q[:, k - 1], rng.uniform(lo, hi, 100), rng.uniform(lo, hi, 100)], 1)   # (100, 3)
    poses = np.repeat(reference.fk(robot, q), 3, axis=0)
    target = np.repeat(reference.fk_matrix(robot, q), 3, axis=0)
    v = values.reshape(-1)
    cq, cc, cs, _ = cfree.c_library(robot, k, _compile).solve(poses, v)
    ref = free_joint.solve(robot, poses, k, v)
    np.testing.assert_array_equal(cc, ref.counts)
    assert cc.sum() > 300 and cc.max() <= 16
    for i in range(len(v)):
        assert _same_set(cq[i, :cc[i]], ref.q[i, :ref.counts[i]]), i
        if cc[i]:
            match = _wrapped(cq[i, :cc[i], None] - ref.q[i, None, :cc[i]]).max(-1).argmin(1)
            np.testing.assert_array_equal(cs[i, :cc[i]], ref.singular[i, match], err_msg=str(i))
    valid = np.arange(16)[None] < cc[:, None]
    assert not np.isnan(cq[valid]).any() and np.isnan(cq[~valid]).all()
    rows = np.nonzero(valid)[0]
    assert np.abs(reference.fk_matrix(robot, cq[valid]) - target[rows]).max() < 1e-10
    np.testing.assert_array_equal(cq[valid][:, k - 1], v[rows])
    gen = np.nanmin(np.where(valid, _wrapped(cq - np.repeat(q, 3, axis=0)[:, None]).max(-1), np.inf), axis=1)
    assert np.all(gen[::3] < 1e-6)


@pytest.mark.parametrize("name,k", [("xarm7", 4), ("gen3", 2)])
def test_triple_side_harmonics_equal_the_per_value_fit(name, k):
    """The triple side baked as a trigonometric polynomial of degree 3 in the held value equals
    the reference's fit from 27 sample angles per value (free_joint._coefs) at random values and
    poses, for the plan and its rescue."""
    robot = derive.load_robot(name)
    pl = free_joint.plan(robot, k)
    rng = np.random.default_rng(8)
    q = _inside(robot, 6, rng)
    target = free_joint.g6._to_matrix(reference.fk(robot, q))
    target[:, :3, 3] /= pl.scale
    for p in (pl, pl.alt):
        h = cfree.triple_harmonics(p)
        d = free_joint.locked_chain(p.c, k, q[:, k - 1])
        t = target
        if p.reverse:
            d = np.stack([free_joint.g6._reverse(x) for x in d])
            t = np.linalg.inv(target)
        y, _ = free_joint._coefs(d, p.e, t)
        np.testing.assert_allclose((cfree._harmonics(q[:, k - 1]) @ h).reshape(6, 14, 27), y, atol=1e-12)


@pytest.mark.parametrize("name,k,keep", [("xarm7", 2, 16), ("xarm7", 7, 16), ("gen3", 6, 16), ("xarm7", 6, 16),
                                         ("panda", 6, 14)])
def test_baked_deflation_holds_at_random_values_and_poses(name, k, keep):
    """Where the C plan bakes the deflation (the held link off the cut's triple side,
    cfree.c_plans; gen3 q6, xarm7 q6 and panda q6 by the span of the shared eigenvectors and
    generalised eigenvectors, cfree._span_deflation), the removed subspace V is invariant under
    every pose's companion matrix at values other than those it was checked at: |W^T C V| (the
    block the C kernel drops) is zero to rounding on the pencils built by the reference's
    per-value fit (free_joint._coefs), and the eigenvalues it removes are the same at every pose
    and value (compared by the block's characteristic polynomial: some are multiple) and none is
    real."""
    robot = derive.load_robot(name)
    pl = cfree.c_plans(robot, k)[0]
    found = cfree._pair_deflation(pl)
    assert found is not None and found[1] == keep
    bases, keep = np.asarray(found[0]), found[1]
    rng = np.random.default_rng(21)
    q = _inside(robot, 8, rng)
    for o, comp in enumerate(_pencil_companions(robot, pl, q)):
        t = np.swapaxes(bases[o], 0, 1) @ comp @ bases[o]
        leak = np.abs(t[:, :keep, keep:]).max(axis=(1, 2)) / np.maximum(1.0, np.abs(comp).max(axis=(1, 2)))
        assert leak.max() < 1e-9, (o, leak)
        # the removed block's eigenvalues: the same at every pose and value, none real (no
        # solution is removed; these arms have no spurious real root)
        assert not found[2]
        block = t[:, keep:, keep:]
        poly = np.array([np.poly(b) for b in block]).real
        assert np.abs(poly[1:] - poly[0]).max() < 1e-6 * (1 + np.abs(poly[0]).max())
        lam = np.linalg.eigvals(block)
        assert np.all(np.abs(lam.imag) > 1e-2 * (1 + np.abs(lam) ** 2))


@needs_gcc
@pytest.mark.parametrize("k", [5, 2, 3])
def test_c_free_joint_source_compiles_as_c99_and_cxx17(tmp_path, k):
    """The emitted source (two copies of the general 6R solver core, the plan and its rescue;
    with q2 given the plan's deflation baked, the rescue's not; with q3 the plan's deflation per
    value, its basis a trigonometric polynomial in the value), warnings as errors, -Wpedantic,
    as C99 and C++17."""
    src = tmp_path / f"xarm7_q{k}.c"
    src.write_text(cfree.c_source("xarm7", k))
    assert_compiles_strict(src)


@needs_gcc
@pytest.mark.parametrize("k", [1, 7])
def test_c_free_joint_source_of_the_end_joints_compiles_unoptimised_without_warnings(tmp_path, k):
    """With joint 1 or 7 given no link comes before or after the held one: the source compiles
    at -O0 (where gcc's -Wall looks at code that optimisation would drop) with warnings as errors
    (with joint 1, fj_locked's loop over the links before it made gcc -O0 warn of a write before
    its array)."""
    src = tmp_path / f"xarm7_q{k}.c"
    src.write_text(cfree.c_source("xarm7", k))
    res = subprocess.run(["gcc", "-std=c99", "-O0", "-Wall", "-Wextra", "-Werror", "-c", "-o", "/dev/null", str(src)],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]


def test_c_free_joint_kernels_api():
    """derive.kernels("xarm7", "c", free="q4"): ik of one pose and a batch (details, within
    limits), ik_sweep and nearest through the C kernel agree with the numpy kernels."""
    robot = derive.load_robot("xarm7")
    kc = derive.kernels("xarm7", "c", free="q4")
    kn = derive.kernels("xarm7", "numpy", free="q4")
    assert kc.route == "general" and kc.free == "q4"
    q = _inside(robot, 6, np.random.default_rng(12))
    poses = kn.fk(q)
    np.testing.assert_allclose(kc.fk(q), poses, atol=1e-12)
    s1, c1 = kc.ik(poses[0], free=q[0, 3])
    assert s1.shape == (16, 7) and c1 >= 1 and _wrapped(s1[:c1] - q[0]).max(-1).min() < 1e-6
    sols, counts, branch, sing = kc.ik(poses, free=q[:, 3], details=True)
    ns, nc = kn.ik(poses, free=q[:, 3])
    np.testing.assert_array_equal(counts, nc)
    assert all(_same_set(sols[i, :counts[i]], ns[i, :nc[i]]) for i in range(6))
    assert np.all(branch == -1) and sing.dtype == bool
    assert not kc.ik_degenerate(poses, free=q[:, 3]).any()
    wl, wc = kc.ik(poses, free=q[:, 3], within_limits=True)
    ok = np.arange(wl.shape[1])[None] < wc[:, None]
    assert np.all((wl[ok] >= robot.limits[:, 0] - 1e-9) & (wl[ok] <= robot.limits[:, 1] + 1e-9))
    sw_c, sw_n = kc.ik_sweep(poses[:2], 5), kn.ik_sweep(poses[:2], 5)
    np.testing.assert_allclose(sw_c.free, sw_n.free)
    np.testing.assert_array_equal(sw_c.counts, sw_n.counts)
    near = kc.nearest(poses[:2], q[:2] + 0.01)
    assert np.all(near.found) and np.all(near.max_move <= 0.015 + 1e-9)
    np.testing.assert_allclose(kc.fk(near.q), poses[:2], atol=1e-9)


@needs_gcc
@pytest.mark.parametrize("k", [4, 2])
def test_c_free_joint_is_clean_under_address_and_undefined_sanitizers(tmp_path, k):
    """xarm7 with q4 given (and q2: the deflated plan), built with -fsanitize=address,undefined, on axis-aligned
    configurations (singular: shared roots, degenerate pencils) and random ones: no invalid
    access, no undefined behaviour, counts within 0..16, no NaN before the padding and only NaN
    after it."""
    robot = derive.load_robot("xarm7")
    grid = np.array(np.meshgrid(*[[0.0, math.pi / 2, -math.pi / 2]] * 3, indexing="ij")).reshape(3, -1).T
    q = np.zeros((len(grid), 7))
    q[:, [1, 3, 5]] = grid
    q = np.concatenate([q, np.random.default_rng(6).uniform(-math.pi, math.pi, (13, 7))])
    poses = reference.fk(robot, q)
    n = len(q)
    rows = ",\n".join("{" + ", ".join(repr(float(v)) for v in p) + "}" for p in poses)
    vals = ", ".join(repr(float(v)) for v in q[:, k - 1])
    ident = cfree._identifier(robot, k)
    (tmp_path / "t.c").write_text(cfree.c_source(robot, k) + f"""
#include <stdio.h>
static const double poses[{n}][8] = {{{rows}}};
static const double vals[{n}] = {{{vals}}};
int main(void) {{
    static double sols[{n} * 16 * 7];
    static int counts[{n}], sg[{n} * 16], dg[{n}];
    {ident}_ik_batch_free({n}, &poses[0][0], vals, sols, counts, sg, dg);
    int bad = 0;
    for (int i = 0; i < {n}; ++i) {{
        bad += counts[i] < 0 || counts[i] > 16;
        for (int k = 0; k < 16 * 7; ++k) bad += k < counts[i] * 7 ? !isfinite(sols[i * 112 + k]) : !isnan(sols[i * 112 + k]);
    }}
    printf("%d\\n", bad);
    return 0;
}}
""")
    res = subprocess.run(["gcc", "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", "-fsanitize=address,undefined",
                          "-fno-sanitize-recover=all", "-o", str(tmp_path / "t"), str(tmp_path / "t.c"), "-lm"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    run = subprocess.run([str(tmp_path / "t")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split() == ["0"]


@pytest.mark.parametrize("name,k", [("xarm7", 4), ("gen3", 2)])
def test_free_joint_general_route_flags_stay_rare_on_random_poses(name, k):
    """The unreliability rule (odd count, the rescue plan's set not the plan's, a solution with
    sigma_min / sigma_max below G6_NEAR_SINGULAR) on the general route: the C kernel and the
    numpy reference flag the same poses, and at most 2 % of 200 random poses (measured 0-0.8 %
    on 1000)."""
    robot = derive.load_robot(name)
    q = _inside(robot, 200, np.random.default_rng(77 + k))
    poses = reference.fk(robot, q)
    fc = derive.kernels(name, "c", free=f"q{k}").ik_degenerate(poses, free=q[:, k - 1])
    fn = free_joint.solve(robot, poses, k, q[:, k - 1]).degenerate
    assert fc.mean() <= 0.02 and fn.mean() <= 0.02, (np.nonzero(fc)[0], np.nonzero(fn)[0])
    assert np.sum(fc != fn) <= 1, (np.nonzero(fc)[0], np.nonzero(fn)[0])


def _pencil_companions(robot, pl, q):
    """The companion matrices (3 offsets, n, 24, 24) of the locked 6R's pencil at the poses of the
    7R configurations q (n, 7), joint pl.joint held at q's value, built by the reference's
    per-value fit (free_joint._coefs), not by the code under test."""
    g6 = free_joint.g6
    n, k = len(q), pl.joint
    target = g6._to_matrix(reference.fk(robot, q))
    target[:, :3, 3] /= pl.scale
    d = free_joint.locked_chain(pl.c, k, q[:, k - 1])
    if pl.reverse:
        d = np.stack([g6._reverse(x) for x in d])
        target = np.linalg.inv(target)
    y, x = free_joint._coefs(d, pl.e, target)
    qq, _ = np.linalg.qr(x[:, :, :8], mode="complete")
    yy = y.copy()
    yy[:, :, 26] -= x[:, :, 8]
    order = [pl.ev] + [i for i in range(3) if i != pl.ev]
    ten = np.moveaxis((np.swapaxes(qq[:, :, 8:], 1, 2) @ yy).reshape(n, 6, 3, 3, 3), [2 + i for i in order], [2, 3, 4])
    mats = g6._twelve((ten.reshape(n, 6, 3, 9) @ g6._t45(pl.offsets[0], pl.offsets[1])).transpose(0, 2, 1, 3))
    out = []
    for d3 in pl.d3:
        mk = np.einsum("ak,naij->nkij", g6._half(d3), mats)
        inv = np.linalg.inv(mk[:, 2])
        comp = np.zeros((n, 24, 24))
        comp[:, :12, 12:] = np.eye(12)
        comp[:, 12:, :12] = -inv @ mk[:, 0]
        comp[:, 12:, 12:] = -inv @ mk[:, 1]
        out.append(comp)
    return out


@pytest.mark.parametrize("name,k,keep", [("xarm7", 3, 16), ("panda", 5, 12)])
def test_triple_side_plan_deflates(name, k, keep):
    """With joint 3-5 held (the held link on the loop cut's triple side) the C plan still deflates
    the eigenvectors every pose shares: xArm7's q3 per value (a basis as a trigonometric
    polynomial in the value, the core's runtime deflation), the Panda's q5 once for every value
    (their span does not move): the eigenproblem is keep x keep, not 24 x 24."""
    pl = cfree.c_plans(name, k)[0]
    assert not cfree._held_on_pair_side(pl)
    defl = cfree._core_context(pl, name)["defl"]
    assert bool(defl.get("runtime")) == (name == "xarm7") and (defl["on"] or defl.get("runtime"))
    assert defl["keep"] == keep


@pytest.mark.parametrize("name,k,kind", [("xarm7", 3, "fourier"), ("panda", 4, "pieces")])
def test_value_basis_is_invariant_at_random_values_and_poses(name, k, kind):
    """xArm7 with q3 held (a trigonometric polynomial in the value) and the Panda with q4 held
    (piecewise: no trigonometric fit holds; a basis on more than half of the pieces, which pieces
    depending on the fit: near v = 0 and pi some may have none): the
    per-value basis V(v) (cfree.value_basis, rotated to each offset) spans a subspace that every
    pose's companion matrix at that value maps into itself, on pencils built by the reference's
    per-value fit at values and poses it was not fitted at; the eigenvalues of the kept block and
    of the removed block together are the whole matrix's (no solution removed), and the removed
    ones are the same at every pose of a value. Where a piece has no basis (if any) V is zero
    (the C kernel's answers on such values: test_c_triple_side_deflation_matches_the_reference).
    The C's table of the pieces (each to its own degree, one after the other) gives the same V."""
    robot = derive.load_robot(name)
    pl = cfree.c_plans(robot, k)[0]
    vb = cfree.value_basis(pl)
    assert vb.kind == kind and vb.r == 8
    rng = np.random.default_rng(41)
    values = list(rng.uniform(-np.pi, np.pi, 4))
    if kind == "pieces":
        # a basis on most of the range (whether or not every piece has one); V = 0 where none
        assert len(vb.present) == len(vb.h) and 2 * sum(vb.present) > len(vb.present)
        for absent in [p for p, there in enumerate(vb.present) if not there]:
            assert not np.any(vb.at(-np.pi + (absent + 0.5) * 2 * np.pi / len(vb.present)))
        values = [v for v in rng.uniform(-np.pi, np.pi, 40) if vb.present[cfree._piece_of(v, len(vb.present))[0]]][:4]
        ctx = cfree._value_basis_context(pl, robot)
        flat = np.array([float(x) for x in re.findall(r"[-+0-9.eE]+", ctx["h"])])
        offsets = [int(x) for x in ctx["offsets"].split(",")]
        degrees = [int(x) for x in ctx["degrees"].split(",")]
        assert len(flat) == ctx["size"] and len(offsets) == len(degrees) == len(vb.present) == ctx["pieces"]
        for v in rng.uniform(-np.pi, np.pi, 16):
            p, t = cfree._piece_of(v, ctx["pieces"])
            if degrees[p] < 0:                        # no basis: V = 0
                assert not vb.present[p] and not np.any(vb.at(v))
                continue
            h = flat[offsets[p]:offsets[p] + (degrees[p] + 1) * 24 * 8].reshape(degrees[p] + 1, 24, 8)
            tk = np.polynomial.chebyshev.chebvander(t, degrees[p])[0]
            np.testing.assert_allclose(np.einsum("k,kij->ij", tk, h), vb.at(v), rtol=0, atol=1e-15)
    for v in values:
        q = _inside(robot, 4, rng)
        q[:, k - 1] = v
        v0 = vb.at(v)
        for o, comp in enumerate(_pencil_companions(robot, pl, q)):
            b = np.linalg.qr(cfree._offset_rotation(pl, o) @ v0, mode="complete")[0]
            r = v0.shape[1]
            t = b.T @ comp @ b                        # [V W] basis: V's block first
            leak = np.abs(t[:, r:, :r]).max(axis=(1, 2)) / np.maximum(1.0, np.abs(comp).max(axis=(1, 2)))
            assert leak.max() < 1e-9, (v, o, leak)
            removed = np.linalg.eigvals(t[:, :r, :r])
            kept = np.linalg.eigvals(t[:, r:, r:])
            whole = np.linalg.eigvals(comp)
            for i in range(len(q)):
                both = np.concatenate([removed[i], kept[i]])
                # matched one to one (a lost eigenvalue cannot hide behind a near duplicate)
                gap = np.abs(both[:, None] - whole[i][None])
                rows, cols = linear_sum_assignment(gap)
                assert len(both) == len(whole[i]) == len(rows)
                assert gap[rows, cols].max() < 1e-6 * (1 + np.abs(whole[i]).max())
                assert np.abs(removed[i][:, None] - removed[0][None]).min(axis=1).max() < 1e-6 * (1 + np.abs(removed[0]).max())


@needs_gcc
@pytest.mark.parametrize("name,k", [("xarm7", 3), ("panda", 5), ("panda", 4)])
def test_c_triple_side_deflation_matches_the_reference(name, k):
    """With the triple-side deflation (per value for xArm7's q3, piecewise per value for the
    Panda's q4, baked for the Panda's q5), 30
    configurations at their generating value and at one other value: the C kernel's counts,
    solutions (1e-9 rad), singular and degenerate flags equal the numpy reference's (which solves
    the whole 24 x 24); every solution within 1e-10 on the plain matrix FK; the generating
    configuration among them."""
    robot = derive.load_robot(name)
    rng = np.random.default_rng(43)
    q = _inside(robot, 30, rng)
    lo, hi = free_joint.joint_range(robot, k)
    v = np.stack([q[:, k - 1], rng.uniform(lo, hi, 30)], 1).reshape(-1)
    poses = np.repeat(reference.fk(robot, q), 2, axis=0)
    target = np.repeat(reference.fk_matrix(robot, q), 2, axis=0)
    cq, cc, cs, cd = cfree.c_library(robot, k, _compile).solve(poses, v)
    ref = free_joint.solve(robot, poses, k, v)
    np.testing.assert_array_equal(cc, ref.counts)
    np.testing.assert_array_equal(cd, ref.degenerate)
    assert cc.sum() > 100
    for i in range(len(v)):
        a, b = cq[i, :cc[i]], ref.q[i, :ref.counts[i]]
        assert _same_set(a, b, tol=1e-9), i
        if not len(a):
            continue
        match = _wrapped(a[:, None] - b[None]).max(-1).argmin(1)
        np.testing.assert_array_equal(cs[i, :cc[i]], ref.singular[i, :ref.counts[i]][match])
    valid = np.arange(16)[None] < cc[:, None]
    assert np.abs(reference.fk_matrix(robot, cq[valid]) - target[np.nonzero(valid)[0]]).max() < 1e-10
    gen = np.nanmin(np.where(valid, _wrapped(cq - np.repeat(q, 2, axis=0)[:, None]).max(-1), np.inf), axis=1)
    assert np.all(gen[::2] < 1e-6)


def test_plans_carry_the_robots_identity_for_their_caches():
    """The caches of the C plans (value_basis, _triple_side_deflation, the quiet plan's choice) are
    keyed by the robot's identity, which every plan (and its rescue) carries: a file arm that
    keeps a library arm's name must not share them."""
    robot = derive.load_robot("xarm7")
    for pl in cfree.c_plans(robot, 3):
        assert pl.robot_id == robot.id
        assert pl.alt is None or pl.alt.robot_id == robot.id


@needs_gcc
def test_c_free_joint_of_a_seven_joint_arm_from_a_file(tmp_path, monkeypatch):
    """A seven-joint arm read from a YAML file by path, under a name the library does not have
    (xArm7's file, its elbow offset 0.0531 m instead of 0.0525 so that its identity is its own):
    derive.kernels(path, "c", free="q6") builds (the C plans' deflation looks up the route of the
    robot itself, not of a library robot by the plan's name) and its solutions equal the "numpy"
    backend's (the numpy reference solver) and reproduce the pose by the plain matrix FK."""
    text = (derive.model.robot.LIBRARY_DIR / "xarm7.yaml").read_text(encoding="utf-8")
    assert "name: xarm7\n" in text and "[0.0525, 0, 0]" in text
    path = tmp_path / "my-arm7.yaml"
    path.write_text(text.replace("name: xarm7\n", "name: my_arm7\n").replace("[0.0525, 0, 0]", "[0.0531, 0, 0]"),
                    encoding="utf-8")
    robot = derive.load_robot(path)
    assert robot.name == "my_arm7" and robot.id != derive.load_robot("xarm7").id
    monkeypatch.setenv("DQ_DERIVE_CFLAGS", "-std=c99 -O0")      # quick to build; the flags are in the digest
    kc, kn = derive.kernels(path, "c", free="q6"), derive.kernels(path, "numpy", free="q6")
    q = _inside(robot, 6, np.random.default_rng(5))
    poses = reference.fk(robot, q)
    (cq, cc), (nq, nc) = kc.ik(poses, free=q[:, 5]), kn.ik(poses, free=q[:, 5])
    np.testing.assert_array_equal(cc, nc)
    assert cc.sum() >= 12
    for i in range(len(q)):
        assert _same_set(cq[i, :cc[i]], nq[i, :nc[i]]), i
    valid = np.arange(cq.shape[1])[None] < cc[:, None]
    target = reference.fk_matrix(robot, q)[np.nonzero(valid)[0]]
    assert np.abs(reference.fk_matrix(robot, cq[valid]) - target).max() < 1e-10


def test_c_free_joint_of_a_file_arm_named_like_a_library_arm(tmp_path):
    """A file arm named like a library arm of another class (xArm7's file, its elbow 0.0531 m,
    named "iiwa14", an SRS arm whose q6 is a class route): its C plan for q6 is on the general
    route and deflates as its own route says (the block _pair_deflation leaves, not 24: the
    library iiwa14's route would turn the deflation off)."""
    text = (derive.model.robot.LIBRARY_DIR / "xarm7.yaml").read_text(encoding="utf-8")
    path = tmp_path / "arm.yaml"
    path.write_text(text.replace("name: xarm7\n", "name: iiwa14\n").replace("[0.0525, 0, 0]", "[0.0531, 0, 0]"),
                    encoding="utf-8")
    robot = derive.load_robot(path)
    assert robot.name == "iiwa14" and free_joint.route(robot, 6) == "general"
    assert free_joint.route("iiwa14", 6) != "general"
    pl = cfree.c_plans(robot, 6)[0]
    defl = cfree._core_context(pl, robot)["defl"]
    assert defl["on"] and defl["keep"] == cfree._pair_deflation(pl)[1] < 24


def _dummy_plan(**kw):
    args = dict(robot="xarm7", joint=4, c=np.zeros((7, 4, 4)), scale=1.0, reverse=False, e=2, ev=1,
                offsets=np.array([0.3, -0.7, 1.1]), d3=1.1 + np.array([0.0, 2.0, 4.0]), notes="a plan")
    return free_joint.Plan(**{**args, **kw})


def test_plan_choices_in_the_user_cache_are_keyed_on_their_plans_and_constants(tmp_path, monkeypatch):
    """The C plan choices kept in the user cache (_quiet_plan's cut, _deflating_first's order) are
    made again, not taken from the cache, when the plans or the constants they were made with
    differ (a test's or a benchmark's monkeypatched constants within the same code), and taken
    from it when they are the same (stubs count the choices made)."""
    monkeypatch.setenv("DQ_DERIVE_CACHE", str(tmp_path / "cache"))
    robot = derive.load_robot("xarm7")
    made = []
    monkeypatch.setattr(cfree, "_fewest_suspects", lambda pl, r: made.append(pl.ev))
    pl = _dummy_plan()
    assert cfree._quiet_plan(pl, robot) is None and cfree._quiet_plan(pl, robot) is None
    assert len(made) == 1                                   # the second from the cache
    cfree._quiet_plan(_dummy_plan(ev=2), robot)             # another plan
    monkeypatch.setattr(cfree, "_SUSPECT_POSES", cfree._SUSPECT_POSES + 1)
    cfree._quiet_plan(pl, robot)                            # another constant
    assert len(made) == 3

    quiet = _dummy_plan(reverse=True, e=1, ev=0)
    monkeypatch.setattr(cfree, "_triple_deflates", lambda p: p is pl)
    suspects = {}
    monkeypatch.setattr(cfree, "_suspects", lambda p, *a: (suspects.setdefault(p.reverse, 0), 1.0))
    monkeypatch.setattr(cfree, "_SUSPECT_POSES", 10)
    suspects.update({False: 1, True: 0})                    # the reference's plan: 1 of 10 more
    assert [p.reverse for p in cfree._deflating_first(pl, quiet, robot)] == [False, True]
    suspects.update({False: 9, True: 0})                    # the same plans and constants: cached
    assert [p.reverse for p in cfree._deflating_first(pl, quiet, robot)] == [False, True]
    monkeypatch.setattr(cfree, "_DEFLATING_EXTRA_SUSPECTS", 0.05)
    suspects.update({False: 1, True: 0})                    # 1 of 10 more: above the new share
    assert [p.reverse for p in cfree._deflating_first(pl, quiet, robot)] == [True, False]


def test_pair_side_plans_are_ranked_by_one_measure(monkeypatch):
    """c_plans ranks the reference's plan and the candidate cuts of joints 1, 2, 6, 7 by the same
    measure (cfree._pair_score: the block the C kernel's baked deflation leaves, then whether only
    the span deflation reaches it). The Gen3's q1: the reference's plan reaches 16 only by the span
    deflation (its eigenvector-wise one leaves 20); with the eigenvector-wise deflation taken
    from every other cut (so they too reach at best 16 only by the span) none beats the
    reference's plan, which stays first; unpatched, a cut that reaches 16 by its eigenvectors
    alone comes first."""
    robot = derive.load_robot("gen3")
    pl = free_joint.plan(robot, 1)
    assert cfree._pair_score(pl) == (16, 1) and cfree._fixed_deflation(pl)[1] == 20
    first = cfree._c_plans(robot, 1)[0]
    assert (first.reverse, first.e, first.ev) != (pl.reverse, pl.e, pl.ev) and cfree._pair_score(first) == (16, 0)
    real = cfree._fixed_deflation
    mine = (pl.reverse, pl.e, pl.ev, tuple(pl.offsets))
    monkeypatch.setattr(cfree, "_fixed_deflation", lambda p, *a, **kw:
                        real(p, *a, **kw) if (p.reverse, p.e, p.ev, tuple(p.offsets)) == mine else None)
    got = cfree._c_plans(robot, 1)
    assert [(p.reverse, p.e, p.ev) for p in got] == [(pl.reverse, pl.e, pl.ev), (pl.alt.reverse, pl.alt.e, pl.alt.ev)]
