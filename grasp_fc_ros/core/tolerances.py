"""Numerical tolerances of the core, in one place.

Every decision that compares a floating-point value with a threshold uses one of
these constants. All of them are dimensionless: positions enter only through unit
directions or through a grasp normalised to unit size, and forces are normalised so
that the normal components sum to at most one.
"""

#: Normals shorter than this carry no usable direction: after normalisation their
#: rounding noise would be as large as the direction itself.
ZERO_NORMAL_NORM = 1e-12

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

#: A separating wrench is accepted by :func:`verify_certificates` if no contact force
#: does more than this fraction of max_j |a_j| of positive work on it (the issue's
#: contract: n_i . a_i + mu_i |a_t,i| <= 1e-6 max_j |a_j|).
CERTIFICATE_TOL = 1e-6

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
