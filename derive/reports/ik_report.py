"""Typesetting of the extracted IK (generated/<robot>/ik.md and ik.tex) beside the thesis's
formulas 4.9-4.44."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import sympy as sp
import yaml

from derive._version import __version__
from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.algebra.angles import wrap_angle
from derive.cache import claim_folder, write_manifest
from derive.codegen.templates import template_environment
from derive.errors import DeriveError, InputError
from derive.ik.closed_form import parallel3_class, spherical_class
from derive.ik.extract import R_SYMS, check_numerically, extract
from derive.ik import panda as panda_ik
from derive.ik import srs as srs_ik
from derive.ik.program import spherical_forms
from derive.ik.nearclass import classify as nearclass_classify
from derive.ik.redundant import LABELS, free_parameter, redundant_kind, solve
from derive.ik.spherical import canonical_robot
from derive.ik.tolerances import ACCEPT_POSITION, DOUBLE_ROOT, REACH_TOL, STRETCH_TOL, WRIST_SINGULAR
from derive.kinematics.fk import fk
from derive.model.robot import load_robot
from derive.reports.appendix import class_context
from derive.reports.latex import latex, side
from derive.symbolic.equations import POSES, derive_equations
from derive.symbolic.trig import as_expr, compact

THESIS_DATA = Path(__file__).resolve().parent.parent / "data" / "thesis_printed.yaml"
PATTERNS = {
    "S1": "one equation A cos u + B sin u + C = 0 (two roots)",
    "S2": "two equations linear in cos u and sin u (atan2, one root)",
    "S3": "two equations squared and added, the other unknown eliminated (two roots)",
    "span": "a combination of the angles found before",
}


def _thesis():
    data = yaml.safe_load(THESIS_DATA.read_text())
    names = {f"t{k}": sp.Symbol(f"theta{k}", real=True) for k in range(1, 7)}
    for n in ("d1 a2 a3 d4 d5 d6 w a b c x y z w4 a4 b4 c4 x4 y4 z4 x5 y5 z5 "
              "alpha beta gamma delta").split():
        names[n] = sp.Symbol(n, real=True)
    return data["formulas"], names


def _thetas_of(unknown: str) -> set:
    return {s.name for s in sp.sympify(unknown).free_symbols}


def build_ik_context(robot, command: str) -> dict:
    robot = load_robot(robot)
    ext = extract(robot)
    check_numerically(ext, samples=200)
    chain = ext.chain
    _, sets = derive_equations(robot, symbolic=False)
    eq_by_id = {e.id: e for s in sets for e in s.equations}
    thetas = [j.theta for j in chain.joints]

    steps, used_eqs, used_syms, known_order, deps = [], set(), set(), [], {}
    for k, st in enumerate(ext.steps):
        used_eqs |= set(st.equations)
        for f in st.forms:
            used_syms |= f.free_symbols
        for eid in st.equations:
            used_syms |= (eq_by_id[eid].lhs - eq_by_id[eid].rhs).free_symbols
        # the equations an angle rests on: its own and those of the steps it combines
        own = set(st.equations)
        for f in st.forms:
            for s2 in f.free_symbols:
                own |= deps.get(s2, set())
        deps[st.symbol] = own
        if st.symbol in thetas:
            known_order.append(st.symbol)
        steps.append({
            "k": k + 1,
            "symbol": latex(st.symbol),
            "unknown": latex(sp.sympify(st.unknown, locals={str(t): t for t in thetas})),
            "is_compound": st.symbol not in thetas,
            "pattern": st.pattern,
            "pattern_text": PATTERNS[st.pattern],
            "equations": [{"id": eid, "lhs": " ".join(side(eq_by_id[eid].lhs_terms)),
                           "rhs": " ".join(side(eq_by_id[eid].rhs_terms))} for eid in st.equations],
            "forms": [latex(f) for f in st.forms],
            "branches": st.branches,
            "check": f"{100 * st.check:.0f} %",
            "note": st.note,
        })

    gens = list(POSES["B"]) + list(chain.parameters) + list(R_SYMS)
    definitions = []
    for sym in list(POSES["W"]) + list(POSES["C"]):
        if sym in used_syms:
            expr = as_expr(compact(ext.definitions[sym], gens))
            definitions.append({"symbol": latex(sym), "expr": latex(expr)})

    formulas, names = _thesis()
    thesis_rows = []
    for f in formulas:
        angle = names[f["angle"]]
        defs = {names[k]: sp.sympify(v, locals=names) for k, v in (f.get("definitions") or {}).items()}
        ours = sorted(deps.get(angle, set()), key=lambda i: ("BWC".index(i[0]), int(i[2:])))
        theirs = list(f["equations"])
        thesis_rows.append({
            "id": f["id"], "angle": latex(angle),
            "forms": [latex(sp.sympify(c, locals=names)) for c in f["candidates"]],
            "definitions": [f"{latex(k)} = {latex(v)}" for k, v in defs.items()],
            "thesis_equations": ", ".join(theirs), "pipeline_equations": ", ".join(ours),
            "same": set(theirs) == set(ours) or (theirs and set(theirs) <= set(ours)),
        })
    thesis_order = [names[f["angle"]] for f in formulas]      # the data lists 4.11 ... 4.44 in order
    return {
        "version": __version__, "command": command, "robot": chain.robot,
        "title": robot.title,
        "parameters": [(latex(p), v) for p, v in chain.parameters.items()],
        "steps": steps, "definitions": definitions,
        "order": ", ".join(latex(t) for t in known_order),
        "thesis_order": ", ".join(latex(t) for t in thesis_order),
        "same_order": [str(t) for t in known_order] == [str(t) for t in thesis_order],
        "thesis": thesis_rows,
        "g_identity": tuple(sp.sympify(v) for v in chain.end_transform[0]) == (1, 0, 0, 0),
    }


def write_ik(robot, out_dir, progress: bool = False, command: str | None = None,
             force: bool = False) -> list:
    """Extract and typeset the closed-form IK into out_dir/<robot name>/ik.{md,tex}, recorded in
    its manifest (a folder of another robot is refused unless ``force``). A 7R arm of the Franka
    Panda or SRS class (:func:`derive.ik.redundant.redundant_kind`) gets the closed form with its
    free parameter (:func:`build_redundant_ik_context`); a 6R arm the extracted one."""
    t0 = time.perf_counter()
    robot = load_robot(robot)
    robot_name = robot.name
    claim_folder(Path(out_dir) / robot_name, robot.id, robot_name, force)
    command = command or f"dq-derive ik {robot_name}"
    kind = redundant_kind(robot)
    if kind is not None:
        ctx, stem = build_redundant_ik_context(robot, command), "ik_redundant"
    else:
        geo = spherical_class(robot)
        p3 = parallel3_class(robot) if geo is None and robot.dof == 6 else None
        if p3 is not None:
            ctx, stem = build_parallel3_ik_context(robot, p3, command), "ik_parallel3"
        elif geo is None:
            try:
                ctx, stem = build_ik_context(robot, command), "ik"
            except DeriveError as exc:
                raise DeriveError(_no_typeset_form(robot, exc)) from None
        else:
            ctx, stem = build_sw_ik_context(robot, geo, command), "ik_spherical"
    env = template_environment()
    out = Path(out_dir) / robot_name
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in ("ik.md", "ik.tex"):
        path = out / name
        path.write_text(env.get_template(name.replace("ik", stem) + ".j2").render(ctx), encoding="utf-8")
        written.append(path)
    written.append(write_manifest(out, {"id": robot.id, "robot": robot_name,
                                        "files": {"ik/md": "ik.md", "ik/tex": "ik.tex"}}))
    if progress:
        print(f"[{robot_name}] IK extracted and typeset ({time.perf_counter() - t0:.2f} s)", file=sys.stderr)
    return written


def _no_typeset_form(robot, exc) -> str:
    """The message of a robot whose IK cannot be typeset: the extraction's reason, and for an arm
    that the general 6R elimination solves (:func:`derive.ik.nearclass.classify`'s ``general6r``,
    not a near-class arm) why there is nothing to typeset and how its IK is computed instead."""
    text = str(exc)
    c = nearclass_classify(robot) if robot.dof == 6 else None
    if c is None or not c.general6r or c.closed_form:        # (a near-class arm: its nominal's closed form)
        return text
    why = text.split(": ", 1)[-1] if text.startswith(robot.name + ": ") else text
    return (f"{robot.name}: no closed form to typeset: the arm is of no special class (UR, spherical "
            "wrist, three parallel), and its IK is the general 6R elimination (derive.ik.general6r: "
            "up to 16 solutions, the roots of an eigenproblem solved per pose in numbers), not a "
            f"sequence of closed-form steps; solve a pose with `dq-derive ik {robot.name} --q ...` (or "
            f"--xyz/--rpy, --dq) or derive.kernels(robot). (The equations' extraction: {why})")


# --------------------------------------------------------------------------- #
# Spherical-wrist class
# --------------------------------------------------------------------------- #
def _sw_check(geo, chain, sf, samples: int = 200, seed: int = 5) -> dict:
    """Per step, the fraction of random configurations (within +-pi) whose true angle is among
    the candidates of the typeset closed form, evaluated with numpy at the robot's numbers."""
    rng = np.random.default_rng(seed)
    canon = canonical_robot(geo)
    th = rng.uniform(-np.pi, np.pi, size=(samples, 6))
    pose = fk(canon, th)
    r = dq.to_matrix(pose)
    values = {k: float(v) for k, v in chain.parameters.items()}
    t = r[:, :3, 3] - r[:, :3, 2] * values[sp.Symbol("c4", real=True)]
    x_w, y_w, z_w = POSES["P"][4:]
    w_r, a_r, b_r, c_r = POSES["O"][:4]
    thetas = [j.theta for j in chain.joints]
    env = {x_w: t[:, 0], y_w: t[:, 1], z_w: t[:, 2]}
    env.update({s: th[:, i] for i, s in enumerate(thetas)})
    # the O pose from the true angles: conj(q1 q23) q
    half1, half23 = th[:, 0] / 2, (th[:, 1] + th[:, 2]) / 2
    q123 = np.stack([np.cos(half1) * np.cos(half23), -np.sin(half1) * np.sin(half23),
                     np.cos(half1) * np.sin(half23), np.sin(half1) * np.cos(half23)], -1)
    o = quat._mul(quat._conj(q123), pose[:, :4])
    env.update({w_r: o[:, 0], a_r: o[:, 1], b_r: o[:, 2], c_r: o[:, 3]})

    def ev(e):
        e = sp.sympify(e).xreplace({k: sp.Float(v) for k, v in values.items()})
        syms = sorted(e.free_symbols, key=str)
        f = sp.lambdify(syms, e, "numpy")
        return np.broadcast_to(f(*[env[s] for s in syms]), (samples,)).astype(float)

    def hit(cands, true):
        d = np.min(np.stack([np.abs(wrap_angle(c - true)) for c in cands]), axis=0)
        return f"{100 * np.mean(d < 1e-7):.0f} %"

    t1, t2, t3, t4, t5, t6 = thetas
    a, b, c = (ev(e) for e in sf.theta1)
    root = np.sqrt(np.clip(a * a + b * b - c * c, 0, None))
    out = {"theta1": hit([np.arctan2(a, -b) - np.arctan2(-c, s * root) for s in (1, -1)], th[:, 0])}
    env[sf.X], env[sf.Z] = ev(sf.x_def), ev(sf.z_def)
    a, b, c = (ev(e) for e in sf.theta3)
    root = np.sqrt(np.clip(a * a + b * b - c * c, 0, None))
    out["theta3"] = hit([np.arctan2(b, a) + s * np.arctan2(root, -c) for s in (1, -1)], th[:, 2])
    ns, nc, d = (ev(e) for e in sf.theta2)
    out["theta2"] = hit([np.arctan2(np.sign(d) * ns, np.sign(d) * nc)], th[:, 1])
    comp = {}
    for kind, (ns, nc, k, _) in sf.halves.items():
        comp[kind] = (ev(ns), ev(nc), float(k))
    hs = np.hypot(comp["sin"][0], comp["sin"][1]) / abs(comp["sin"][2])
    hc = np.hypot(comp["cos"][0], comp["cos"][1]) / abs(comp["cos"][2])
    out["theta5"] = hit([2 * s * np.arctan2(hs, hc) for s in (1, -1)], th[:, 4])
    s_sum = np.arctan2(np.sign(comp["cos"][2]) * comp["cos"][0], np.sign(comp["cos"][2]) * comp["cos"][1])
    s_dif = np.arctan2(np.sign(comp["sin"][2]) * comp["sin"][0], np.sign(comp["sin"][2]) * comp["sin"][1])
    out["theta4"] = hit([s_sum + s_dif, s_sum + s_dif + np.pi], th[:, 3])
    out["theta6"] = hit([s_sum - s_dif, s_sum - s_dif - np.pi], th[:, 5])
    return out


def build_sw_ik_context(robot, geo, command: str) -> dict:
    """The closed form of a spherical-wrist arm as its class's derived equations give it."""
    canon = canonical_robot(geo)
    chain, sets = derive_equations(canon, symbolic=False)
    eq_by_id = {e.id: e for s in sets for e in s.equations}
    sf = spherical_forms(chain, {k: sp.expand(e.lhs - e.rhs) for k, e in eq_by_id.items()})
    check = _sw_check(geo, chain, sf)
    thetas = [j.theta for j in chain.joints]
    t1, t2, t3, t4, t5, t6 = thetas

    def eqs(ids):
        return [{"id": i, "lhs": " ".join(side(eq_by_id[i].lhs_terms)),
                 "rhs": " ".join(side(eq_by_id[i].rhs_terms))} for i in ids]

    a1, b1, c1 = sf.theta1
    a3, b3, c3 = sf.theta3
    ns2, nc2, d2 = sf.theta2
    hcos, hsin = sf.halves["cos"], sf.halves["sin"]
    sig1, sig2 = sp.Symbol(r"\sigma_1", real=True), sp.Symbol(r"\sigma_2", real=True)
    steps = [
        {"k": 1, "symbol": latex(t1), "pattern": "S1", "text": PATTERNS["S1"], "check": check["theta1"],
         "equations": eqs(["P.13"]),
         "coefficients": [f"A = {latex(a1)},\\; B = {latex(b1)},\\; C = {latex(c1)}"],
         "forms": [r"\operatorname{atan2}(A, -B) - \operatorname{atan2}\left(-C, \pm\sqrt{A^2 + B^2 - C^2}\right)"]},
        {"k": 2, "symbol": latex(t3), "pattern": "S3", "text": PATTERNS["S3"], "check": check["theta3"],
         "equations": eqs(["P.12", "P.14"]),
         "coefficients": [f"X = {latex(sf.x_def)},\\; Z = {latex(sf.z_def)}",
                          f"A = {latex(a3)},\\; B = {latex(b3)},\\; C = {latex(c3)}"],
         "forms": [r"\operatorname{atan2}(B, A) \pm \operatorname{atan2}\left(\sqrt{A^2 + B^2 - C^2}, -C\right)"]},
        {"k": 3, "symbol": latex(t2), "pattern": "S2", "text": PATTERNS["S2"], "check": check["theta2"],
         "equations": eqs(["P.12", "P.14"]),
         "coefficients": [f"d = {latex(d2)}"],
         "forms": [r"\operatorname{atan2}\left(\operatorname{sgn}(d)\,(" + latex(ns2) + r"),\ "
                   r"\operatorname{sgn}(d)\,(" + latex(nc2) + r")\right)"]},
        {"k": 4, "symbol": latex(t5), "pattern": "half angles", "check": check["theta5"],
         "text": "cos and sin of theta5/2 from the magnitudes of the two wrist pairs (exact at 0 and pi)",
         "equations": eqs(["O.15", "O.16", "O.17", "O.18"]),
         "coefficients": [],
         "forms": [r"\pm 2 \operatorname{atan2}\left(\sqrt{" + latex(hsin[0] ** 2 + hsin[1] ** 2) + r"},\ \sqrt{"
                   + latex(hcos[0] ** 2 + hcos[1] ** 2) + r"}\right)"]},
        {"k": 5, "symbol": latex(sig1) + " = " + latex((t4 + t6) / 2), "pattern": "S2",
         "text": PATTERNS["S2"] + ", divided by " + ("" if hcos[2] == 1 else f"{hcos[2]} ") + "cos(theta5/2)", "check": check["theta4"],
         "equations": eqs(list(hcos[3])), "coefficients": [],
         "forms": [latex(sp.atan2(hcos[0], hcos[1]))]},
        {"k": 6, "symbol": latex(sig2) + " = " + latex((t4 - t6) / 2), "pattern": "S2",
         "text": PATTERNS["S2"] + ", divided by " + ("" if hsin[2] == 1 else f"{hsin[2]} ")
         + "sin(theta5/2) (plus pi on the branch sin(theta5/2) < 0)",
         "check": check["theta6"], "equations": eqs(list(hsin[3])), "coefficients": [],
         "forms": [latex(sp.atan2(hsin[0], hsin[1]))]},
    ]
    return {
        "version": __version__, "command": command, "robot": robot.name, "title": robot.title,
        "sw": class_context(geo, robot), "steps": steps,
        "spans": [f"{latex(t4)} = {latex(sig1 + sig2)}", f"{latex(t6)} = {latex(sig1 - sig2)}"],
        "wrist_singular": WRIST_SINGULAR,
    }


# --------------------------------------------------------------------------- #
# Seven-joint classes with a free parameter (Franka Panda class, SRS class)
# --------------------------------------------------------------------------- #
#: The numerical check of the 7R report: configurations, seed of numpy's default_rng, and the
#: distance (rad, every joint, after wrapping) within which a solution is the generating
#: configuration.
CHECK7_SAMPLES = 200
CHECK7_SEED = 7
CHECK7_FOUND = 1e-9
#: The largest FK residual is reported as below the first of these levels it is below (a level,
#: not the value, so that rounding differences between machines do not change the text).
RESIDUAL_LEVELS = (1e-12, 1e-10, 1e-8)

#: The sources of each class: (authors, title, where and what is taken from it).
SOURCES = {
    "srs": [("M. Shimizu, H. Kakuya, W.-K. Yoon, K. Kitagaki, K. Kosuge",
             "Analytical inverse kinematic computation for 7-DOF redundant manipulators with joint "
             "limits and its application to redundancy resolution",
             "IEEE Transactions on Robotics 24(5), 2008, sec. III (the arm angle, the joints as "
             "functions of it, the feasible arm angles)"),
            ("C. Faria, F. Ferreira, W. Erlhagen, S. Monteiro, E. Bicho",
             "Position-based kinematics for 7-DoF serial manipulators with global configuration "
             "control, joint limit and singularity avoidance",
             "Mechanism and Machine Theory 121, 2018 (the same construction for the iiwa, the "
             "configuration flags GC2, GC4, GC6)")],
    "panda": [("Y. He, S. Liu",
               "Analytical inverse kinematics for Franka Emika Panda - a geometric solver for 7-DOF "
               "manipulators with unconventional design",
               "ICCCR 2021 (q7 fixed, the point O6, the elbow from the shoulder-O6 distance, then q6, "
               "q5 and the shoulder; the steps here are dq-derive's own form of that geometry, "
               "derive.ik.panda)")],
}


def _num(x) -> str:
    """A number for the report: at most 12 significant digits (no float noise such as
    0.30000000000000004), 0 below 1e-12 in magnitude (never -0)."""
    x = float(x)
    if abs(x) < 1e-12:
        return "0"
    return f"{x:.12g}"


def _lin(terms) -> str:
    """LaTeX of the sum of (coefficient, factor) terms with the numbers formatted by
    :func:`_num`; zero terms left out, a unit coefficient not printed before a factor."""
    out = ""
    for c, f in terms:
        c = float(c)
        if abs(c) < 1e-12:
            continue
        mag = _num(abs(c))
        body = f if (mag == "1" and f) else (rf"{mag}\,{f}" if f else mag)
        if not out:
            out = ("-" if c < 0 else "") + body
        else:
            out += (" - " if c < 0 else " + ") + body
    return out or "0"


def _vector(v) -> str:
    return r"\left(" + ",\\ ".join(_num(x) for x in v) + r"\right)"


def _matrix(m) -> str:
    rows = [" & ".join(_num(x) for x in row) for row in np.asarray(m, dtype=float)]
    return r"\begin{pmatrix} " + r" \\ ".join(rows) + r" \end{pmatrix}"


def _sci(x: float) -> str:
    """A tolerance such as 1e-10 (not 1e-010 or 1e-08)."""
    return f"{x:.0e}".replace("e-0", "e-").replace("e+0", "e+")


def _residual_text(largest: float) -> str:
    for level in RESIDUAL_LEVELS:
        if largest < level:
            return f"below {_sci(level)}"
    return f"at least {_sci(RESIDUAL_LEVELS[-1])}"


def _redundant_check(robot, kind: str, samples: int = CHECK7_SAMPLES, seed: int = CHECK7_SEED) -> dict:
    """The report's numerical check of :func:`derive.ik.redundant.solve`: ``samples``
    configurations uniform inside the joint limits (numpy ``default_rng(seed)``; +-pi for a joint
    without limits), their poses by the reference FK (:func:`derive.kinematics.fk.fk`, the
    function that :mod:`derive.reference` exports as ``fk``), each solved at its own value of the
    free parameter (q7 = q[:, 6], or the arm angle :func:`derive.ik.srs.arm_angle`). Returns how
    many generating configurations are among the solutions (every joint within CHECK7_FOUND rad
    after :func:`derive.algebra.angles.wrap_angle`), the largest FK residual of any returned
    solution (unit dual quaternions compared up to sign, min(|a - b|, |a + b|) of the largest
    component) as a RESIDUAL_LEVELS level, and the histogram of solution counts."""
    q, poses = _check_configurations(robot, samples, seed)
    free = q[:, 6] if kind == "panda" else srs_ik.arm_angle(robot, q)
    sol = solve(robot, poses, free)
    return _check_summary(robot, q, poses, sol.q, sol.counts, sol.reason, samples, seed)


def _check_configurations(robot, samples: int, seed: int):
    """``samples`` configurations uniform inside the joint limits (numpy ``default_rng(seed)``;
    +-pi for a joint without limits) and their poses by the reference FK."""
    lim = np.asarray(robot.limits, dtype=float)
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -np.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], np.pi)
    rng = np.random.default_rng(seed)
    q = rng.uniform(lo, hi, size=(samples, 7))
    return q, fk(robot, q)


def _check_summary(robot, q, poses, sols, counts, reasons, samples: int, seed: int) -> dict:
    """The report's check numbers for solutions ``sols`` (n, 8, 7) of the poses of ``q``: the
    generating configurations found, the largest FK residual, the histogram of counts."""
    with np.errstate(invalid="ignore"):
        dist = np.abs(wrap_angle(sols - q[:, None, :])).max(-1)
    dist = np.where(np.isfinite(dist), dist, np.inf).min(-1)
    found = int(np.sum(dist < CHECK7_FOUND))
    valid = np.isfinite(sols).all(-1)
    rows, _ = np.nonzero(valid)
    got, want = fk(robot, sols[valid]), poses[rows]
    res = np.minimum(np.abs(got - want).max(-1), np.abs(got + want).max(-1))
    largest = float(res.max()) if len(res) else 0.0
    hist = np.bincount(counts, minlength=9)
    return {
        "samples": samples, "seed": seed, "found": found,
        "found_percent": f"{100 * found // samples} %", "found_tol": f"{_sci(CHECK7_FOUND)}",
        "solutions": int(valid.sum()), "residual": _residual_text(largest),
        "unsolved": int(sum(1 for r in reasons if r)),
        "histogram": [{"count": k, "poses": int(n)} for k, n in enumerate(hist) if n],
    }


def _joint3_context(robot) -> dict:
    """The SRS closed form with joint 3 given instead of psi (:func:`derive.ik.srs.ik_joint`,
    :func:`derive.ik.program7.srs_joint3_program`): steps, branch numbering and its check."""
    q, poses = _check_configurations(robot, CHECK7_SAMPLES, CHECK7_SEED)
    sol = srs_ik.ik_joint(robot, poses, 3, q[:, 2])
    check = _check_summary(robot, q, poses, sol.q, sol.count, sol.reason, CHECK7_SAMPLES, CHECK7_SEED)
    steps = [
        {"title": r"The pose, the wrist centre and the elbow $\theta_4$",
         "text": r"As steps 1 and 2 above; $\theta_3 = s_3 q_3$ is given.", "formulas": []},
        {"title": r"The shoulder $\theta_1, \theta_2$ (the root of subproblem 2)",
         "text": r"The shoulder carries the forearm $u = R_z(\theta_3)\, v(\theta_4)$ onto $W$: "
                 r"$R_z(\theta_1) R_y(\theta_2)\, u = W$ (Paden-Kahan subproblem 2 about $z$ and $y$). "
                 r"Its $z$ row fixes $\theta_2$ (two roots, unreachable with this $\theta_3$ where the "
                 r"cosine leaves $[-1, 1]$), then $\theta_1$ turns $u' = R_y(\theta_2)\, u$ onto $W$ "
                 r"(free, set to 0, where $W$ lies on axis 1):",
         "formulas": [r"\theta_2 = \pm\arccos\frac{W_z}{\sqrt{u_x^2 + u_z^2}} - \operatorname{atan2}(u_x, u_z),"
                      r"\qquad \theta_1 = \operatorname{atan2}(W_y, W_x) - \operatorname{atan2}(u'_y, u'_x)"]},
        {"title": r"The wrist $\theta_5, \theta_6, \theta_7$",
         "text": r"As step 6 above, from the rounded $\theta_1, \theta_2, \theta_3, \theta_4$.",
         "formulas": []},
    ]
    return {"steps": steps, "check": check,
            "branch": r"k = 4\, i + 2\, i_4 + i_6",
            "branch_text": r"$i = 0$ for the + root and 1 for the - root of $\theta_2$, the others as above."}


def _srs_context(robot) -> dict:
    """Class paragraph, numbers, steps and singular sets of an SRS arm, after
    :mod:`derive.ik.srs` (Shimizu sec. III; Faria) and :func:`derive.ik.program7.srs_program`."""
    geo = srs_ik.srs_geometry(robot)
    _, (lo, hi) = free_parameter(robot)
    dse, dew = geo.d_se, geo.d_ew
    signs = [int(s) for s in geo.signs]
    s4 = signs[3]
    intro = [
        "The SRS class (spherical shoulder, revolute elbow, spherical wrist): axes 1, 2, 3 meet at "
        "the shoulder $S$, axes 5, 6, 7 at the wrist centre $W$, and at the zero pose the arm is "
        "stretched along one line through both, axes 1, 3, 5, 7 on it and axes 2, 4, 6 "
        "perpendicular to it, axis 4 crossing it at the elbow $E$. A pose fixes $S$ and $W$, and "
        "so the triangle $S, E, W$ up to a rotation about the shoulder-wrist line: one free "
        "parameter remains.",
        r"The free parameter is the arm angle $\psi$ (rad), after Shimizu et al. (2008, sec. III): "
        "the rotation of the arm plane $(S, E, W)$ about the shoulder-wrist line, right-handed "
        r"about $x = W / \lVert W \rVert$, measured from the reference plane (the plane of axis 1 "
        r"and $W$, in which the arm lies with $\theta_3 = 0$; $\psi = 0$ has the elbow on the side "
        r"that the sign of $\theta_4$ gives). It is periodic, its range "
        rf"$[-\pi, \pi)$ = [{_num(lo)}, {_num(hi)}) rad; the values a pose can take under the "
        "joint limits are a union of intervals (derive.ik.srs.psi\\_intervals, from the closed "
        r"form's breakpoints). With $\psi$ given, a pose has up to 8 solutions.",
    ]
    numbers = [
        {"name": "d_{bs}", "value": _num(geo.d_bs), "text": "base origin to shoulder (m)"},
        {"name": "d_{se}", "value": _num(dse), "text": "shoulder to elbow (m)"},
        {"name": "d_{ew}", "value": _num(dew), "text": "elbow to wrist centre (m)"},
        {"name": "d_{wf}", "value": _num(geo.d_wf), "text": "wrist centre to the end frame along the arm line at zero (m)"},
    ]
    relation = [
        r"\theta_i = s_i\, q_i,\quad s = " + _vector(signs),
        r"F = " + _matrix(geo.frame) + r",\quad S = " + _vector(geo.shoulder),
        r"T_R = " + _matrix(geo.tool_rotation) + r",\quad t_T = " + _vector(geo.tool_translation),
        r"R(\theta) = R_z(\theta_1) R_y(\theta_2) R_z(\theta_3) R_y(\theta_4) R_z(\theta_5) "
        r"R_y(\theta_6) R_z(\theta_7),\quad W(\theta) = R_z(\theta_1) R_y(\theta_2) R_z(\theta_3)\, "
        r"v(\theta_4),\quad v(\theta_4) = \left(d_{ew} \sin\theta_4,\ 0,\ d_{se} + d_{ew} \cos\theta_4\right)",
    ]
    relation_text = (
        r"In the canonical frame (origin $S$, $z$ along the arm line, $y$ along axis 2; its axes "
        r"are the columns of $F$ in base coordinates) every axis is $\pm z$ or $\pm y$, so with "
        r"$\theta_i = s_i q_i$ the rotation and wrist centre are the products below; the robot's "
        r"end frame is $(F R, S + F W)$ followed by the constant $(T_R, t_T)$ (the end frame in the "
        r"wrist frame at zero; the flange offset $d_{wf}$ and any tool are in it). The relation "
        f"reproduces the robot's FK on random configurations with errors {_residual_text(geo.error)} "
        "(m, rad; below 1e-10 is required).")
    cos_c, cos_d = dse ** 2 + dew ** 2, 2 * dse * dew
    steps = [
        {"title": "The pose in the canonical frame, the wrist centre",
         "text": "From the pose's rotation $R$ and translation $t$:",
         "formulas": [r"R_c = F^\top R\, T_R^\top,\qquad W = F^\top (t - S) - R_c\, t_T"]},
        {"title": r"The elbow $\theta_4$ (branch GC4)",
         "text": r"The triangle $S, E, W$ gives the elbow by the cosine law, independent of $\psi$; "
                 r"its two roots are the elbow branches.",
         "formulas": [r"\cos\theta_4 = \frac{\lVert W \rVert^2 - d_{se}^2 - d_{ew}^2}{2\, d_{se}\, d_{ew}}"
                      r" = \frac{\lVert W \rVert^2 - " + _num(cos_c) + "}{" + _num(cos_d) + "}",
                      r"\theta_4 = \pm \arccos(\cos\theta_4)"]},
        {"title": r"The reference configuration $R_0$",
         "text": r"The shoulder rotation with $\theta_3 = 0$ that carries $v(\theta_4)$ onto $W$ "
                 r"(with $W$ on axis 1, $W_x = W_y = 0$, $a = 0$ is taken):",
         "formulas": [r"R_0 = R_z(a)\, R_y(b - \varphi),\quad a = \operatorname{atan2}(W_y, W_x),\quad "
                      r"b = \operatorname{atan2}\left(\sqrt{W_x^2 + W_y^2},\ W_z\right),\quad "
                      r"\varphi = \operatorname{atan2}(v_x, v_z)",
                      r"v = \left(" + _num(dew) + r"\sin\theta_4,\ 0,\ " + _num(dse) + " + "
                      + _num(dew) + r"\cos\theta_4\right)"]},
        {"title": r"The shoulder rotation at the arm angle $\psi$",
         "text": r"Every shoulder rotation that carries $v(\theta_4)$ onto $W$ is $R_0$ followed by a "
                 r"rotation about $x = W / \lVert W \rVert$ (Rodrigues); it is affine in "
                 r"$\sin\psi$ and $\cos\psi$:",
         "formulas": [r"R_\psi = I + \sin\psi\, [x]_\times + (1 - \cos\psi)\, [x]_\times^2,\qquad R_s = R_\psi R_0",
                      r"R_s = A_s \sin\psi + B_s \cos\psi + C_s,\quad A_s = [x]_\times R_0,\quad "
                      r"B_s = -[x]_\times^2 R_0,\quad C_s = x x^\top R_0"]},
        {"title": r"The shoulder joints $\theta_1, \theta_2, \theta_3$ (branch GC2)",
         "text": r"A ZYZ Euler decomposition $R_s = R_z(\theta_1) R_y(\theta_2) R_z(\theta_3) = (m_{ij})$, "
                 r"the sign (GC2) that of $\sin\theta_2$; the kernels compute $\theta_3$ from the "
                 r"rounded $\theta_1, \theta_2$ (column 1 of $R_y(\theta_2)^\top R_z(\theta_1)^\top R_s$), "
                 "which equals the formula below and keeps the product exact near the singular set:",
         "formulas": [r"\theta_2 = \operatorname{atan2}\left(\pm\sqrt{m_{13}^2 + m_{23}^2},\ m_{33}\right),\quad "
                      r"\theta_1 = \operatorname{atan2}(\pm m_{23},\ \pm m_{13}),\quad "
                      r"\theta_3 = \operatorname{atan2}(\pm m_{32},\ \mp m_{31})"]},
        {"title": r"The wrist joints $\theta_5, \theta_6, \theta_7$ (branch GC6)",
         "text": r"The wrist rotation from the rounded shoulder angles (so that the wrist absorbs "
                 r"their rounding), then the same ZYZ decomposition $R_w = R_z(\theta_5) R_y(\theta_6) "
                 r"R_z(\theta_7) = (n_{ij})$, the sign (GC6) that of $\sin\theta_6$:",
         "formulas": [r"R_w = \left(R_z(\theta_1) R_y(\theta_2) R_z(\theta_3) R_y(\theta_4)\right)^\top R_c",
                      r"\theta_6 = \operatorname{atan2}\left(\pm\sqrt{n_{13}^2 + n_{23}^2},\ n_{33}\right),\quad "
                      r"\theta_5 = \operatorname{atan2}(\pm n_{23},\ \pm n_{13}),\quad "
                      r"\theta_7 = \operatorname{atan2}(\pm n_{32},\ \mp n_{31})"]},
        {"title": "The joint values",
         "text": r"Each candidate is wrapped to $(-\pi, \pi]$ and checked by the FK (dropped beyond "
                 f"{_sci(ACCEPT_POSITION)} in position or rotation); branches that coincide on a singular "
                 "set are returned once.",
         "formulas": [r"q_i = s_i\, \theta_i"]},
    ]
    branch = {
        "formula": r"k = 4\, i_2 + 2\, i_4 + i_6",
        "text": r"with $i = 0$ for the + sign and 1 for the - sign of GC2 ($\sin\theta_2$), GC4 "
                r"($\theta_4$) and GC6 ($\sin\theta_6$). The signs are those of the canonical angles "
                rf"$\theta_i = s_i q_i$; here $s_4 = {s4}$" + (", so GC4 + is $q_4 < 0$." if s4 < 0 else "."),
    }
    singular = [
        {"name": r"Elbow stretched or folded ($\theta_4 = 0$ or $\pi$)",
         "text": rf"$\cos\theta_4$ within {_sci(STRETCH_TOL)} of $\pm 1$ is taken as $\pm 1$: "
                 "the two elbow branches coincide and are returned once (the kernels flag the "
                 "solution singular, "
                 rf"$\lvert\sin\theta_4\rvert$ below {_sci(WRIST_SINGULAR)}). No joint is left free."},
        {"name": r"Shoulder aligned ($\sin\theta_2 = 0$)",
         "text": r"axes 1 and 3 are one line: only $\theta_1 + \theta_3$ ($\theta_2 = 0$) or "
                 r"$\theta_1 - \theta_3$ ($\theta_2 = \pi$) is fixed "
                 rf"($\sqrt{{m_{{13}}^2 + m_{{23}}^2}}$ below {_sci(WRIST_SINGULAR)}). The kernels set "
                 r"$q_1 = 0$, give $\theta_3$ the rest and flag the solution singular; the reference "
                 "solver (derive.reference.ik) takes $q_1$ from q\\_ref when one is given (else 0)."},
        {"name": r"Wrist aligned ($\sin\theta_6 = 0$)",
         "text": r"axes 5 and 7 are one line: only $\theta_5 \pm \theta_7$ is fixed. The kernels set "
                 r"$q_5 = 0$, give $\theta_7$ the rest and flag the solution singular; the reference "
                 "solver takes $q_5$ from q\\_ref (else 0)."},
        {"name": "Wrist centre on axis 1",
         "text": r"the reference plane is undefined ($W_x = W_y = 0$); $a = 0$ is taken (the plane of "
                 r"axis 1 and the canonical $x$ axis), in the solver and in the arm angle alike, so "
                 r"$\psi$ keeps a meaning (there $\psi$ and $q_1$ move the arm the same way)."},
        {"name": "Wrist centre at the shoulder",
         "text": r"$W = 0$, possible only with $d_{se} = d_{ew}$ and the elbow folded: the shoulder "
                 r"rotation is free in three dimensions and there is no arm angle; no solution, with "
                 "its reason."},
    ]
    reach = {
        "text": r"The elbow's $\cos\theta_4$ beyond $\pm 1$ by more than "
                f"{_sci(REACH_TOL)} (the cosine is a ratio, so the tolerance is relative): the wrist "
                r"centre is out of reach for every $\psi$; no solution, with the reason",
        "reasons": [srs_ik.REASON_REACH, srs_ik.REASON_FOLDED],
    }
    return {"kind_name": "SRS class",
            "free": "psi", "free_tex": r"\psi", "intro": intro, "numbers": numbers,
            "relation_text": relation_text, "relation": relation, "table": None,
            "steps": steps, "branch": branch, "singular": singular, "reach": reach}


def _panda_context(robot) -> dict:
    """Class paragraph, numbers, steps and singular sets of a Franka Panda-class arm, after
    :mod:`derive.ik.panda` (He & Liu 2021) and :func:`derive.ik.program7.panda_program`."""
    geo = panda_ik.panda_geometry(robot)
    _, (lo, hi) = free_parameter(robot)
    v = geo.values
    d1, d3, a3, a4, d5, a6, d7 = (v[k] for k in panda_ik.PARAMETERS)
    a_e, b_e = a3 * a4 + d3 * d5, a4 * d3 - a3 * d5
    k_c = a3 ** 2 + d3 ** 2 + a4 ** 2 + d5 ** 2
    r_e = math.hypot(a_e, b_e)
    intro = [
        "The Franka Panda class (Panda, FR3): Franka's modified-DH chain with seven lengths (table "
        "below). Axes 1, 2, 3 meet at the shoulder $S = (0, 0, d_1)$; the elbow offsets $a_3$, "
        "$a_4$ and the wrist offset $a_6$ leave the arm without a spherical wrist, so a pose has a "
        "one-parameter self-motion.",
        "The free parameter is $q_7$, the value of joint 7 (rad), after He and Liu (2021): with "
        "$q_7$ fixed the other six joints are in closed form, with up to 8 solutions. Its range "
        f"is joint 7's limits, [{_num(lo)}, {_num(hi)}] rad; the solutions return $q_7$ as given.",
    ]
    names = {"d1": "d_1", "d3": "d_3", "a3": "a_3", "a4": "a_4", "d5": "d_5", "a6": "a_6", "d7": "d_7"}
    texts = {"d1": "base to shoulder (m)", "d3": "shoulder to elbow along axis 3 (m)",
             "a3": "elbow offset (m)", "a4": "elbow offset (m)", "d5": "elbow to wrist along axis 5 (m)",
             "a6": "wrist offset (m)", "d7": "flange along axis 7 (m)"}
    numbers = [{"name": names[k], "value": _num(v[k]), "text": texts[k]} for k in panda_ik.PARAMETERS]
    table = [("1", "0", "0", _num(d1)), ("2", r"-\pi/2", "0", "0"), ("3", r"\pi/2", "0", _num(d3)),
             ("4", r"\pi/2", _num(a3), "0"), ("5", r"-\pi/2", _num(a4), _num(d5)),
             ("6", r"\pi/2", "0", "0"), ("7", r"\pi/2", _num(a6), "0"), ("flange", "0", "0", _num(d7))]

    def dq_text(d):
        d = np.asarray(d, dtype=float)
        return "I" if np.array_equal(d, np.array([1.0, 0, 0, 0, 0, 0, 0, 0])) else _vector(d)

    relation_text = (
        "The canonical chain is Franka's modified-DH table (Craig: $T_i = R_x(\\alpha_{i-1}) "
        "T_x(a_{i-1}) R_z(q_i) T_z(d_i)$) with the robot's lengths; the robot is related to it by "
        "constant transforms $B$ (base) and $T$ (end frame), unit dual quaternions, $I$ the "
        "identity. The relation reproduces the robot's FK on random configurations with errors "
        f"{_residual_text(geo.error)} (m, rad; below 1e-10 is required).")
    relation = [r"FK_{\mathrm{robot}}(q) = B\, FK_{\mathrm{canonical}}(q)\, T,\quad B = "
                + dq_text(geo.base) + r",\quad T = " + dq_text(geo.tool)]
    steps = [
        {"title": "The pose in the canonical chain's frames",
         "text": "The canonical flange pose, its rotation $R_7$ (columns $x_7, y_7, z_7$) and "
                 "position $p$:",
         "formulas": [r"(R_7, p) = B^{-1} P\, T^{-1}"]},
        {"title": "Frame 6 (eq. F7)",
         "text": r"From $T_7 = T_6 R_x(\pi/2) T_x(a_6) R_z(q_7)$: the origin $O_6$ (also that of "
                 r"frame 5, $a_5 = d_6 = 0$) and the rotation of frame 6, $x_6$ its first column:",
         "formulas": [r"R_6 = R_7\, R_z(-q_7)\, R_x(-\pi/2),\qquad O_6 = p - d_7\, z_7 - a_6\, x_6 = "
                      + _lin([(1, "p"), (-d7, "z_7"), (-a6, "x_6")])]},
        {"title": "The shoulder in frame 6",
         "text": "",
         "formulas": [r"v = R_6^\top (S - O_6),\quad S = " + _vector([0.0, 0.0, d1])]},
        {"title": r"The elbow $q_4$ (eqs. E1, E2; first branch)",
         "text": r"The shoulder in frame 5 seen from the arm side is $(X c_5, -X s_5, Z)$ (E1); "
                 r"$\lVert v \rVert^2 = X^2 + Z^2$ is linear in $c_4 = \cos q_4$, $s_4 = \sin q_4$ (E2), "
                 "with the robot's numbers:",
         "formulas": [r"X = -(a_3 c_4 + d_3 s_4 + a_4) = " + _lin([(-a3, "c_4"), (-d3, "s_4"), (-a4, "")])
                      + r",\quad Z = a_3 s_4 - d_3 c_4 - d_5 = " + _lin([(a3, "s_4"), (-d3, "c_4"), (-d5, "")]),
                      r"A c_4 + B s_4 = K,\quad A = a_3 a_4 + d_3 d_5 = " + _num(a_e)
                      + r",\quad B = a_4 d_3 - a_3 d_5 = " + _num(b_e),
                      r"K = \tfrac{1}{2}\left(\lVert v \rVert^2 - a_3^2 - d_3^2 - a_4^2 - d_5^2\right) = "
                      r"\tfrac{1}{2}\left(\lVert v \rVert^2 - " + _num(k_c) + r"\right)",
                      r"q_4 = \operatorname{atan2}(B, A) \pm \arccos\frac{K}{\sqrt{A^2 + B^2}} = "
                      + _num(math.atan2(b_e, a_e)) + r" \pm \arccos\frac{K}{" + _num(r_e) + "}"]},
        {"title": r"The wrist $q_6$ (eqs. W1, W2; second branch)",
         "text": r"The same point seen from the wrist side is $R_x(\pi/2) R_z(q_6)\, v = "
                 r"(v_x c_6 - v_y s_6,\ -v_z,\ v_x s_6 + v_y c_6)$ (W1); its third row equals $Z(q_4)$ (W2):",
         "formulas": [r"v_x s_6 + v_y c_6 = Z,\qquad q_6 = \operatorname{atan2}(v_x, v_y) \pm "
                      r"\arccos\frac{Z}{\sqrt{v_x^2 + v_y^2}}"]},
        {"title": r"The wrist $q_5$ (eq. W3)",
         "text": r"Rows 1 and 2 of E1 = W1: $X c_5 = v_x c_6 - v_y s_6$, $X s_5 = v_z$:",
         "formulas": [r"q_5 = \operatorname{atan2}\left(\operatorname{sgn}(X)\, v_z,\ "
                      r"\operatorname{sgn}(X)\,(v_x c_6 - v_y s_6)\right)"]},
        {"title": r"The shoulder $q_1, q_2, q_3$ (eqs. S1, S2; third branch)",
         "text": r"The rotation of frame 3, then a ZYZ Euler decomposition $R_3 = (m_{ij})$, the "
                 r"sign that of $\sin q_2$ (the kernels compute $q_3$ from the rounded $q_1, q_2$, "
                 "which equals the formula below):",
         "formulas": [r"R_3 = R_6\, R_z(-q_6)\, R_y(-q_5)\, R_z(-q_4)\, R_x(-\pi/2) = R_z(q_1)\, R_y(q_2)\, R_z(q_3)",
                      r"q_2 = \operatorname{atan2}\left(\pm\sqrt{m_{13}^2 + m_{23}^2},\ m_{33}\right),\quad "
                      r"q_1 = \operatorname{atan2}(\pm m_{23},\ \pm m_{13}),\quad "
                      r"q_3 = \operatorname{atan2}(\pm m_{32},\ \mp m_{31})"]},
        {"title": "The joint values",
         "text": r"$q_1$ to $q_6$ are wrapped to $(-\pi, \pi]$, $q_7$ is the given value; each "
                 f"candidate is checked by the FK (dropped beyond {_sci(ACCEPT_POSITION)} in position or "
                 "rotation) and near-duplicates are merged.",
         "formulas": []},
    ]
    branch = {
        "formula": r"b = 4\, i_4 + 2\, i_6 + i_2",
        "text": r"with $i = 0$ for the + root and 1 for the - root of the elbow ($q_4$, E2), the "
                r"wrist ($q_6$, W2) and the shoulder (the sign of $\sin q_2$).",
    }
    x0 = " or ".join(_num(x) for x in ((0.0, 2 * math.atan2(d3, a3)) if abs(a4 + a3) < 1e-12 else ()))
    axis6 = d5 > math.hypot(a3, d3)
    singular = [
        {"name": "Elbow stretched or folded",
         "text": r"$\lvert K \rvert = \sqrt{A^2 + B^2}$: the two $q_4$ roots coincide (an argument within "
                 f"{_sci(DOUBLE_ROOT)} of $\\pm 1$ is taken as $\\pm 1$) and the pairs merge: "
                 "4 solutions."},
        {"name": r"Shoulder on axis 5 ($X = 0$)",
         "text": r"$a_3 c_4 + d_3 s_4 = -a_4$" + (f" ($q_4$ = {x0} rad)" if x0 else "")
                 + r": axes 3 and 5 are one line through $S$, $q_5$ is free and $q_3$ absorbs it. "
                 r"The kernels set $q_5 = 0$ and flag the solution singular; the reference solver "
                 "(derive.reference.ik) takes $q_5$ from q\\_ref when one is given (else 0)."},
        {"name": r"Shoulder on axis 6 ($v_x = v_y = 0$)",
         "text": r"needs $Z(q_4) = 0$; $q_6$ is free: set to 0 by the kernels, from q\_ref in the "
                 "reference solver, flagged singular."
                 + (r" Impossible for this robot: $\lvert Z \rvert \ge d_5 - \sqrt{a_3^2 + d_3^2} = "
                    + _num(d5 - math.hypot(a3, d3)) + " > 0$." if axis6 else "")},
        {"name": r"Double root of $q_6$ ($c_5 = 0$)",
         "text": r"$\lvert Z \rvert = \sqrt{v_x^2 + v_y^2}$ ($q_5 = \pm\pi/2$): the two $q_6$ roots merge."},
        {"name": r"Axes 1 and 3 aligned ($\sin q_2 = 0$)",
         "text": r"only $q_1 + q_3$ ($q_2 = 0$) or $q_1 - q_3$ ($q_2 = \pi$) is fixed "
                 rf"($\sqrt{{m_{{13}}^2 + m_{{23}}^2}}$ below {_sci(WRIST_SINGULAR)}). The kernels set "
                 r"$q_1 = 0$, give $q_3$ the rest and flag the solution singular; the reference solver "
                 "takes $q_1$ from q\\_ref (else 0)."},
        {"name": "Wrist centre on axis 1",
         "text": r"not singular here: $q_1$ comes from the orientation of frame 3, not from the "
                 r"position of $O_6$."},
    ]
    reach = {
        "text": r"An arccos argument ($K / \sqrt{A^2 + B^2}$ of the elbow, $Z / \sqrt{v_x^2 + v_y^2}$ "
                rf"of $q_6$) beyond $\pm 1$ by more than {_sci(REACH_TOL)} (the arguments are normalised, "
                r"so the tolerance is relative): that branch has no solution for this value of $q_7$; "
                "where none remains, the pose has no solution at this $q_7$, with the reason",
        "reasons": [panda_ik.REASON_ELBOW, panda_ik.REASON_WRIST],
    }
    return {"kind_name": "Franka Panda class", "free": "q7", "free_tex": "q_7", "intro": intro,
            "numbers": numbers, "relation_text": relation_text, "relation": relation,
            "table": table, "steps": steps, "branch": branch, "singular": singular, "reach": reach}


def build_redundant_ik_context(robot, command: str) -> dict:
    """The closed form of a 7R arm with its free parameter (:func:`derive.ik.redundant.redundant_kind`:
    the SRS class after Shimizu et al. 2008 and Faria et al. 2018, :mod:`derive.ik.srs`; the
    Franka Panda class after He & Liu 2021, :mod:`derive.ik.panda`), as the IK programs of
    :mod:`derive.ik.program7` run it, with the class's numbers, the branch numbering
    (:data:`derive.ik.redundant.LABELS`), the singular sets, reachability and a numerical check
    (:func:`_redundant_check`)."""
    robot = load_robot(robot)
    kind = redundant_kind(robot)
    if kind is None:
        raise InputError(f"{robot.name}: not a 7R arm of the Franka Panda or SRS class")
    ctx = _srs_context(robot) if kind == "srs" else _panda_context(robot)
    for k, st in enumerate(ctx["steps"]):
        st["k"] = k + 1
    ctx["joint3"] = _joint3_context(robot) if kind == "srs" else None
    ctx.update({
        "version": __version__, "command": command, "robot": robot.name, "title": robot.title,
        "kind": kind,
        "labels": [{"weight": 4 >> i, "text": t} for i, t in enumerate(LABELS[kind])],
        "sources": SOURCES[kind], "check": _redundant_check(robot, kind),
    })
    return ctx


# --------------------------------------------------------------------------- #
# Three-parallel class (IK-Geo's subproblem decomposition)
# --------------------------------------------------------------------------- #
P3_SOURCES = [("A. J. Elias, J. T. Wen",
               "IK-Geo: Unified robot inverse kinematics using subproblem decomposition",
               "Mechanism and Machine Theory 196, 2024 (arXiv:2211.05737): the solvers "
               "IK_3_parallel_2_intersecting (subproblems 4, 4, 1, 1, 3, 1) and IK_3_parallel "
               "(subproblems 6, 1, 1, 3, 1); the steps here are derive.ik.parallel3's form of them")]


def _p3_check(robot, geo, samples: int = CHECK7_SAMPLES, seed: int = CHECK7_SEED) -> dict:
    """The report's numerical check of the three-parallel closed form
    (:func:`derive.ik.closed_form.solve` with the class's geometry): ``samples`` configurations
    uniform inside the joint limits (numpy ``default_rng(seed)``; +-pi for a joint without
    limits), their poses by the reference FK, as :func:`_check_summary` reports them."""
    from derive.ik.closed_form import solve as closed_solve
    lim = np.asarray(robot.limits, dtype=float)
    lo = np.where(np.isfinite(lim[:, 0]), lim[:, 0], -np.pi)
    hi = np.where(np.isfinite(lim[:, 1]), lim[:, 1], np.pi)
    q = np.random.default_rng(seed).uniform(lo, hi, size=(samples, robot.dof))
    poses = fk(robot, q)
    sols, counts, _, reasons = closed_solve(robot, geo, poses)
    return _check_summary(robot, q, poses, sols, counts, reasons, samples, seed)


def build_parallel3_ik_context(robot, geo, command: str) -> dict:
    """The closed form of a 6R arm of the three-parallel class (:mod:`derive.ik.parallel3`, after
    IK-Geo): the product-of-exponentials numbers of the robot, IK-Geo's steps as the module
    solves them (axes 5 and 6 meeting: subproblems 4, 4, 1, 1, 3, 1; apart: 6, 1, 1, 3, 1), the
    branch numbering, the singular sets, reachability and a numerical check (:func:`_p3_check`).
    Typeset from the geometry, not from extracted equations: the class's closed form is a
    composition of subproblems, which the equation extraction (:mod:`derive.ik.extract`) does
    not find."""
    from derive.ik import parallel3
    robot = load_robot(robot)
    sp6 = geo.layout == "sp6"
    joint = [f"q_{{{geo.order[i] + 1}}}" for i in range(6)]          # the robot's joint of chain axis i
    q1, q2, q3, q4, q5, q6 = joint
    numbers = [{"name": f"h_{{{i + 1}}}", "value": _vector(h), "text": f"unit axis of joint ${joint[i]}$"}
               for i, h in enumerate(geo.h)]
    numbers += [{"name": f"p_{{{i}}}", "value": _vector(v),
                 "text": ("base origin to a point of axis 1 (m)" if i == 0 else
                          "a point of axis 6 to the end frame's origin (m)" if i == 6 else
                          ("point of axis 5 to point of axis 6 (m)" if sp6 else
                           "0: axes 5 and 6 meet at the wrist point") if i == 5 else
                          f"point of axis {i} to point of axis {i + 1} (m)")}
                for i, v in enumerate(geo.p)]
    numbers.append({"name": "d_1", "value": _num(geo.d1),
                    "text": "$h_2^T (p_1 + p_2 + p_3 + p_4)$, the arm's offset along the parallel axes (m)"})
    intro = [
        "Axes 2, 3 and 4 are parallel" + (", axes 5 and 6 do not meet" if sp6 else
                                          " and axes 5 and 6 meet at the wrist point")
        + ": the three-parallel class, solved as IK-Geo's "
        + ("three parallel solver by subproblems 6, 1, 1, 3 and 1" if sp6 else
           "three parallel, two intersecting solver by subproblems 4, 4, 1, 1, 3 and 1")
        + ". The class's closed form is this composition of subproblems (derive.ik.parallel3), "
          "written from the arm's geometry, not extracted from its derived equations.",
        "The arm in the product-of-exponentials form (every number from the robot's own chain at "
        "the zero configuration, base frame; $R(h, q)$ the rotation by $q$ about the unit axis $h$, "
        "$R_i = R(h_i, q_i)$ for the axis $h_i$ of chain position $i$, whose joint is named in the "
        "table):",
    ]
    relation = [r"R = R_1 R_2 R_3 R_4 R_5 R_6\, R_{6T},\qquad t = p_0 + R_1 p_1 + R_1 R_2 p_2 + "
                r"R_1 R_2 R_3 p_3 + R_1 R_2 R_3 R_4 p_4 + R_1 \cdots R_5\, p_5 + R_1 \cdots R_6\, p_6",
                r"R_{6T} = " + _matrix(geo.r6t)]
    relation_text = (f"The form reproduces the robot's FK with errors {_residual_text(geo.error)} "
                     "(m, rad; below 1e-10 is required), with")
    pose = {"title": r"The pose terms",
            "text": r"From the pose $(R, t)$ of the end frame:",
            "formulas": [r"R_{06} = R\, R_{6T}^T,\qquad p_{16} = t - p_0 - R_{06}\, p_6"]}
    q6_theta = [
        {"title": rf"${q6}$ (subproblem 1)",
         "text": r"With $R_t = R(h_1, " + q1 + r")^T R_{06} = R(h_2, " + q2 + " + " + q3 + " + " + q4
                 + r")\, R_5 R_6$, the rotations about $h_2$ fix $h_2$:",
         "formulas": [rf"R(-h_6, {q6})\, \left(R(h_5, {q5})^T h_2\right) = R_t^T h_2"]},
        {"title": rf"$\theta = {q2} + {q3} + {q4}$ (subproblem 1)",
         "text": r"On a unit vector $x$ across $h_2$ (exact also where $" + q6 + r"$ was chosen freely):",
         "formulas": [rf"R(h_2, \theta)\, x = R_t\, R(h_6, {q6})^T R(h_5, {q5})^T x"]},
        {"title": rf"${q3}$ (subproblem 3)",
         "text": "Two roots:",
         "formulas": [r"v = R(h_1, " + q1 + r")^T p_{16} - p_1 - R(h_2, \theta)\, "
                      + (r"\left(p_4 + R(h_5, " + q5 + r")\, p_5\right)" if sp6 else "p_4") + ",",
                      rf"\left\| R(h_2, {q3})\, p_3 + p_2 \right\| = \| v \|"]},
        {"title": rf"${q2}$ (subproblem 1) and ${q4}$",
         "text": "",
         "formulas": [rf"R(h_2, {q2})\, \left(p_2 + R(h_2, {q3})\, p_3\right) = v,\qquad "
                      rf"{q4} = \theta - {q2} - {q3}"]},
    ]
    if sp6:
        first = [{"title": rf"${q1}$ and ${q5}$ (subproblem 6)",
                  "text": "Projected on $h_2$ (the rotations about $h_2$ keep it), two equations in "
                          f"${q1}$ and ${q5}$ with up to 4 solutions, $d_1$ from the table:",
                  "formulas": [rf"h_2^T R(-h_1, {q1})\, p_{{16}} + h_2^T R(h_5, {q5})\, (-p_5) = d_1",
                               rf"h_2^T R(-h_1, {q1})\, R_{{06}} h_6 + h_2^T R(h_5, {q5})\, (-h_6) = 0"]}]
        branch = {"formula": r"k = 2\, i_6 + i_3",
                  "text": (f"$i_6$ (0 to 3) is the solution of subproblem 6, ascending in ${q1}$ (the "
                           "solutions first, then the empty slots); $i_3$ is the root of subproblem 3 "
                           "(0 the first, 1 the second).")}
        singular = [{"name": "subproblem 6 degenerate",
                     "text": "an angle of subproblem 6 is free: the candidate is marked singular."}]
        reasons = [parallel3.REASON_SP6, parallel3.REASON_REACH]
    else:
        first = [{"title": rf"${q1}$ (subproblem 4)",
                  "text": r"The rotations about $h_2$ keep the component along $h_2$; two roots:",
                  "formulas": [rf"h_2^T R(-h_1, {q1})\, p_{{16}} = d_1"]},
                 {"title": rf"${q5}$ (subproblem 4)",
                  "text": r"With $R_t = R(h_1, " + q1 + r")^T R_{06}$; two roots:",
                  "formulas": [rf"h_2^T R(h_5, {q5})\, h_6 = h_2^T R_t\, h_6"]}]
        branch = {"formula": r"k = 4\, i_1 + 2\, i_5 + i_3",
                  "text": (f"$i_1$, $i_5$ and $i_3$ are the roots of the subproblems of ${q1}$, ${q5}$ "
                           f"and ${q3}$ (0 the first, 1 the second).")}
        singular = [{"name": "shoulder",
                     "text": (f"the wrist point (the end of $p_{{16}}$) on axis 1: subproblem 4 of ${q1}$ "
                              f"degenerates and ${q1}$ is free; it is taken from the reference "
                              "configuration when one is given, else 0, and the solution is marked "
                              "singular.")}]
        reasons = [parallel3.REASON_SHOULDER, parallel3.REASON_REACH]
    singular.insert(0, {"name": "wrist",
                        "text": (rf"$R(h_5, {q5})^T h_2$ along $h_6$ (closer than {_sci(WRIST_SINGULAR)}: "
                                 rf"axis 6 parallel to the parallel axes): ${q6}$ and $\theta$ are one "
                                 rf"rotation about $h_2$ and ${q6}$ is free, from the reference "
                                 "configuration when one is given, else 0; the solution is marked singular.")})
    steps = [pose] + first + q6_theta
    for k, st in enumerate(steps):
        st["k"] = k + 1
    return {
        "version": __version__, "command": command, "robot": robot.name, "title": robot.title,
        "layout": geo.layout, "sp6": sp6, "intro": intro, "numbers": numbers,
        "relation_text": relation_text, "relation": relation, "steps": steps, "branch": branch,
        "singular": singular,
        "reach": {"text": "A branch is dropped where a subproblem has no exact solution; where none "
                          "remains the pose has no solution, with the reason", "reasons": reasons},
        "check": _p3_check(robot, geo), "sources": P3_SOURCES,
    }
