"""Speed of the generated kernels against plain matrix code and the peers (``dq-derive bench kernels``).

Measured on the same poses in the same run:

* every backend through ``derive.kernels`` (FK and IK, batch of n and single calls);
* a C harness (``derive/data/bench_harness.c``) compiled with the C backend's flags: the
  generated FK/IK batch and single-pose functions, and plain 4x4 homogeneous-matrix FK written in
  the harness (standard DH, libm sin/cos);
* when installed (the optional ``bench`` extra): Pinocchio's ``forwardKinematics`` called in a
  Python loop, EAIK's ``IK_batched`` and IK-Geo's ``get_ik`` (UR robots, standard DH); for a
  spherical-wrist arm EAIK's ``HPRobot`` built from the robot's axes and py-opw-kinematics'
  ``inverse`` (all solutions, one pose per call) on the same poses;
* exactness at the wrist singularity (theta5 = 0 of the UR; the wrist angle of the canonical chain
  0 for a spherical-wrist arm): for poses of configurations with theta5 = 0, how
  many poses each tool solves exactly (a returned solution with residual < 1e-10) and how many
  returned solutions are only approximate.

Not a test: the numbers go to docs/benchmarks.md.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np
import sympy as sp

from derive import reference
from derive.algebra import dualquat as dq
from derive.algebra import quaternion as quat
from derive.bench.machine import best_time as _time
from derive.bench.machine import machine
from derive.bench.general6r import bench_general, general_report, is_general
from derive.bench.redundant import bench_redundant, redundant_report
from derive.codegen.emit import identifier
from derive.codegen.loader import c_compiler, c_flags, kernel_folder, kernels
from derive.errors import DeriveError
from derive.ik.closed_form import spherical_class
from derive.ik.redundant import redundant_kind
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot
from derive.symbolic.chain import chain_from_robot

EXACT = 1e-10


def dh_table(robot) -> np.ndarray:
    """(d, a, alpha) per joint of a standard-DH robot (from its transforms after the joint)."""
    r = load_robot(robot)
    if r.convention != "standard_dh":
        raise DeriveError(f"{r.name}: the matrix baseline needs a standard-DH description")
    return np.array([[j.post[0].vector[2], j.post[1].vector[0], j.post[2].angle] for j in r.joints])


def _harness(robot: str, q: np.ndarray, poses: np.ndarray, repeats: int) -> dict:
    compiler = c_compiler()
    if compiler is None:
        return {"error": "no C compiler"}
    ident = identifier(load_robot(robot).name)     # a file's robot too, not its path
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        folder, manifest = kernel_folder(robot)      # the shipped or cached sources: no derivation
        for name in manifest["files"].values():
            shutil.copy(folder / name, tmp / name)
        src = resources.files("derive.data").joinpath("bench_harness.c").read_text()
        (tmp / "harness.c").write_text(src)
        try:
            dh = dh_table(robot)
        except DeriveError:          # not standard DH: the harness's matrix FK has no table
            dh = None
        (np.zeros((6, 3)) if dh is None else dh).astype(np.float64).tofile(tmp / "dh.bin")
        np.ascontiguousarray(q).tofile(tmp / "q.bin")
        np.ascontiguousarray(poses).tofile(tmp / "poses.bin")
        exe = tmp / "harness"
        cmd = [compiler, *c_flags(), f"-DPREFIX={ident}", "-o", str(exe), str(tmp / "harness.c"),
               str(tmp / f"{ident}_kinematics.c"), "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            return {"error": res.stderr}
        run = subprocess.run([str(exe), str(len(q)), str(repeats), str(tmp / "dh.bin"), str(tmp / "q.bin"),
                              str(tmp / "poses.bin"), str(tmp / "mat.bin")],
                             capture_output=True, text=True, check=True)
        out = json.loads(run.stdout)
        mat = np.fromfile(tmp / "mat.bin").reshape(-1, 4, 4)
        if dh is None:
            out.pop("matrix_fk_ns", None)
        else:
            out["matrix_fk_max_error"] = float(np.abs(mat - reference.fk_matrix(robot, q)).max())
        out["flags"] = " ".join(c_flags())
        return out


def _residual_ok(robot, sols, poses) -> np.ndarray:
    """(n, k) bool: solution k of pose i reproduces the pose within EXACT (NaN rows False)."""
    n, k, _ = sols.shape
    flat = sols.reshape(-1, 6)
    ok = np.zeros(n * k, dtype=bool)
    valid = ~np.isnan(flat[:, 0])
    if valid.any():
        dpos, drot = reference.pose_error(reference.fk(robot, flat[valid]),
                                          np.repeat(poses, k, axis=0)[valid])
        ok[valid] = (dpos < EXACT) & (drot < EXACT)
    return ok.reshape(n, k)


def _pinocchio_fk(robot, q, limit):
    try:
        import pinocchio as pin
    except ImportError:
        return None
    dh = dh_table(robot)
    model = pin.Model()
    parent = 0
    placement = pin.SE3.Identity()
    for i, (d, a, al) in enumerate(dh):
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{i + 1}")
        placement = (pin.SE3(np.eye(3), np.array([0.0, 0.0, d])) * pin.SE3(np.eye(3), np.array([a, 0.0, 0.0]))
                     * pin.SE3(pin.utils.rotate("x", al), np.zeros(3)))
    end = placement
    data = model.createData()
    m = min(limit, len(q))

    def run():
        for row in q[:m]:
            pin.forwardKinematics(model, data, row)

    t = _time(run, 3) / m
    pin.forwardKinematics(model, data, q[0])
    mat = (data.oMi[6] * end).homogeneous
    err = float(np.abs(mat - reference.fk_matrix(robot, q[0])).max())
    return {"fk_loop_ns": t * 1e9, "n": m, "max_error": err, "version": pin.__version__}


def _eaik(robot, mats):
    try:
        from eaik.IK_DH import DhRobot
    except ImportError:
        return None
    dh = dh_table(robot)
    bot = DhRobot(dh[:, 2], dh[:, 1], dh[:, 0])
    t = time.perf_counter()
    res = bot.IK_batched(mats, 1)              # one thread, as ours
    batch = (time.perf_counter() - t) / len(mats)
    t = time.perf_counter()
    for m in mats[:2000]:
        bot.IK(m)
    single = (time.perf_counter() - t) / min(2000, len(mats))
    sols = np.full((len(mats), 8, 6), np.nan)
    approx = 0
    for i, r in enumerate(res):
        k = r.num_solutions()
        if k:
            sols[i, :k] = r.Q[:k]
            approx += int(np.sum(r.is_LS[:k]))
    return {"batch_ns": batch * 1e9, "single_ns": single * 1e9, "sols": sols, "flagged_ls": approx}


def _eaik_hp(robot, mats, threads: int = 1):
    """EAIK's HPRobot of a spherical-wrist arm from its numeric axes and axis points at zero
    (H the axes, P the vectors between consecutive points, the last to the end frame; EAIK's end
    frame has the base orientation at zero, so the poses' rotations are turned by R0^T)."""
    try:
        from eaik.IK_HP import HPRobot
    except ImportError:
        return None
    ch = numeric_chain(robot)
    pts = ch.start + np.vstack([np.zeros(3), np.cumsum(ch.links, axis=0)])
    t0 = reference.fk_matrix(robot, np.zeros(6))
    P = np.vstack([pts[0], np.diff(pts[:6], axis=0), t0[:3, 3] - pts[5]])
    bot = HPRobot(np.array(ch.axes, dtype=float), P)
    me = np.array(mats, dtype=float)
    me[:, :3, :3] = me[:, :3, :3] @ t0[:3, :3].T
    t = time.perf_counter()
    res = bot.IK_batched(me, threads)
    batch = (time.perf_counter() - t) / len(me)
    t = time.perf_counter()
    for m in me[:2000]:
        bot.IK(m)
    single = (time.perf_counter() - t) / min(2000, len(me))
    sols = np.full((len(me), 8, 6), np.nan)
    approx = 0
    for i, r in enumerate(res):
        Q = np.asarray(r.Q, dtype=float).reshape(-1, 6)[:8]
        ls = np.asarray(r.is_LS, dtype=bool).reshape(-1)[:8]
        sols[i, :len(Q)] = Q
        approx += int(ls.sum())
    return {"batch_ns": batch * 1e9, "single_ns": single * 1e9, "sols": sols, "flagged_ls": approx,
            "threads": threads}


def _py_opw(geo, poses, limit: int = 5000):
    """py-opw-kinematics (Rust, from Python) on the canonical chain's poses: its ``inverse``
    returns every solution of one pose; timed over ``limit`` poses."""
    try:
        import py_opw_kinematics as opw
        from scipy.spatial.transform import RigidTransform
    except ImportError:
        return None
    model = opw.KinematicModel(**{k: float(v) for k, v in geo.values.items()},
                               offsets=(0.0,) * 6, flip_axes=(False,) * 6)
    bot = opw.Robot(model, degrees=False)
    canon = geo.into_canonical(poses[:limit])
    mats = dq.to_matrix(canon)
    tf = [RigidTransform.from_matrix(m) for m in mats]
    t = time.perf_counter()
    out = [bot.inverse(x) for x in tf]
    single = (time.perf_counter() - t) / len(tf)
    return {"single_ns": single * 1e9, "n": len(tf), "mean_solutions": float(np.mean([len(o) for o in out]))}


def _ikgeo(robot, mats):
    try:
        import ik_geo
    except ImportError:
        return None
    chain = chain_from_robot(robot)
    vals = chain.parameters
    axes = [[float(sp.sympify(v).subs(vals)) for v in j.axis] for j in chain.joints]
    links = [[0.0, 0.0, 0.0]] + [[float(sp.sympify(v).subs(vals)) for v in j.link] for j in chain.joints]
    # IK-Geo's solvers for intersecting wrist axes want p_56 = 0: an offset along h6 commutes
    # with the rotation about h6, so it moves to the tool vector p_6T (same end point)
    if np.allclose(np.cross(links[5], axes[5]), 0.0):
        links[6] = list(np.add(links[6], links[5]))
        links[5] = [0.0, 0.0, 0.0]
    gq, gt = chain.end_transform
    rg = quat.to_matrix(np.array([float(sp.sympify(v).subs(vals)) for v in gq]))
    gt = np.array([float(sp.sympify(v).subs(vals)) for v in gt])
    bot = ik_geo.Robot.three_parallel_two_intersecting(axes, links)
    sols = np.full((len(mats), 8, 6), np.nan)
    t = time.perf_counter()
    # ik_geo takes (and its forward_kinematics returns) the rotation as a list of columns
    # (the chain end is the robot end times G^-1)
    out = [bot.get_ik((m[:3, :3] @ rg.T).T.tolist(), (m[:3, 3] - m[:3, :3] @ rg.T @ gt).tolist())
           for m in mats]
    single = (time.perf_counter() - t) / len(mats)
    flagged = 0
    for i, res in enumerate(out):
        for k, (qq, is_ls) in enumerate(res[:8]):
            sols[i, k] = qq
            flagged += bool(is_ls)
    return {"single_ns": single * 1e9, "sols": sols, "flagged_ls": flagged}


def bench_kernels(robot: str = "ur5", n: int = 100_000, repeats: int = 5, seed: int = 0,
                  singular: int = 2000) -> dict:
    if redundant_kind(robot) is not None:
        return bench_redundant(robot, repeats)
    if is_general(robot):                  # a general 6R arm: its own benchmark (vs ssik)
        return bench_general(robot, repeats=repeats, seed=seed)
    rng = np.random.default_rng(seed)
    geo = spherical_class(robot)
    q = rng.uniform(-np.pi, np.pi, size=(n, 6))
    poses = reference.fk(robot, q)
    mats = reference.fk_matrix(robot, q)
    out: dict = {"robot": robot, "n": n, "machine": machine(), "date": time.strftime("%Y-%m-%d")}
    for backend in ("c", "numpy", "python"):
        k = kernels(robot, backend)
        m = n if backend != "python" else n // 20
        k.fk(q[:10])
        k.ik(poses[:10])
        out[backend] = {"fk_batch_ns": _time(lambda: k.fk(q[:m]), repeats if backend != "python" else 1) / m * 1e9,
                        "ik_batch_ns": _time(lambda: k.ik(poses[:m]), repeats if backend != "python" else 1) / m * 1e9}
        s = 2000
        rep = max(repeats, 3) if backend == "c" else 1   # single calls: the noisiest figure
        out[backend]["fk_single_ns"] = _time(lambda: [k.fk(row) for row in q[:s]], rep) / s * 1e9
        out[backend]["ik_single_ns"] = _time(lambda: [k.ik(row) for row in poses[:s]], rep) / s * 1e9
        if backend == "c" and k.has_ik:
            # the same poses as 4x4 matrices (converted and checked in C by the extension)
            k.ik(mats[:10])
            out[backend]["ik_batch_matrix_ns"] = _time(lambda: k.ik(mats), repeats) / n * 1e9
    k = kernels(robot, "c")
    if k.has_ik:
        seeds = q + 0.01
        k.nearest(poses[:10], seeds[:10])
        out["c"]["nearest_batch_ns"] = _time(lambda: k.nearest(poses, seeds), repeats) / n * 1e9
        chunks = [poses[i:i + 1000] for i in range(0, n - 999, 1000)]
        out["c"]["ik_batch_chunked_ns"] = _time(lambda: [k.ik(c) for c in chunks], repeats) / (1000 * len(chunks)) * 1e9
    out["harness"] = _harness(robot, q, poses, repeats)
    pin = _pinocchio_fk(robot, q, 20_000) if load_robot(robot).convention == "standard_dh" else None
    if pin:
        out["pinocchio"] = pin
    # IK peers on the same poses (a subset for the slow ones) and the wrist-singular set
    qs = rng.uniform(-np.pi, np.pi, size=(singular, 6))
    qs[:, 4] = 0.0 if geo is None else -geo.signs[4] * geo.offsets[4]
    spose = reference.fk(robot, qs)
    smats = reference.fk_matrix(robot, qs)
    ours_s, ours_c = kernels(robot, "c").ik(spose)
    exact_ours = _residual_ok(robot, ours_s, spose)
    out["singular"] = {"n": singular, "ours": {"exact_poses": int(exact_ours.any(axis=1).sum()),
                                              "approximate_solutions": int((~exact_ours & ~np.isnan(ours_s[..., 0])).sum())}}
    m_peer = min(n, 20_000)
    if geo is not None:
        return _spherical_peers(out, robot, geo, poses, mats, spose, smats, m_peer)
    ea = _eaik(robot, mats[:m_peer])
    if ea:
        out["eaik"] = {k: v for k, v in ea.items() if k != "sols"} | {"n": m_peer}
        es = _eaik(robot, smats)
        ok = _residual_ok(robot, es["sols"], spose)
        out["singular"]["eaik"] = {"exact_poses": int(ok.any(axis=1).sum()),
                                   "approximate_solutions": int((~ok & ~np.isnan(es["sols"][..., 0])).sum()),
                                   "flagged_ls": es["flagged_ls"]}
    ig = _ikgeo(robot, mats[:m_peer])
    if ig:
        ok = _residual_ok(robot, ig["sols"], poses[:m_peer])
        out["ikgeo"] = {"single_ns": ig["single_ns"], "n": m_peer,
                        "exact_fraction": float(ok.any(axis=1).mean())}
        gs = _ikgeo(robot, smats)
        ok = _residual_ok(robot, gs["sols"], spose)
        out["singular"]["ikgeo"] = {"exact_poses": int(ok.any(axis=1).sum()),
                                    "approximate_solutions": int((~ok & ~np.isnan(gs["sols"][..., 0])).sum()),
                                    "flagged_ls": gs["flagged_ls"]}
    return out


def _spherical_peers(out, robot, geo, poses, mats, spose, smats, m_peer) -> dict:
    """EAIK (HPRobot, batched with 1 thread, and single calls) and py-opw-kinematics on the
    poses of a spherical-wrist arm; EAIK's exactness on the wrist-singular set."""
    ea = _eaik_hp(robot, mats[:m_peer])
    if ea:
        ok = _residual_ok(robot, ea["sols"], poses[:m_peer])
        out["eaik"] = {k: v for k, v in ea.items() if k != "sols"} | {
            "n": m_peer, "exact_fraction": float(ok.any(axis=1).mean())}
        es = _eaik_hp(robot, smats)
        ok = _residual_ok(robot, es["sols"], spose)
        out["singular"]["eaik"] = {"exact_poses": int(ok.any(axis=1).sum()),
                                   "approximate_solutions": int((~ok & ~np.isnan(es["sols"][..., 0])).sum()),
                                   "flagged_ls": es["flagged_ls"]}
    po = _py_opw(geo, poses)
    if po:
        out["py_opw"] = po
    return out


def report(r: dict) -> str:
    if r.get("kind") == "redundant":
        return redundant_report(r)
    if r.get("kind") == "general6r":
        return general_report(r)
    h = r["harness"]
    lines = [f"generated kernels of {r['robot']}, {r['n']} poses, {r['machine']}, {r['date']}",
             f"C flags: {h.get('flags', '?')}",
             "per pose (ns)          FK batch   FK single   IK batch   IK single"]
    if "error" not in h:
        lines.append(f"  C, pure C harness   {h['fk_batch_ns']:9.1f} {h['fk_single_ns']:10.1f} "
                     f"{h['ik_batch_ns']:10.1f} {h['ik_single_ns']:10.1f}")
    for b in ("c", "numpy", "python"):
        x = r[b]
        lines.append(f"  {b:<6} via kernels()  {x['fk_batch_ns']:9.1f} {x['fk_single_ns']:10.1f} "
                     f"{x['ik_batch_ns']:10.1f} {x['ik_single_ns']:10.1f}")
    if "ik_batch_matrix_ns" in r["c"]:
        x = r["c"]
        lines.append(f"IK batch with 4x4 matrices (converted in C) via kernels(): {x['ik_batch_matrix_ns']:.1f} ns per "
                     f"pose ({100 * (x['ik_batch_matrix_ns'] / x['ik_batch_ns'] - 1):+.0f} % on dual quaternions)")
    if "error" not in h and "nearest_batch_ns" in h:
        lines.append(f"IK batch in chunks of 1000 poses (output in cache): C harness {h['ik_batch_chunked_ns']:.1f}, "
                     f"via kernels() {r['c'].get('ik_batch_chunked_ns', float('nan')):.1f} ns per pose")
        if "fk_batch_chunked_ns" in h:
            lines.append(f"in chunks of 1000 poses, C harness: FK batch {h['fk_batch_chunked_ns']:.1f} ns per pose, "
                         f"nearest {h['nearest_batch_chunked_ns']:.1f} ns per pose "
                         f"({100 * (h['nearest_batch_chunked_ns'] / h['ik_batch_chunked_ns'] - 1):+.0f} % on the "
                         "IK batch in chunks)")
        lines.append(f"nearest solution to a seed (IK + selection, one batch): C harness {h['nearest_batch_ns']:.1f}, "
                     f"via kernels() {r['c'].get('nearest_batch_ns', float('nan')):.1f} ns per pose "
                     f"({100 * (h['nearest_batch_ns'] / h['ik_batch_ns'] - 1):+.0f} % on the C IK batch)")
    if "error" not in h and "matrix_fk_ns" in h:
        lines.append(f"plain 4x4-matrix C FK: {h['matrix_fk_ns']:.1f} ns per pose "
                     f"(max error {h['matrix_fk_max_error']:.1e}); generated C FK batch is "
                     f"{h['matrix_fk_ns'] / h['fk_batch_ns']:.1f}x faster")
    if "pinocchio" in r:
        p = r["pinocchio"]
        lines.append(f"Pinocchio {p['version']} forwardKinematics in a Python loop: {p['fk_loop_ns']:.0f} ns per "
                     f"pose ({p['fk_loop_ns'] / r['c']['fk_batch_ns']:.0f}x the C kernel via kernels())")
    if "eaik" in r:
        e = r["eaik"]
        lines.append(f"EAIK IK_batched (1 thread): {e['batch_ns']:.0f} ns per pose, single IK {e['single_ns']:.0f} ns "
                     f"({e['batch_ns'] / h.get('ik_batch_ns', float('nan')):.0f}x the C IK batch)"
                     + (f", an exact solution for {100 * e['exact_fraction']:.2f} % of the poses"
                        if "exact_fraction" in e else ""))
    if "py_opw" in r:
        o = r["py_opw"]
        lines.append(f"py-opw-kinematics inverse (all solutions, one pose per call from Python): "
                     f"{o['single_ns']:.0f} ns per pose, {o['mean_solutions']:.2f} solutions per pose "
                     f"({o['single_ns'] / r['c']['ik_single_ns']:.1f}x our C single call via kernels())")
    if "ikgeo" in r:
        g = r["ikgeo"]
        lines.append(f"IK-Geo get_ik (Python loop): {g['single_ns']:.0f} ns per pose; exact solution found for "
                     f"{100 * g['exact_fraction']:.2f} % of random poses "
                     f"({g['single_ns'] / h.get('ik_single_ns', float('nan')):.0f}x the C single-pose IK)")
    s = r["singular"]
    lines.append(f"wrist singularity (theta5 = 0), {s['n']} poses: poses solved exactly / approximate solutions")
    for tool in ("ours", "eaik", "ikgeo"):
        if tool in s:
            lines.append(f"  {tool:<6} {s[tool]['exact_poses']:6d} / {s[tool]['approximate_solutions']}")
    return "\n".join(lines)
