"""Choosing IK solutions and a run-time tool offset with the C kernels (docs/kernels.md).
Run: python docs/examples/select_and_tool.py (tests/test_selection.py runs it too)."""

import numpy as np

import derive

k = derive.kernels("ur5", "c")

# a pose given as position + quaternion in ROS / scipy order (x, y, z, w)
P = derive.pose.from_position_quaternion([0.40, 0.10, 0.30], [1.0, 0.0, 0.0, 0.0], order="xyzw")

sols, count = k.ik(P)                                   # every closed-form solution, NaN-padded
print(f"{count} solutions in (-pi, pi]")

# inside the joint limits, every 2 pi winding (a UR joint with +-2 pi limits has two values)
wl, wcount, branch, singular = k.ik(P, within_limits=True, details=True)
print(f"{wcount} solutions inside the limits; branches {sorted(set(branch[:wcount].tolist()))}")

# the one nearest to the current joints: the largest single-joint move decides
current = np.array([0.2, -1.2, 1.5, -1.8, -1.6, 0.3])
best = k.nearest(P, current)
print("nearest:", np.round(best.q, 4), f"max move {best.max_move:.3f} rad, branch {best.branch}")

# a gripper 0.15 m along the flange's z axis, set at run time (no regeneration)
tool = derive.pose.as_pose((np.eye(3), [0.0, 0.0, 0.15]))
kt = k.with_tool(tool)
tcp = kt.fk(best.q)                                     # the tool frame's pose
again = kt.nearest(tcp, best.q)                         # IK of the tool frame
assert np.abs(again.q - best.q).max() < 1e-9
print("tool-frame round trip ok")
