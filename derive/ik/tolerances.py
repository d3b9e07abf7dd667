"""Tolerances shared by the closed-form IK solvers (UR family and spherical wrist), their IK
programs and the generated kernels."""

#: |sin| of the wrist angle below this is the wrist singularity (one wrist joint free)
WRIST_SINGULAR = 1e-11
#: Candidates whose FK misses the pose by more than this (m or rad) are dropped.
ACCEPT_TOL = 1e-8
#: Solutions closer than this in every joint (mod 2 pi) are one solution: such pairs only arise
#: within about 1e-7 of a singular set, where a double root splits by rounding (sqrt of noise).
MERGE_TOL = 1e-6
#: Slack on |cos| <= 1 and on the discriminant before a branch counts as unreachable.
REACH_TOL = 1e-10
