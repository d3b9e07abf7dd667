"""The one tolerance module of the IK layer (derive.ik): the closed-form solvers (UR family,
spherical wrist, SRS, Panda), their finish step (:mod:`derive.ik.finish`), the IK programs and
the generated kernels, and the subproblem library.

Every constant states its unit and the one quantity it is compared with. Two constants with the
same value but different units (a length and an angle) are two constants. docs/ik.md has the
table ("Tolerances").
"""

# --- Class detection: the robot's axes at the zero pose, in its own frames.

#: Directions of unit joint axes: |h_i . h_j| of two axes that must be perpendicular, |h_i x h_j|
#: of two that must be parallel, the largest component difference of an axis from the class's
#: direction (dimensionless; about the angle in rad). Spherical wrist, SRS, Panda.
CLASS_DIRECTION = 1e-10
#: Positions: the distance (m) between axis lines that must meet, of a point from a line it must
#: lie on, of a coordinate from the class's value. Spherical wrist, SRS, Panda.
CLASS_DISTANCE = 1e-10
#: The UR layout (derive.ik.closed_form): each component of a unit axis in thesis form against
#: the UR axes (dimensionless).
UR_AXIS_TOL = 1e-12
#: The UR layout: each component of a link vector (m) against the UR shape (zeros where the UR
#: has none) and of the chain's start point.
UR_LINK_TOL = 1e-12
#: The relation FK_robot(q) = B FK_canonical(s q + o) T, checked on random configurations: the
#: largest position error (m).
MAP_POSITION = 1e-10
#: ... and the largest rotation angle (rad) of the same check.
MAP_ANGLE = 1e-10
#: Joint offsets of the spherical-wrist relation within this (rad) of a multiple of pi/12 are
#: that multiple.
OFFSET_SNAP = 1e-12
#: Entries of the fixed transforms written into the 7R IK programs (derive.ik.program7) within
#: this of an integer are that integer (dimensionless rotation entries and metres alike: the
#: canonical frames are signed permutations up to the rounding of the description's numbers).
PROGRAM_SNAP = 1e-12

# --- Solving.

#: |sin| of the middle angle of a rotation decomposition (the UR's t5, the spherical wrist's t5,
#: the ZYZ decompositions of SRS and Panda, :mod:`derive.ik.euler`) below this is a singularity:
#: the first angle is free (dimensionless). Also |sin t4| of the SRS elbow, marked singular.
WRIST_SINGULAR = 1e-11
#: A Panda joint is free when a point is this close (m) to its axis: |X| (the shoulder on axis
#: 5, q5 free), hypot(vx, vy) (the shoulder on axis 6, q6 free; then |Z| must be within it too).
FREE_JOINT_DISTANCE = 1e-11
#: The SRS wrist centre counts as on axis 1 when it is closer than this to it (m) with joint 3
#: given (q1 is then free). With psi given the reference plane's subproblem 1 decides it by
#: SP_FREE_ANGLE (the same 1e-12 m) and the plane then uses the canonical x axis.
AXIS_TOL = 1e-12
#: Slack on |cos| <= 1 and on a discriminant before a branch counts as unreachable (relative:
#: the cosines are ratios, the discriminants compared with max(1, c^2)).
REACH_TOL = 1e-10
#: SRS elbow: cos t4 within this of +-1 is +-1 (dimensionless), so the two elbow branches
#: coincide exactly at the stretch (a rounding of 1e-16 would split them by 1e-8 rad). The same
#: for the SRS shoulder's double roots with a joint given: |W_z / r| (q3 given) and |sin t3|
#: (q1 given) within it of 1.
STRETCH_TOL = 1e-14
#: Panda elbow (eq. E2) and q6 roots (eq. W4): a cosine within this of +-1 is +-1
#: (dimensionless), and the q6 roots merge where (X c5)^2 < DOUBLE_ROOT X^2 + W4_NOISE |X|. It
#: is larger than STRETCH_TOL because the Panda's cosine K / hypot(A, B) is a difference of four
#: squared lengths: its rounding is about 1e-14 where the SRS's is about 1e-16. The two are kept
#: apart because the generated kernels use them (changing one changes the emitted programs).
DOUBLE_ROOT = 1e-13
#: Rounding of X^2 - vz^2 per metre of |X| (m), eq. W4 of the Panda: vz of a pose made by FK is
#: off by up to ~5e-15 m (measured 3e-15 on the Panda at q5 = pi/2).
W4_NOISE = 1e-13

# --- The finish step (derive.ik.finish): checking and merging candidates.

#: A candidate is kept when the FK of the robot's own model reproduces the pose within this
#: position error (m) ...
ACCEPT_POSITION = 1e-8
#: ... and within this rotation angle (rad): 2 atan2(|vec(r)|, |w(r)|) of the relative rotation.
ACCEPT_ANGLE = 1e-8
#: Solutions closer than this (rad; m for a prismatic joint) in every joint, each difference
#: wrapped to (-pi, pi], are one solution: such pairs only arise within about 1e-7 of a singular
#: set, where a double root splits by rounding (sqrt of noise). The later one is dropped.
MERGE_TOL = 1e-6
#: Joint limits are closed intervals with this slack (rad, m for a prismatic joint).
LIMIT_SLACK = 1e-12

# --- The SRS arm angle and the 7R nearest search (derive.ik.srs, derive.ik.redundant).

#: a sin psi + b cos psi + c = 0 has no isolated roots when hypot(a, b) is below this (the
#: coefficients are entries of rotation matrices: dimensionless).
TRIG_DEGENERATE = 1e-14
#: Breakpoints of the feasible arm angles closer than this (rad) are one.
ARC_MERGE = 1e-13
#: The 7R nearest search: largest-move values closer than this (rad) count as equal (the summed
#: move decides).
TIE = 1e-13
#: The 7R nearest search stops refining when the bracket of the free parameter is narrower than
#: this (rad).
FREE_TOL = 1e-9

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
#: Seven-joint arms only, when the projection with NEAR_POINT_TOL gives no nominal: the axis
#: points' coordinates within this (m) are made equal (the Kinova Gen3: its shoulder axes miss a
#: common point by 5.9 mm, its axis points step by 6.4 mm; all of them are then merged onto one
#: line, an SRS arm) ...
NEAR_POINT_TOL_7R = 1e-2
#: ... and the relation's largest mismatch (m, rad; as NEAR_DEVIATION_MAX) may be up to this:
#: the Gen3's projected SRS nominal is 0.049 from it. Solved with joint 3 given, the polish with
#: the seeds near singular sets found the generating configuration on 2000 of 2000 poses.
NEAR_DEVIATION_MAX_7R = 0.06
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
#: A candidate of the nominal closed form whose Jacobian on the arm (the free joints' columns,
#: rows metres per rad and rad per rad) has its smallest singular value below this fraction of
#: its largest times the square root of the nominal's deviation (this factor in 1 / sqrt(m or
#: rad)) lies near a singular set of the arm: extra seeds on both sides along the singular
#: direction are polished too (derive.ik.nearclass._singular_seeds). The calibrated UR5
#: (deviation 0.016) seeds below a ratio of 0.032, the iiwa14 with axes 0.44 mm off (8.8e-4)
#: below 0.0074 (about a tenth of its candidates), the Gen3 (0.049) below 0.055, a URDF's
#: printed constants (1e-8) below 2.5e-5. At 0.1 the Gen3 missed the generating configuration on
#: 4 of 2000 poses (a fold its seeds did not reach), at 1 a third of the iiwa14's candidates
#: were seeded (three times the time).
SEED_SINGULAR = 0.25

# --- General 6R (derive.ik.general6r): the Raghavan-Roth / Manocha-Canny elimination.

#: A returned solution's FK misses the pose by at most this (m and rad), on derive's exact FK.
G6_ACCEPT = 1e-10
#: An eigenvalue x3 counts as real when |Im x3| / (1 + |x3|^2) is below this (the distance of
#: exp(i q3) from the unit circle, to first order); the candidate is kept only when Newton
#: polish brings it onto the pose. Generous, so that a double root split by rounding (about the
#: square root of rounding, 1e-8) is never lost.
G6_REAL_TOL = 1e-3
#: Newton iterations at most per candidate (most need one or two).
G6_NEWTON_MAX = 30
#: A solution is singular (flag) when the Jacobian's smallest singular value over its largest is
#: below this.
G6_SINGULAR = 1e-8
#: The leading matrix of the pencil is too ill-conditioned (flag "degenerate") beyond this
#: 1-norm condition number for every offset tried.
G6_LEADING_COND = 1e12
#: A leading matrix this well conditioned is taken without trying the other offsets of q3.
G6_GOOD_COND = 1e6
#: Relative singular value below which Q (14 x 8) or the pencil is rank-deficient.
G6_RANK_TOL = 1e-9
#: A pose whose elimination degenerates is solved again at nearby poses, each moved by a random
#: twist of this size (rad, and this times the arm's size in m), and Newton carries their
#: solutions back onto it.
G6_PERTURB = 1e-4
#: Nearby poses tried for a degenerate pose.
G6_PERTURB_TRIALS = 3
#: A pose with a solution whose Jacobian's smallest singular value over its largest is below this
#: is flagged degenerate (near the singular set's image two solutions merge, and one of a nearly
#: merged pair can be lost; at a singular solution the joints are only determined to about the
#: square root of G6_ACCEPT).
G6_NEAR_SINGULAR = 1e-6
#: The sp6 layout's IK program (derive.ik.program_parallel3.parallel3_sp6_program) flags a
#: solution singular (flag ``singular_dr``) where its q1 is a (near-)double root of subproblem
#: 6's quartic: |F'(q1)| below this times the sum of |coefficients| of F (a trigonometric
#: polynomial of degree 2). There the root is good to about the square root of the rounding only.
SP6_DOUBLE_ROOT = 1e-4

# --- Moved here from their modules (issue 31's leftovers); the values, and so the emitted
# --- kernels' bytes, are unchanged.

#: General 6R Newton (derive.ik.general6r._newton): a candidate is done when its error (scaled
#: lengths and rad, largest component) is below this, and the step is accepted as the last when
#: the linear model's residual |e - J dq| (same unit) is below it (the error the step leaves is
#: that residual plus the order of the step's square).
G6_NEWTON_STOP = 1e-13
#: ... and the last step is one below this (rad, every joint) taken where the error was below it
#: too (scaled lengths and rad): the second derivatives of the scaled FK are of order one, so
#: such a step leaves an error of the order of its square, below G6_NEWTON_STOP; no evaluation
#: only to confirm it. (derive.ik.general6r.NEWTON_DONE.)
G6_NEWTON_DONE = 1e-7
#: The sp6 layout's IK program (derive.ik.program_parallel3): the q5 block of subproblem 6 (a
#: constant 2 x 2 matrix of the arm) must have |det| / (squared Frobenius norm) at least this
#: (dimensionless; 1/2 for a scaled rotation, 0 for a singular block) for the program to
#: eliminate x_5 by its adjugate; below it the program is refused (DeriveError).
SP6_BLOCK_MIN = 1e-6
#: The "roots4" line of the IK programs (templates roots4.c.j2, roots4.py.j2, roots4_numpy.py.j2:
#: the real roots of F(t) = a0 + a1 cos t + b1 sin t + a2 cos 2t + b2 sin 2t): the quartic's
#: leading coefficient F(t0 + pi), the largest of eight samples of |F|, at most this times the
#: largest |coefficient| (dimensionless) means F vanishes to rounding: no roots (every t solves
#: it, or none can be told apart).
ROOTS4_LEAD = 1e-12
#: ... Durand-Kerner (C, pure Python) stops when no root moves by more than this relative to
#: 1 + |root| (dimensionless, |Re| + |Im|): rounding of the monic quartic's roots.
ROOTS4_DK_STOP = 1e-14
#: ... Ferrari (C) takes the quartic as biquadratic (the depressed cubic term Q dropped) when
#: |Q| is at most this times 1 + |P|^(3/2) + |R| (dimensionless, the depressed quartic's
#: coefficients in their own scale): there the resolvent's root would be 0 to rounding.
ROOTS4_BIQUADRATIC = 1e-14
#: ... each root gets two Newton steps on F (on its cosine and sine), but only where |F'(t)| is
#: above this times the largest |coefficient| (dimensionless): at a (near-)double root F' vanishes
#: and a step would throw the root away ...
ROOTS4_NEWTON_DF = 1e-8
#: ... and only a step below this (rad) is taken (a larger one means the quartic's root was not
#: near F's; the sixth-order Taylor turn of the C and Python kernels is exact to rounding below it).
ROOTS4_NEWTON_STEP = 1e-3
#: The near-class kernels' Newton polish (derive.codegen.polish, templates polish*.j2; the numpy
#: reference's is POLISH_TOL): it stops when every component of its error e (m and rad) is at
#: most this (rounding of the kernels' own FK) ...
POLISH_STOP = 1e-14
#: ... a polished candidate is a solution when its residual (derive.codegen.polish.RESIDUAL_METRIC,
#: the larger of metres and radians) is at most this ...
POLISH_ACCEPT = 1e-11
#: ... and a step whose largest joint move is at most this (rad or m) ends the polish without
#: another FK and Jacobian (quadratic convergence leaves an error of the order of its square);
#: the residual of the kernels' own FK checks it, and where it fails the steps go on.
POLISH_LAST_STEP = 1e-9
#: A candidate of the nominal closed form in the near-class kernels (its reach checks dropped,
#: derive.codegen.polish._reach_check) is polished only when its start misses the pose by at most
#: this many deviations of the nominal (dimensionless; + 1e-9, then m, and sin of the rotation
#: angle, each compared): the nominal's miss within SEED_REACH deviations
#: (derive.ik.nearclass._near_reach) and the arm's own mismatch on top.
SEED_KEEP = SEED_REACH + 1.0
#: General 6R numpy reference (derive.ik.general6r._newton, the pose's own solve): from this
#: Newton step on, a candidate whose error is above 1e-6 and not below half the previous step's
#: stops (a spurious candidate, no root near, that would take every step to G6_NEWTON_MAX and
#: be dropped; the steps left cost the whole batch's per-step overhead). The C and numpy
#: kernels stop such a candidate from step 3 (G6_NEWTON_FAR); the reference waits longer (the
#: slowest true candidates of random poses converge by step 8). A pose flagged degenerate before
#: Newton, and the nearby-pose path's carrying back, take every step. G6_NEWTON_MAX: no stop.
G6_REF_NEWTON_FAR = 10
