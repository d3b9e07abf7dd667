"""Speed of the generated IK kernels of a 7-joint arm with one free parameter (``dq-derive bench
kernels --robot panda|fr3|iiwa7|iiwa14``) against the peers, on the same poses in the same run,
one thread.

Poses: random configurations inside the joint limits (numpy ``default_rng(seed)``), their FK;
the free value of a pose is the generating configuration's (q7 for the Panda class, the arm
angle :func:`derive.ik.srs.arm_angle` for the SRS class). Measured, best of ``repeats``:

* a C harness (``derive/data/bench_harness7.c``) compiled with the C backend's flags: the
  generated IK batch (one free value per pose, all solutions) in calls of 1000 poses and in one
  call of n, the single-pose IK in a loop, and a sweep of 16 values of the free parameter per
  pose (the batch on 16 rows per pose; the values are the feasible ones of ``ik_sweep`` on
  ``sweep_poses`` poses, tiled to ``n_sweep`` poses);
* the C kernel through ``derive.kernels``: the batch, one pose per call from Python, and
  ``ik_sweep(P, 16)`` (which includes the computation of the feasible range);
* peers when importable: frankik's ``ik_full`` (Panda, FR3; the flange pose and q7, one call per
  pose), EAIK's ``HPRobot`` with one joint locked (Panda class: joint 7 locked at 0 and the pose
  turned back by q7, so one robot serves all poses; SRS: joint 3 locked at the generating value,
  one robot built per pose, the build timed apart), ssik's prebuilt arm (its default
  ``solve(T)``, and ``self_motion(T)`` evaluated at the free value; see :func:`_ssik`).

For every tool: on how many poses its solutions include the generating configuration (every
joint within GEN_TOL rad, angles compared modulo 2 pi).

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

from derive import reference
from derive.bench.machine import best_time as _time
from derive.bench.machine import machine
from derive.codegen.loader import c_compiler, c_flags, kernel_folder, kernels
from derive.ik import srs
from derive.ik.redundant import redundant_kind
from derive.model.geometry import numeric_chain
from derive.model.robot import load_robot

#: A returned solution "is" the generating configuration when every joint is this close (rad).
GEN_TOL = 1e-6
#: A returned solution is exact when its FK matrix matches the pose's within this.
EXACT = 1e-10
#: Values of the free parameter per pose in the sweep.
SWEEP = 16


def _found(sols: np.ndarray, q: np.ndarray) -> int:
    """Poses whose solutions (n, k, 7), NaN-padded, include q (n, 7) within GEN_TOL modulo 2 pi."""
    d = np.abs(np.angle(np.exp(1j * (sols - q[:, None, :])))).max(axis=2)
    return int((np.where(np.isnan(d), np.inf, d).min(axis=1) < GEN_TOL).sum())


def _exact(robot, sols: np.ndarray, mats: np.ndarray) -> float:
    """Mean number per pose of returned solutions (n, k, 7) whose FK matches the pose matrix
    (n, 4, 4) within EXACT (every entry)."""
    n, k, _ = sols.shape
    ok = ~np.isnan(sols[..., 0])
    if not ok.any():
        return 0.0
    err = np.abs(reference.fk_matrix(robot, sols[ok]) - np.repeat(mats, k, axis=0)[ok.ravel()]).max(axis=(1, 2))
    return float((err < EXACT).sum() / n)


def instruction_set() -> str:
    """The widest x86 vector extension of this CPU (what -march=native compiles for)."""
    flags: set = set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith(("flags", "Features")):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    for name, label in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"), ("sse4_2", "SSE4.2")):
        if name in flags:
            return label + (" + FMA" if "fma" in flags else "")
    return "unknown (no /proc/cpuinfo flags)"


def _harness(robot, poses, fv, sweep_free, n_sweep: int, repeats: int) -> dict:
    compiler = c_compiler()
    if compiler is None:
        return {"error": "no C compiler"}
    folder, manifest = kernel_folder(robot)
    ident = manifest["prefix"]
    reps = -(-n_sweep // len(sweep_free))
    sp_poses = np.tile(poses[:len(sweep_free)], (reps, 1))[:n_sweep]
    sp_free = np.tile(sweep_free, (reps, 1))[:n_sweep]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = manifest["files"]["c_source"]
        for name in manifest["files"].values():
            shutil.copy(folder / name, tmp / name)
        (tmp / "harness7.c").write_text(resources.files("derive.data").joinpath("bench_harness7.c").read_text())
        for name, arr in (("poses", poses), ("fv", fv), ("sweep_poses", sp_poses), ("sweep_fv", sp_free)):
            np.ascontiguousarray(arr, dtype=np.float64).tofile(tmp / f"{name}.bin")
        exe = tmp / "harness7"
        cmd = [compiler, *c_flags(), f"-DPREFIX={ident}", "-o", str(exe), str(tmp / "harness7.c"),
               str(tmp / src), "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            return {"error": res.stderr}
        run = subprocess.run([str(exe), str(len(poses)), str(repeats), str(tmp / "poses.bin"), str(tmp / "fv.bin"),
                              str(n_sweep), str(SWEEP), str(tmp / "sweep_poses.bin"), str(tmp / "sweep_fv.bin")],
                             capture_output=True, text=True, check=True)
        out = json.loads(run.stdout)
    out["n_sweep"] = n_sweep
    out["flags"] = " ".join(c_flags())
    return out


def _frankik(robot, q, mats, n: int, repeats: int):
    """frankik's ik_full (up to 4 solutions; flange pose, q7 given) one pose per call."""
    try:
        import frankik
    except ImportError:
        return {"missing": "frankik not importable"}
    if robot not in ("panda", "fr3"):
        return None
    fr3 = robot == "fr3"
    m = mats[:n]
    q7 = q[:n, 6]
    full = lambda: [frankik.ik_full(m[i], None, float(q7[i]), fr3) for i in range(n)]  # noqa: E731
    t_full = _time(full, repeats) / n
    sols = np.array(full())
    one = lambda: [frankik.ik(m[i], None, float(q7[i]), fr3) for i in range(n)]  # noqa: E731
    t_one = _time(one, repeats) / n
    lo, hi = np.array(frankik.q_min_fr3 if fr3 else frankik.q_min_panda), np.array(frankik.q_max_fr3 if fr3 else frankik.q_max_panda)
    inside = ((q[:n] >= lo) & (q[:n] <= hi)).all(axis=1)
    ok = ~np.isnan(sols[..., 0])
    flat = sols[ok]
    err = np.abs(reference.fk_matrix(robot, flat) - np.repeat(m, sols.shape[1], axis=0)[ok.ravel()]).max(axis=(1, 2)) if len(flat) else np.zeros(0)
    d = np.abs(np.angle(np.exp(1j * (sols - q[:n, None, :])))).max(axis=2)
    missed = np.where(np.isnan(d), np.inf, d).min(axis=1) >= GEN_TOL
    q4_other = missed & ~(np.abs(sols[..., 3] - q[:n, None, 3]) < GEN_TOL).any(axis=1) & ok.any(axis=1)
    return {"version": frankik.__version__, "n": n, "full_s": t_full, "one_s": t_one,
            "exact": _exact(robot, sols, m), "missed_other_q4": int(q4_other.sum()),
            "found": _found(sols, q[:n]), "inside_own_limits": int(inside.sum()),
            "found_inside": _found(sols[inside], q[:n][inside]),
            "solutions": float(ok.sum(axis=1).mean()), "no_solution": int((~ok.any(axis=1)).sum()),
            "max_fk_error": float(err.max()) if len(err) else 0.0}


def _hp(robot):
    """EAIK's H (7, 3) and P (8, 3) of a 7R arm from its axes and axis points at zero, and the end
    frame at zero in EAIK's convention (the base orientation)."""
    ch = numeric_chain(robot)
    pts = ch.start + np.vstack([np.zeros(3), np.cumsum(ch.links, axis=0)])
    t0 = reference.fk_matrix(robot, np.zeros(7))
    H = np.array(ch.axes, dtype=float)
    P = np.vstack([pts[0], np.diff(pts[:7], axis=0), t0[:3, 3] - pts[6]])
    return H, P, pts, t0


def _rotation(h, angle):
    """(n, 3, 3) rotations by angle (n,) about the unit axis h (3,)."""
    k = np.array([[0.0, -h[2], h[1]], [h[2], 0.0, -h[0]], [-h[1], h[0], 0.0]])
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def _eaik(robot, kind, q, mats, n: int, repeats: int):
    try:
        from eaik.IK_HP import HPRobot
    except ImportError:
        return {"missing": "eaik not importable"}
    H, P, pts, t0 = _hp(robot)
    me = np.array(mats[:n], dtype=float)
    me[:, :3, :3] = me[:, :3, :3] @ t0[:3, :3].T
    sols = np.full((n, 8, 7), np.nan)
    ls = 0
    if kind == "panda":
        # joint 7 locked at 0: e1..e6 M0 = T M0^-1 e7(-q7) M0, e7 the rotation about h7 at p7
        m0 = np.eye(4)
        m0[:3, 3] = t0[:3, 3]
        g = np.tile(np.eye(4), (n, 1, 1))
        r = _rotation(H[6], -q[:n, 6])
        g[:, :3, :3] = r
        g[:, :3, 3] = pts[6] - r @ pts[6]
        me = me @ np.linalg.inv(m0) @ g @ m0
        bot = HPRobot(H, P, fixed_axes=[(6, 0.0)])
        batch = _time(lambda: bot.IK_batched(me, 1), repeats) / n
        single = _time(lambda: [bot.IK(x) for x in me], repeats) / n
        for i, res in enumerate(bot.IK_batched(me, 1)):
            Q = np.asarray(res.Q, dtype=float).reshape(-1, 7)[:8]
            sols[i, :len(Q)] = Q
            sols[i, :len(Q), 6] = q[i, 6]
            ls += int(np.asarray(res.is_LS, dtype=bool).reshape(-1)[:8].sum())
        return {"n": n, "lock": "joint 7 at q7 (pose turned back by q7, one robot)", "batch_s": batch,
                "single_s": single, "found": _found(sols, q[:n]), "flagged_ls": ls,
                "family": bot.getKinematicFamily(), "exact": _exact(robot, sols, mats[:n]), "solutions": float((~np.isnan(sols[..., 0])).sum(axis=1).mean())}
    # SRS: joint 3 locked at the generating value, one robot per pose
    build = _time(lambda: [HPRobot(H, P, fixed_axes=[(2, float(q[i, 2]))]) for i in range(n)], repeats) / n
    bots = [HPRobot(H, P, fixed_axes=[(2, float(q[i, 2]))]) for i in range(n)]
    single = _time(lambda: [b.IK(x) for b, x in zip(bots, me)], repeats) / n
    for i, (b, x) in enumerate(zip(bots, me)):
        res = b.IK(x)
        Q = np.asarray(res.Q, dtype=float).reshape(-1, 7)[:8]
        sols[i, :len(Q)] = Q
        ls += int(np.asarray(res.is_LS, dtype=bool).reshape(-1)[:8].sum())
    return {"n": n, "lock": "joint 3 at its generating value (one robot built per pose)", "build_s": build,
            "single_s": single, "found": _found(sols, q[:n]), "flagged_ls": ls,
            "family": bots[0].getKinematicFamily(), "exact": _exact(robot, sols, mats[:n]), "solutions": float((~np.isnan(sols[..., 0])).sum(axis=1).mean())}


#: ssik's prebuilt arm of each of our robots (the flange frame, no hand, as ours: checked at run time).
SSIK_ARMS = {"panda": "franka_panda_ik", "fr3": "fr3_ik", "iiwa14": "iiwa14_ik", "iiwa7": "iiwa7_ik"}


def _pad(rows: list, width: int = 0) -> np.ndarray:
    """(n, k, 7) NaN-padded from a list of (k_i, 7) arrays."""
    k = max([width] + [len(x) for x in rows]) or 1
    out = np.full((len(rows), k, 7), np.nan)
    for i, x in enumerate(rows):
        if len(x):
            out[i, :len(x)] = x
    return out


def _ssik(robot, kind, q, mats, n: int, repeats: int, ours_counts=None):
    """ssik's prebuilt arm (``Manipulator.from_prebuilt``), one pose per call: (a) its default
    ``solve(T)`` (every in-limits solution it enumerates: for the spherical-shoulder class one
    per in-limits arc of q7 per branch, at the arc centre; for SRS a grid of 16 swivel values);
    (b) the given-free-value route: ``self_motion(T)`` (the closed-form charts) and every chart
    evaluated at the value, ``chart.q(t)`` (NaN where the branch does not exist; limits not
    applied, as ours). The value is q7 itself for the Panda class (ssik's coordinate is the last
    joint); for SRS our arm angle, mapped onto ssik's swivel per chart (below; the values are
    computed before the timing). Poses: ssik's frames are ours (base and flange, no hand)."""
    try:
        import ssik
    except ImportError:
        return {"missing": "ssik not installed (import ssik fails)"}
    name = SSIK_ARMS.get(robot)
    if name is None:
        return {"missing": f"ssik {ssik.__version__}: no prebuilt arm for {robot}"}
    man = ssik.Manipulator.from_prebuilt(name)
    m, qn = mats[:n], q[:n]
    reps = min(repeats, 3)
    fk_err = float(max(np.abs(man.fk(qn[i]) - m[i]).max() for i in range(min(n, 200))))
    lims = np.array([(-np.inf, np.inf) if x is None else x for x in man.joint_limits], dtype=float)
    inside = ((qn >= lims[:, 0]) & (qn <= lims[:, 1])).all(axis=1)

    solve = lambda: [man.solve(m[i]) for i in range(n)]  # noqa: E731
    t0 = time.perf_counter()
    first = solve()
    t_first = time.perf_counter() - t0
    # keep ssik's part bounded: more repeats only when one pass is short
    t_solve = min(t_first, _time(solve, reps - 1) if t_first < 5.0 and reps > 1 else t_first) / n
    sols = _pad([np.array([s.q for s in ss]).reshape(-1, 7) for ss in first])
    ok = ~np.isnan(sols[..., 0])
    d = np.abs(np.angle(np.exp(1j * (sols - qn[:, None, :])))).max(axis=2)
    nearest = np.where(np.isnan(d), np.inf, d).min(axis=1)
    out = {"version": ssik.__version__, "arm": name, "n": n, "repeats": reps,
           "solve_repeats": reps if t_first < 5.0 else 1, "max_fk_frame_error": fk_err,
           "inside_own_limits": int(inside.sum()), "solve_s": t_solve, "solutions": float(ok.sum(axis=1).mean()),
           "max_solutions": int(ok.sum(axis=1).max()), "exact": _exact(robot, sols, m), "found": _found(sols, qn),
           "found_inside": _found(sols[inside], qn[inside]), "no_solution": int((~ok.any(axis=1)).sum()),
           "nearest_median": float(np.median(nearest[np.isfinite(nearest)])) if np.isfinite(nearest).any() else float("nan")}

    sms = [man.self_motion(m[i]) for i in range(n)]
    if kind == "panda":
        tv = np.repeat(qn[:, 6:7], 2, axis=1)
        out["given"] = "q7 (ssik's coordinate is the last joint, q6 in its 0-based names)"
    else:
        # ssik's swivel: the elbow on the shoulder-wrist circle from the base z axis projected onto
        # the circle's plane (base x when the axis is within 8.1 deg of z, |u_z| >= 0.99): it equals
        # our arm angle psi on the charts with elbow label 1 and psi + pi on label 0 (checked here);
        # on the near-vertical poses t is ssik's param_of of the generating configuration
        psi = srs.arm_angle(robot, qn)
        geo = srs.srs_geometry(robot)
        _, w = srs._into_canonical(geo, reference.fk(robot, qn))
        u = (geo.frame @ w[..., None])[..., 0]
        vertical = np.abs(u[:, 2]) >= 0.99 * np.linalg.norm(u, axis=1)
        own = np.array([sms[i].param_of(qn[i]) for i in range(n)])
        tv = np.stack([psi + np.pi, psi], axis=1)
        tv[vertical] = own[vertical, None]
        dd = np.abs(np.angle(np.exp(1j * (own - psi))))
        out["given"] = "our arm angle psi (psi + pi on ssik's elbow-0 charts)"
        out["vertical"] = int(vertical.sum())
        out["mapping_holds"] = int((~vertical & ((dd < 1e-9) | (np.abs(dd - np.pi) < 1e-9))).sum())
    lab = 0 if kind == "panda" else 1  # SRS: the chart's elbow label picks the column of tv

    def given():
        res = []
        for i in range(n):
            sm = man.self_motion(m[i])
            res.append([c.q(tv[i, min(c.label[0], lab)]) for c in sm])
        return res

    out["given_s"] = _time(given, reps) / n
    out["self_motion_s"] = _time(lambda: [man.self_motion(m[i]) for i in range(n)], reps) / n
    rows = []
    for i in range(n):
        x = np.array([c.q(tv[i, min(c.label[0], lab)]) for c in sms[i]]).reshape(-1, 7)
        rows.append(x[~np.isnan(x).any(axis=1)])
    gs = _pad(rows)
    gok = ~np.isnan(gs[..., 0])
    out.update(given_solutions=float(gok.sum(axis=1).mean()), given_exact=_exact(robot, gs, m),
               given_found=_found(gs, qn), charts=float(np.mean([len(sm) for sm in sms])))
    if ours_counts is not None:
        out["given_same_count"] = int((gok.sum(axis=1) == np.asarray(ours_counts)[:n]).sum())
    return out


def bench_redundant(robot: str, repeats: int = 5, n: int = 100_000, n_slow: int = 2000,
                    sweep_poses: int = 200, n_sweep: int = 10_000, seed: int = 0) -> dict:
    kind = redundant_kind(robot)
    r = load_robot(robot)
    rng = np.random.default_rng(seed)
    lim = np.asarray(r.limits, dtype=float)
    q = rng.uniform(lim[:, 0], lim[:, 1], size=(n, 7))
    poses = reference.fk(robot, q)
    mats = reference.fk_matrix(robot, q[:n_slow])
    fv = q[:, 6].copy() if kind == "panda" else srs.arm_angle(robot, q)
    k = kernels(robot, "c")
    out: dict = {"kind": "redundant", "class": kind, "free": k.free, "robot": robot, "n": n,
                 "n_slow": n_slow, "machine": machine(), "isa": instruction_set(),
                 "date": time.strftime("%Y-%m-%d %H:%M"), "repeats": repeats}
    k.ik(poses[:10], free=fv[:10])
    sols, counts = k.ik(poses, free=fv)
    ours = {"found": _found(sols, q), "solutions": float(counts[:n_slow].mean()), "exact": _exact(robot, sols[:n_slow], mats),
            "batch_s": _time(lambda: k.ik(poses, free=fv), repeats) / n}
    ps, pv = poses[:n_slow], fv[:n_slow]
    ours["single_s"] = _time(lambda: [k.ik(ps[i], free=pv[i]) for i in range(n_slow)], repeats) / n_slow
    sp = poses[:sweep_poses]
    sw = None

    def sweep():
        nonlocal sw
        sw = k.ik_sweep(sp, SWEEP)

    ours["sweep_s"] = _time(sweep, min(repeats, 2)) / sweep_poses
    ours["sweep_poses"] = sweep_poses
    ours["sweep_solutions"] = float(np.asarray(sw.counts).mean())
    out["ours"] = ours
    sweep_free = np.nan_to_num(np.asarray(sw.free, dtype=float), nan=0.0)
    out["harness"] = _harness(robot, poses, fv, sweep_free, n_sweep, repeats)
    if "error" not in out["harness"]:
        out["harness"]["counts_match"] = (out["harness"]["count_batch"] == int(counts.sum())
                                          == out["harness"]["count_single"])
    out["frankik"] = _frankik(robot, q, mats, n_slow, repeats)
    out["eaik"] = _eaik(robot, kind, q, mats, n_slow, repeats)
    out["ssik"] = _ssik(robot, kind, q, mats, min(n_slow, 1000), repeats, counts)
    return out


def _us(s: float) -> str:
    return f"{s * 1e6:8.3f} us"


def redundant_report(r: dict) -> str:
    h, o = r["harness"], r["ours"]
    n, m = r["n"], r["n_slow"]
    lines = [f"generated IK kernels of {r['robot']} ({r['class']} class, free parameter {r['free']}), "
             f"{n} poses inside the joint limits, one thread",
             f"{r['machine']}, {r['isa']}, {r['date']}, best of {r['repeats']}",
             f"C flags: {h.get('flags', '?')}",
             "per pose                                              time   generating config found"]
    if "error" in h:
        lines.append(f"  C harness failed: {h['error'][:300]}")
    else:
        lines += [f"  C harness, IK batch, calls of {h['chunk']} poses          {_us(h['ik_batch_chunked_s'])}"
                  f"   {o['found']}/{n} (target 0.250 us)",
                  f"  C harness, IK batch, one call of {n}            {_us(h['ik_batch_s'])}",
                  f"  C harness, single-pose IK in a loop              {_us(h['ik_single_s'])}",
                  f"  C harness, sweep of {SWEEP} values (batch, 16 rows)     {_us(h['sweep_s'])}"
                  f"   (target 3 us; {h['n_sweep']} poses)"]
    lines += [f"  kernels(), IK batch of {n}                       {_us(o['batch_s'])}",
              f"  kernels(), k.ik(P[i], free=v[i]) from Python     {_us(o['single_s'])}   (target 3 us; {m} poses)",
              f"  kernels(), k.ik_sweep(P, {SWEEP}) incl. the range      {_us(o['sweep_s'])}   ({o['sweep_poses']} poses)"]
    fk = r.get("frankik")
    if fk and "missing" not in fk:
        lines += [f"  frankik {fk['version']} ik_full (<= 4 sols), Python loop  {_us(fk['full_s'])}   "
                  f"{fk['found']}/{fk['n']}",
                  f"  frankik ik (one solution), Python loop           {_us(fk['one_s'])}"]
    ea = r.get("eaik")
    if ea and "missing" not in ea:
        if "batch_s" in ea:
            lines += [f"  EAIK HPRobot IK_batched (1 thread)               {_us(ea['batch_s'])}   {ea['found']}/{ea['n']}",
                      f"  EAIK HPRobot IK, Python loop                     {_us(ea['single_s'])}"]
        else:
            lines += [f"  EAIK HPRobot IK, Python loop                     {_us(ea['single_s'])}   {ea['found']}/{ea['n']}",
                      f"  EAIK HPRobot build (per pose: locked value)      {_us(ea['build_s'])}"]
    ss = r.get("ssik")
    ss_ok = bool(ss) and "missing" not in ss
    if ss_ok:
        lines += [f"  {'ssik ' + ss['version'] + ' solve(T) (all it returns), loop':<49}{_us(ss['solve_s'])}   "
                  f"{ss['found']}/{ss['n']}",
                  f"  {'ssik self_motion(T), charts at the value, loop':<49}{_us(ss['given_s'])}   {ss['given_found']}/{ss['n']}",
                  f"  {'ssik self_motion(T) alone, loop':<49}{_us(ss['self_motion_s'])}"]
    lines.append(f"solutions per pose (exact: FK within {EXACT:.0e}, on the first {m} poses): ours {o['solutions']:.2f} "
                 f"({o['exact']:.2f}; sweep: {o['sweep_solutions']:.2f} per value)"
                 + (f", frankik {fk['solutions']:.2f} ({fk['exact']:.2f})" if fk and "missing" not in fk else "")
                 + (f", EAIK {ea['solutions']:.2f} ({ea['exact']:.2f})" if ea and "missing" not in ea else "")
                 + (f", ssik solve {ss['solutions']:.2f} ({ss['exact']:.2f}), at the value {ss['given_solutions']:.2f} "
                    f"({ss['given_exact']:.2f}) (first {ss['n']})" if ss_ok else ""))
    if "error" not in h:
        lines.append(f"C harness solution counts equal kernels()'s: {h['counts_match']}")
    if fk and "missing" not in fk:
        lines.append(f"frankik: flange pose and q7 in (checked: its solutions' FK vs ours, max error "
                     f"{fk['max_fk_error']:.1e}); no solution for {fk['no_solution']} poses; generating config "
                     f"inside frankik's own limits for {fk['inside_own_limits']} poses, found for {fk['found_inside']} of them; "
                     f"of the poses it misses, {fk['missed_other_q4']} get solutions with only another q4 (elbow) root")
    if ea and "missing" not in ea:
        lines.append(f"EAIK: {ea['lock']}, {ea['family']}, {ea['flagged_ls']} least-squares solutions flagged")
    if ss_ok:
        sampled = ("one solution per branch and in-limits q7 arc, at the arc centre" if r["class"] == "panda"
                   else "a grid of 16 swivel values, limit-filtered")
        lines.append(f"ssik: prebuilt {ss['arm']}, same flange frame as ours (FK max difference {ss['max_fk_frame_error']:.1e}); "
                     f"solve(T) samples the self-motion ({sampled}; up to {ss['max_solutions']} per pose, none for "
                     f"{ss['no_solution']} poses), generating config inside ssik's limits for {ss['inside_own_limits']} poses, "
                     f"found for {ss['found_inside']}, nearest returned solution median {ss['nearest_median']:.3f} rad; "
                     f"best of {ss['solve_repeats']} (solve), {ss['repeats']} (charts)")
        lines.append(f"ssik at a given value: {ss['charts']:.2f} charts per pose evaluated at {ss['given']}, "
                     f"as many solutions as ours on {ss.get('given_same_count', '?')}/{ss['n']} poses"
                     + (f"; ssik's swivel = psi or psi + pi checked on {ss['mapping_holds']} poses, its own coordinate "
                        f"of the generating config (param_of) used on {ss['vertical']} poses with the shoulder-wrist axis "
                        f"within 8.1 deg of z (its reference switches to x)" if "vertical" in ss else ""))
    if fk is None:
        lines.append("frankik: not applicable (Franka Panda and FR3 only)")
    for name in ("frankik", "eaik", "ssik"):
        x = r.get(name)
        if x and "missing" in x:
            lines.append(f"{name}: skipped, {x['missing']}")
    return "\n".join(lines)
