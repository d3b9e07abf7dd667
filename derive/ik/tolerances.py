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

# --- Subproblem library (derive/ik/subproblems). Each constant names its unit and the one
# --- quantity it is compared with.

#: Exactness of a subproblem solution: the norm of the subproblem's own equation residual at the
#: returned angles, in the equation's units (metres for sp1, sp2, sp3 and sp5, where the residual
#: is a distance; the units of h^T p for sp4 and sp6). At or below it the solution is exact
#: (``exact`` True), above it a least-squares one.
SP_EXACT_TOL = 1e-9
#: A free angle: the norm of the (sin, cos) coefficient vector with which an angle enters its
#: equation, in the equation's units (|k x p| in metres for sp1 and sp2, |k x p1| |k x p2| in m^2
#: for sp3, |k x h| |k x p| for sp4). Below it the angle does not enter the equation: the
#: subproblem is degenerate and the angle is returned as 0.
SP_FREE_ANGLE = 1e-12
#: A rotation axis given to a subproblem: | |k| - 1 | (dimensionless). Beyond it InputError.
SP_AXIS_UNIT_TOL = 1e-9
#: sp5 and sp6 reduce to M x = b with x = (sin t_a, cos t_a, sin t_b, cos t_b) and M 2x4: a 2x2
#: block of M counts as rank 1 when |det| / (squared Frobenius norm) is below this
#: (dimensionless: 1/2 for a scaled rotation, 0 at rank 1); a whole M whose second singular value
#: over its first is below it has a continuum of solutions (degenerate).
SP_RANK_TOL = 1e-9
#: A root u of the quartic in the tangent half-angle (sp5, sp6) is taken as a real angle when
#: 2 |Im u| / (1 + |u|^2) is below this (dimensionless: the distance of exp(i theta) from the
#: unit circle, to first order; a double root, a tangency, splits off the real axis by about the
#: square root of rounding). The candidate is still kept only if its residual is within
#: SP_EXACT_TOL.
SP_ROOT_MODULUS = 1e-6
