"""Numerical tolerances of the core, in one place.

Every decision that compares a floating-point value with a threshold uses one of
these constants. All of them are dimensionless: positions enter only through unit
directions or through a grasp normalised to unit size, and forces are normalised so
that the normal components sum to at most one.
"""

#: A normal is turned into a direction by dividing it by its largest absolute component
#: first (so that squaring can neither overflow nor underflow), which is exact to a few
#: ulps whenever that component is a normal float. Below the smallest normal float,
#: subnormal components carry fewer significant bits than a direction needs, so such a
#: normal (and the zero normal) is refused as too short.
MIN_NORMAL_COMPONENT = 2.2250738585072014e-308  # np.finfo(np.float64).tiny

#: Largest accepted |coordinate| of a contact position (2**1000, about 1.07e301). Lever
#: arms (differences of two positions), centroids (sums of up to 2**14 positions) and
#: the filter's reference point stay finite below it, with 2**10 to spare. Beyond it a
#: grasp is refused: choose a larger length unit (verdicts do not depend on it).
MAX_ABS_COORDINATE = 2.0 ** 1000

#: Largest accepted friction coefficient. Force closure only grows with mu, but no finite
#: mu is "as good as infinite" for every grasp, so larger values cannot be clamped and
#: are refused. At mu = 1e3 the cone's half-angle is within 0.06 degrees of 90, far past
#: any physical contact (rubber on rough surfaces: about 1 to 2). The exact test's conic
#: program scales its rows by mu, and Clarabel starts failing on random grasps a little
#: above 1e4: the bound keeps a wide margin below that (docs/performance.md#exact-stage).
MAX_FRICTION_COEFFICIENT = 1e3

#: Fans of the torque filter are widened by this angle (radians) on each side.
#: Their boundary directions come out of arcsin and cross products with errors of a
#: few 1e-16; widening by far more than that makes every computed fan contain the
#: true one, so rounding can only make the filter pass more grasps, never reject a
#: force-closure grasp.
FAN_WIDEN_RAD = 1e-9

#: A fan whose (widened) half-angle comes this close to 90 degrees is replaced by its
#: whole plane. Near the half-plane case the two boundary torques become opposite and
#: stop describing the set (and arcsin is ill-conditioned there), so the larger set is
#: the sound stand-in.
HALF_PLANE_MARGIN_RAD = 1e-6

#: A candidate separating direction c rejects a set of unit torque directions only if
#: every direction satisfies c . v >= -SPAN_TOL * |c|. Far below FAN_WIDEN_RAD, so a
#: widened fan that truly crosses the separating plane is never mistaken for one that
#: does not.
SPAN_TOL = 1e-12

#: Two cross products shorter than this (for unit inputs) are treated as parallel:
#: the pair does not define a separating plane.
PARALLEL_TOL = 1e-12

#: The grasp map of a grasp normalised to unit size has rank 6 only if its smallest
#: singular value exceeds this fraction of its largest. Below it, collinear or
#: coincident contacts leave a wrench direction that no contact force can resist.
RANK_TOL = 1e-9

#: Force closure is reported only for a verified internal force that lies at least
#: this deep inside every friction cone (mu * f_n - |f_t| >= MARGIN_TOL, with the normal
#: forces summing to one). Grasps closer to the boundary are numerically marginal: the
#: solver's own accuracy (about 1e-8) could not tell them from non-force-closure ones.
MARGIN_TOL = 1e-6

#: Multiplies the unit roundoff in the a-priori rounding bounds of the certificates
#: (a matrix-vector product of length k errs by at most about k eps |A| |x|). A
#: generous factor: it costs nothing measurable (the slack stays ~1e-13 against
#: MARGIN_TOL) and covers the rounding of the bounds' own arithmetic.
ROUNDING_SLACK = 64.0

#: A separating wrench w is accepted (by the filter before it returns one, and by
#: :func:`verify_certificates`) only if no contact force does more than this fraction of
#: max_j |a_j| of positive work on it: for every contact, with a_i = w_force +
#: w_torque x p_i, n_i . a_i + mu_i |a_i - (n_i . a_i) n_i| <= CERTIFICATE_TOL max_j |a_j|
#: (the issue's contract). The filter's directions are exact up to SPAN_TOL (1e-12) on
#: unit torques, so its wrenches meet this with six orders of magnitude to spare, except
#: on nearly collinear grasps, whose a_j are all nearly zero.
CERTIFICATE_TOL = 1e-6

#: Rounding allowance of the filter's check of its own wrenches, in units of
#: eps * (1 + mu_i), for a_i computed from a unit direction and lever arms scaled to at
#: most one: the worst case of the few products and sums involved, doubled. It matters
#: only when every a_j is rounding noise (a wrench no contact can do any work on, e.g.
#: the torque about a line of contacts).
WORK_ROUNDING_ULPS = 16

#: Contact forces pass :func:`verify_certificates` if their net force and net torque
#: about the caller's origin are at most this fraction of sum_i |f_i| (times the
#: largest lever arm) and their normal parts sum to one within it: rounding of the
#: caller-frame check itself is ~n eps |p| / size, far below this.
EQUILIBRIUM_TOL = 1e-9

#: The fast exact stage (:mod:`.interior_point`) decides a grasp only if its grasp map
#: has sigma_min^2 > FAST_RANK_TOL^2 trace(G G^T), with sigma_min^2 bounded below by
#: 1 / |(G G^T)^-1|_F from a Cholesky factor (whose relative error, ~cond eps <= 1e-4
#: here, only shifts that bound a little). Grasps nearer rank deficiency go to the
#: Clarabel path, which decides rank from an SVD with RANK_TOL.
FAST_RANK_TOL = 1e-6

#: The fast stage hands a grasp to the Clarabel path when the equilibrium forces with
#: normal parts summing to one are nearly absent: the Schur complement of the
#: normalisation row in [G; n^T] [G; n^T]^T is below this fraction of n (it is 0 when
#: all contacts share one normal).
SHARED_NORMAL_TOL = 1e-9

#: With ``margin="optimum"`` the margin is reported as a certified interval at most
#: this wide (the accuracy Clarabel's default tolerances give the optimum).
MARGIN_ACCURACY = 1e-8

#: The fast stage keeps iterating on a not-force-closure grasp (when a separating
#: wrench is requested) until its wrench does at most this fraction of max_j |a_j| of
#: positive work at any contact: a tenth of CERTIFICATE_TOL, leaving room for the
#: rounding of the map back to the caller's frame.
SEPARATION_TARGET = 1e-7

#: The torque filter passes a grasp with soft contacts at once when the smallest
#: eigenvalue of sum_i n_i n_i^T over its soft normals exceeds this: a rejection needs a
#: unit direction c with |c . n_i| <= SPAN_TOL at every soft contact (its line {tau n_i}),
#: so c^T (sum_i n_i n_i^T) c <= n SPAN_TOL^2 (~1e-20 for 10,000 contacts), far below it.
#: Below it the grasp just goes through the filter as usual.
SOFT_SPAN_TOL = 1e-12
