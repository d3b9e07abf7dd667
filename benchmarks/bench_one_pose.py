"""Latency of one pose per call from Python (CPU time, time.process_time, best of 3 x 2000 calls)
beside the batch figure: derive.kernels("ur5", "c").ik and ("crx10ia", "c").ik (the extension's
bound ik: input checked in C), ("xarm7", "c", free="q1").ik (the free-joint wrapper: pose checks in
derive.kinematics.pose.as_pose_batch, the C library through ctypes), each with one dual quaternion
(8,) and one 4x4 matrix; the pose checks alone; xarm7's batch of 500 per pose.

    .venv/bin/python benchmarks/bench_one_pose.py
"""
import time, numpy as np, derive
from derive.algebra import dualquat as dq
from derive.kinematics.pose import as_pose_batch
def t(f, n=2000):
    for _ in range(50): f()
    r = []
    for _ in range(3):
        t0 = time.process_time()
        for _ in range(n): f()
        r.append((time.process_time() - t0) / n * 1e6)
    return min(r)
ku = derive.kernels("ur5", "c"); kc = derive.kernels("crx10ia", "c"); kx = derive.kernels("xarm7", "c", free="q1")
rng = np.random.default_rng(1)
P = np.asarray(ku.fk(rng.uniform(-1, 1, 6))); Pc = np.asarray(kc.fk(rng.uniform(-1, 1, 6)))
qx = rng.uniform(-1, 1, 7); Px = np.asarray(kx.fk(qx)); v = float(qx[0])
M, Mc, Mx = dq.to_matrix(P), dq.to_matrix(Pc), dq.to_matrix(Px)
Bx = np.asarray(kx.fk(rng.uniform(-1, 1, (500, 7))))
rows = [("ur5 ik(dq)", lambda: ku.ik(P)), ("ur5 ik(4x4)", lambda: ku.ik(M)),
        ("crx10ia ik(dq)", lambda: kc.ik(Pc)), ("crx10ia ik(4x4)", lambda: kc.ik(Mc)),
        ("xarm7 q1 ik(dq)", lambda: kx.ik(Px, free=v)), ("xarm7 q1 ik(4x4)", lambda: kx.ik(Mx, free=v)),
        ("as_pose_batch(dq)", lambda: as_pose_batch(Px)), ("as_pose_batch(4x4)", lambda: as_pose_batch(Mx)),
        ("dq.check_unit(dq)", lambda: dq.check_unit(Px))]
for name, f in rows:
    print(f"{name:22s} {t(f):8.2f} us")
print(f"{'xarm7 q1 batch 500':22s} {t(lambda: kx.ik(Bx, free=v), 10) / 500:8.2f} us per pose")
