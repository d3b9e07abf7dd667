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

# --- Near-class arms (derive/ik/nearclass): the nominal robot and the Newton polish. Each
# --- constant names its unit and the one quantity it is compared with.

#: Axes projected onto the class (route "projection" of :func:`derive.ik.nearclass.nominal`):
#: the angle (rad) between a joint axis at the zero pose, in the nominal's canonical frame, and
#: the nearest coordinate axis. At or below it the axis is made that coordinate axis (a URDF's
#: 1.570796325 twists: 2e-9 rad; a DH file's ``alpha: 1.5708``: 3.7e-6 rad).
NEAR_AXIS_TOL = 1e-3
#: Axis points projected onto the class: the difference (m) between two coordinates of the axis
#: points (canonical frame, one coordinate direction at a time, single-linkage clusters). At or
#: below it they are made equal, so nearly intersecting axes intersect and nearly coincident
#: parallel axes coincide (an iiwa14 whose axes miss by 0.44 mm).
NEAR_POINT_TOL = 1e-3
#: The largest mismatch of the relation FK_robot(q) ~= B FK_nominal(s q + o) T that a nominal
#: robot may have: max over sample configurations of the position error (m) and the rotation
#: angle (rad), each compared with it (``Nominal.deviation``). The calibrated UR5
#: (ur5-calibrated.yaml) is 0.016 from the UR5.
NEAR_DEVIATION_MAX = 0.03
#: A polished solution has converged when its residual, the larger of the position error (m)
#: and the rotation angle (rad) of FK(q) against the pose, is at or below this.
POLISH_TOL = 1e-12
#: Newton iterations of the polish before a candidate counts as not converged.
POLISH_MAX_ITER = 40
#: The largest change of one joint (rad for revolute, m for prismatic joints) in one Newton
#: step of the polish (a trust region: larger steps are scaled down).
POLISH_MAX_STEP = 0.3
#: A nominal whose ``deviation`` (m, rad: the largest relation mismatch) exceeds this is carried
#: onto the arm by a homotopy (derive.ik.nearclass.track) before the polish; below it Newton
#: starts from the nominal's candidates directly.
HOMOTOPY_FROM = 1e-4
#: The homotopy parameters s (dimensionless, 0 the nominal, 1 the arm) of the tracking stages.
HOMOTOPY_STAGES = (0.25, 0.5, 0.75)
#: Damped Newton steps per homotopy stage (the final polish at s = 1 is POLISH_MAX_ITER).
HOMOTOPY_STEPS = 4
#: A seed from a branch the nominal does not reach (its square root clipped) is polished only
#: when the nominal's FK at the seed is within this multiple of the nominal's deviation of the
#: pose (dimensionless; the comparison is in m and rad, max of the two).
SEED_REACH = 4.0
