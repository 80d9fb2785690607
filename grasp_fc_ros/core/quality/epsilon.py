"""The Ferrari-Canny epsilon (Q1) of a grasp with exact friction cones, certified.

Definition
----------
Contact i has position p_i, inward unit normal n_i and friction mu_i. A contact force
with unit normal part is f = n_i + t with t perpendicular to n_i and |t| <= mu_i; its
wrench about the centre c is (f, (p_i - c) x f / L), with the torque scale L
(``torque_scale``; default: the largest |p_i - c|, so that epsilon does not change
when the grasp and c are scaled together). The grasp wrench space W is the convex hull
of the origin and of every contact's unit-normal-force wrenches: the contact forces in
their circular cones whose normal parts sum to at most 1 (the L1 budget of Q1).
epsilon is the radius of the largest ball about the origin inside W, and 0 when the
origin is not an interior point of W (the grasp is not force closure).

For a unit direction u = (u_f, u_t) the work of contact i's unit force on u is
<f, a_i> with a_i = u_f + u_t x (p_i - c) / L, and its largest value over the cone is

    h_i(u) = a_n,i + mu_i |a_t,i|     (a_n,i = <a_i, n_i>, a_t,i = a_i - a_n,i n_i),

so W's support function is h(u) = max(0, max_i h_i(u)), and epsilon = min over unit u
of h(u). Every unit u therefore bounds epsilon from above: ``direction`` certifies
``upper``, and anyone can recompute h(direction) from the formula.

``lower`` is certified by points that lie in W: exact support points of the circular
cones (the maximisers above, not pyramid edges), held as the vertices of a closed
surface around the origin (:mod:`.epsilon_kernels`); rounding is accounted for there.

Budgets and soft fingers
------------------------
``budget="linf"`` bounds each normal force by 1 instead of their sum: W is then the
Minkowski sum of conv({0}, contact i's wrenches) and h(u) = sum_i max(0, h_i(u)).
``torsional_friction`` (gamma, a length) makes contacts soft fingers: a torsional
moment tau about n_i with |(t, mu_i tau / gamma_i)| <= mu_i, adding tau n_i / L to the
torque, so that h_i(u) = a_n,i + |(mu_i a_t,i, gamma_i <n_i, u_t> / L)|.

Not provided: contact forces that attain epsilon (the primal side), weighted or
non-spherical wrench norms other than the torque scale, and budgets other than L1 and
L-infinity.

Consistency with the verdicts
-----------------------------
The grasps are first decided by :func:`.pipeline.check_force_closure`. Only
force-closure grasps get ``lower`` > 0 (the others get 0, whatever their epsilon), and
every force-closure grasp gets ``upper`` > 0. A grasp that is not force closure gets
the separating wrench of its verdict, mapped to (c, L), as ``direction``: no contact
does positive work on it (within CERTIFICATE_TOL), so ``upper`` is 0 or within
``ZERO_UPPER_TOL`` of the wrench scale.
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .._kernels.jit import kernel_array
from ..model.grasp_input import GraspBatch, prepare_grasps, unit_vectors
from ..pipeline import check_force_closure, run_pipeline
from ..tolerances import MAX_ABS_COORDINATE
from . import epsilon_kernels

BUDGETS = ("l1", "linf")

#: Smallest accepted rtol. The certificates lose ~1e-13 of the wrench scale to
#: rounding; below 1e-9 a small epsilon could not be bracketed that tightly.
MIN_RTOL = 1e-9

#: Support points per grasp before the search gives up (``converged`` False, bounds
#: still valid): far above what random grasps need at rtol 1e-6 (docs/epsilon.md#cost).
MAX_SUPPORT_POINTS = 2000

#: Facets per grasp before the search gives up (how fast the surface grows:
#: docs/epsilon.md#how-it-is-computed). With MAX_SUPPORT_POINTS it sizes the search's
#: arrays (~11 MB, kept per thread).
MAX_FACETS = 1 << 16

#: Support points and facets of :func:`warm_up`'s own workspace: the kernels' types do
#: not depend on the sizes, and a small one is not kept (the full one is ~11 MB).
WARM_UP_POINTS, WARM_UP_FACETS = 128, 1 << 13

#: A grasp that is not force closure counts as ``converged`` when its ``upper`` is at
#: most this fraction of its wrench scale: the separating wrench of its verdict is only
#: accepted within CERTIFICATE_TOL (1e-6) of max_j |a_j| as well.
ZERO_UPPER_TOL = 1e-6



def _seed_directions() -> np.ndarray:
    """The first support points' directions (19, 6): the 7 vertices of a regular
    simplex, then +-each axis, all in an orthonormal frame chosen at random once (seed
    fixed) so that no grasp's symmetry lines up with them."""
    frame = np.linalg.qr(np.random.default_rng(20_240_611).standard_normal((6, 6)))[0].T
    centred = np.eye(7) - 1.0 / 7.0                       # 7 points summing to 0, in R^7
    simplex = centred @ np.linalg.svd(centred)[2][:6].T   # ... in their 6-D span
    simplex /= np.linalg.norm(simplex, axis=1, keepdims=True)
    return np.ascontiguousarray(np.vstack([simplex, frame, -frame]) @ frame)


#: Directions of the first support points (:func:`_seed_directions`).
SEED_DIRECTIONS = _seed_directions()


class EpsilonNotConverged(RuntimeWarning):
    """Warned by :func:`epsilon_quality` when some grasps' bounds miss the requested
    accuracy (``converged`` False): the bounds are still certified, only wider. It names
    how many grasps and the widest gap; ``warnings.simplefilter("error",
    EpsilonNotConverged)`` makes it an exception, ``"ignore"`` silences it."""


@dataclass(frozen=True)
class EpsilonResult:
    """Certified bounds on epsilon: 0-d arrays (direction (6,)) for one grasp, (N,) for
    a batch.

    Attributes
    ----------
    lower, upper : ndarray of float
        lower <= epsilon <= upper; where ``converged``, upper - lower <= rtol * upper
        (force closure) or upper <= ZERO_UPPER_TOL x the wrench scale (not force closure).
    direction : ndarray, shape (6,) or (N, 6)
        Unit wrench (force, torque / L about ``center``) with upper = h(direction).
    force_closure : ndarray of bool
        The verdict of :func:`.pipeline.check_force_closure` the bounds agree with.
    converged : ndarray of bool
        The bounds meet the requested accuracy (see ``lower``, ``upper``). False where
        the search ran out of budget or could not certify a thin surface (bounds still
        valid), and for grasps that are not force closure without a separating wrench
        (marginal or rank-deficient ones).
    center : ndarray, shape (3,) or (N, 3)
        The centre c used.
    torque_scale : ndarray of float
        The torque scale L used.
    support_points : ndarray of int
        Support points the search took (0 where the verdict's wrench sufficed).
    """

    lower: np.ndarray
    upper: np.ndarray
    direction: np.ndarray
    force_closure: np.ndarray
    converged: np.ndarray
    center: np.ndarray
    torque_scale: np.ndarray
    support_points: np.ndarray


def epsilon_quality(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike, *,
                    center: npt.ArrayLike = (0.0, 0.0, 0.0),
                    torque_scale: npt.ArrayLike | None = None, rtol: float = 1e-3,
                    budget: str = "l1",
                    torsional_friction: npt.ArrayLike = 0.0) -> EpsilonResult:
    """Certified Ferrari-Canny epsilon with circular friction cones (module docstring).

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0: one for all, one per grasp ((N, 1)) or per contact.
    center : array_like, shape (3,) or (N, 3)
        Centre c of the torques, in the positions' frame and unit.
    torque_scale : None, float or array_like of shape (N,)
        L, a length (> 0): torques are divided by it. None: the largest |p_i - c| of
        each grasp (1 where every contact is at c).
    rtol : float
        Relative accuracy: upper - lower <= rtol * upper, MIN_RTOL <= rtol < 1; smaller
        is slower (docs/epsilon.md#cost).
    budget : {"l1", "linf"}
        Sum of the normal forces <= 1 (Q1, default), or each normal force <= 1.
    torsional_friction : float or array_like broadcastable to (N, n)
        gamma of soft fingers (a length, >= 0); 0 (default): hard contacts.

    Returns
    -------
    EpsilonResult

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact (or the argument) and the value.

    Warns
    -----
    EpsilonNotConverged
        If the bounds of some grasps miss ``rtol`` (``converged`` False): how many, and
        the grasp with the widest relative gap.
    """
    linf = _budget_is_linf(budget)
    rtol = _checked_rtol(rtol)
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    centre = _centres(center, grasps.positions.shape[0])
    scale = _torque_scales(torque_scale, grasps.positions, centre)
    rows = _Rows(*wrench_rows(grasps, centre, scale), grasps.mu, linf)
    force_closure, separating = _verdicts(positions, normals, mu, torsional_friction, grasps)
    has_wrench = ~np.isnan(separating).any(axis=1)

    n_grasps = force_closure.shape[0]
    lower, upper = np.zeros(n_grasps), np.zeros(n_grasps)
    direction = np.zeros((n_grasps, 6))
    status = np.full(n_grasps, epsilon_kernels.CONVERGED)
    points = np.zeros(n_grasps, dtype=np.int64)
    searched = np.flatnonzero(force_closure | ~has_wrench)
    if searched.size:
        lower[searched], upper[searched], direction[searched], points[searched], \
            status[searched] = _search(rows.subset(searched), rtol)
    separated = np.flatnonzero(~force_closure & has_wrench)
    if separated.size:
        direction[separated] = _to_frame(separating[separated], centre[separated],
                                         scale[separated])
        upper[separated] = _certified_uppers(rows.subset(separated), direction[separated])
    # The verdicts decide: no lower bound above 0 without force closure, where epsilon
    # is 0 up to the separating wrench's tolerance.
    lower[~force_closure] = 0.0
    converged = np.where(force_closure, status == epsilon_kernels.CONVERGED,
                         upper <= ZERO_UPPER_TOL * rows.wrench_scale)
    if not converged.all():
        _warn_not_converged(lower, upper, converged, rtol)
    return EpsilonResult(
        lower=grasps.unbatch(lower), upper=grasps.unbatch(upper),
        direction=grasps.unbatch(direction), force_closure=grasps.unbatch(force_closure),
        converged=grasps.unbatch(converged), center=grasps.unbatch(centre),
        torque_scale=grasps.unbatch(scale), support_points=grasps.unbatch(points))


def warm_up() -> None:
    """Compile (or load from numba's cache) the search's kernels, both budgets, on a
    force-closure tetrahedron grasp, in a small workspace of its own, so that the calling
    thread keeps no full one (:func:`search_workspace` makes that at its first real
    search). The problem is a run-time code, so these also serve the position radius's
    search (``TORQUE_INRADIUS``).
    """
    corners = np.array([[[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]])
    grasps = prepare_grasps(corners, -corners, 0.5)
    arrays = epsilon_kernels.workspace(WARM_UP_POINTS, WARM_UP_FACETS)
    for linf in (False, True):
        rows = _Rows(*wrench_rows(grasps, np.zeros((1, 3)), np.ones(1)), grasps.mu, linf)
        direction = epsilon_kernels.epsilon_batch(
            rows.normal_rows, rows.tangent_rows, rows.mu, rows.wrench_scale, rows.problem,
            1e-3, SEED_DIRECTIONS, arrays)[2]
        _certified_uppers(rows, kernel_array(direction))


def _warn_not_converged(lower: np.ndarray, upper: np.ndarray, converged: np.ndarray,
                        rtol: float) -> None:
    """Warn :class:`EpsilonNotConverged`: how many of the (N,) grasps missed ``rtol``,
    and the one with the widest gap relative to its upper bound."""
    missed = np.flatnonzero(~converged)
    gaps = (upper[missed] - lower[missed]) / upper[missed]   # upper > 0 where missed
    worst = int(missed[np.argmax(gaps)])
    warnings.warn(
        f"epsilon_quality: {missed.size} of {converged.size} grasps did not converge to "
        f"rtol {rtol:g}; widest gap: grasp {worst}, {lower[worst]:.6g} <= epsilon <= "
        f"{upper[worst]:.6g} ((upper - lower) / upper = {gaps.max():.2g}). The bounds are "
        "still certified, only wider; EpsilonResult.converged says which grasps "
        "(docs/epsilon.md#what-is-returned)", EpsilonNotConverged, stacklevel=3)


def _verdicts(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
              torsional_friction: npt.ArrayLike,
              grasps: GraspBatch) -> tuple[np.ndarray, np.ndarray]:
    """Force closure (N,) from :func:`.pipeline.check_force_closure` (its one-grasp fast
    path where it applies), and the separating wrenches (N, 6) of the grasps that are
    not (NaN where none; the certificates are computed for those grasps only)."""
    verdict = check_force_closure(positions, normals, mu, margin="bound",
                                  torsional_friction=torsional_friction)
    force_closure = np.atleast_1d(verdict.force_closure)
    separating = np.full((force_closure.size, 6), np.nan)
    others = np.flatnonzero(~force_closure)
    if others.size:
        torsional = None if grasps.torsional is None else grasps.torsional[others]
        subset = GraspBatch(grasps.positions[others], grasps.normals[others],
                            grasps.mu[others], False, torsional)
        separating[others] = run_pipeline(subset, use_filter="auto", margin="bound",
                                          certificates=True).separating_wrench
    return force_closure, separating


@dataclass(frozen=True)
class _Rows:
    """A batch's wrench rows (:func:`wrench_rows`), friction, rounding scale and budget."""

    normal_rows: np.ndarray
    tangent_rows: np.ndarray
    mu: np.ndarray
    linf: bool
    wrench_scale: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "mu", kernel_array(self.mu))
        object.__setattr__(self, "wrench_scale", _wrench_scale(
            self.normal_rows, self.tangent_rows, self.mu, self.linf))

    def subset(self, index: np.ndarray) -> _Rows:
        return _Rows(self.normal_rows[index], self.tangent_rows[index], self.mu[index],
                     self.linf)

    @property
    def problem(self) -> int:
        """The kernels' code of this budget's epsilon."""
        return epsilon_kernels.EPSILON_LINF if self.linf else epsilon_kernels.EPSILON_L1


def wrench_rows(grasps: GraspBatch, centre: np.ndarray,
                scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-contact wrench rows in the frame (c, L), as :mod:`.epsilon_kernels` takes them.

    Returns
    -------
    normal_rows : ndarray, shape (N, n, 6)
        w_i(n_i) = (n_i, r_i x n_i), r_i = (p_i - c) / L.
    tangent_rows : ndarray, shape (N, n, 3, 6)
        w_i(t1_i), w_i(t2_i) for an orthonormal tangent basis, and the soft-finger row
        (0, gamma_i / (mu_i L) n_i) (zero for hard contacts).
    """
    normals = grasps.normals
    lever = (grasps.positions - centre[:, None, :]) / scale[:, None, None]
    first, second = _tangent_basis(normals)
    normal_rows = np.concatenate([normals, np.cross(lever, normals)], axis=-1)
    tangent_rows = np.zeros(normals.shape[:2] + (3, 6))
    tangent_rows[..., 0, :3], tangent_rows[..., 0, 3:] = first, np.cross(lever, first)
    tangent_rows[..., 1, :3], tangent_rows[..., 1, 3:] = second, np.cross(lever, second)
    if grasps.torsional is not None:
        twist = grasps.torsional / (grasps.mu * scale[:, None])
        tangent_rows[..., 2, 3:] = twist[..., None] * normals
    return kernel_array(normal_rows), kernel_array(tangent_rows)


def _tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (..., 3) completing each unit normal to an orthonormal frame."""
    helper = np.zeros_like(normals)
    use_x = np.abs(normals[..., 0]) < 0.9
    helper[use_x, 0] = 1.0
    helper[~use_x, 1] = 1.0
    first = unit_vectors(np.cross(normals, helper))
    return first, np.cross(normals, first)


def _wrench_scale(normal_rows: np.ndarray, tangent_rows: np.ndarray, mu: np.ndarray,
                  linf: bool) -> np.ndarray:
    """Per grasp, an upper bound on |support point| (N,): the scale of the rounding
    allowances (an L-infinity support point sums one point per contact)."""
    reach = (np.linalg.norm(normal_rows, axis=-1)
             + mu * np.linalg.norm(tangent_rows, axis=-1).sum(axis=-1))
    return kernel_array(reach.sum(axis=1) if linf else reach.max(axis=1))


_WORKSPACES = threading.local()


def search_workspace() -> epsilon_kernels.Workspace:
    """This thread's search arrays (:func:`.epsilon_kernels.workspace`), made once:
    allocated per call they cost as much as a grasp's search (docs/epsilon.md#cost).
    Shared by every search of the thread (epsilon, the position radius)."""
    arrays = getattr(_WORKSPACES, "arrays", None)
    if arrays is None:
        arrays = _WORKSPACES.arrays = epsilon_kernels.workspace(MAX_SUPPORT_POINTS,
                                                                MAX_FACETS)
    return arrays


def _search(rows: _Rows,
            rtol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The compiled search on a batch: lower, upper, direction, points, status (N,)."""
    lower, upper, direction, points, status = epsilon_kernels.epsilon_batch(
        rows.normal_rows, rows.tangent_rows, rows.mu, rows.wrench_scale, rows.problem, rtol,
        SEED_DIRECTIONS, search_workspace())
    stalled = status != epsilon_kernels.CONVERGED
    if stalled.any():
        # Marginal or rank-deficient grasps: a wrench no contact works on, if any.
        null = _least_worked_directions(rows.normal_rows[stalled], rows.tangent_rows[stalled])
        null_upper = _certified_uppers(rows.subset(np.flatnonzero(stalled)), null)
        better = null_upper < upper[stalled]
        index = np.flatnonzero(stalled)[better]
        upper[index], direction[index] = null_upper[better], null[better]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return lower, upper, direction, points, status


def _least_worked_directions(normal_rows: np.ndarray, tangent_rows: np.ndarray) -> np.ndarray:
    """Per grasp the unit direction that the wrench rows span least (N, 6): the normal
    of W's span for a rank-deficient grasp map, on which no contact does work; signed
    so that the normal rows' work on it sums to at most 0."""
    rows = np.concatenate([normal_rows[:, :, None, :], tangent_rows[:, :, :2, :]], axis=2)
    rows = rows.reshape(rows.shape[0], -1, 6)
    _, _, vt = np.linalg.svd(rows)
    least = vt[:, -1, :]
    sign = np.where(np.einsum("gic,gc->g", normal_rows, least) > 0, -1.0, 1.0)
    return kernel_array(least * sign[:, None])


def _certified_uppers(rows: _Rows, directions: np.ndarray) -> np.ndarray:
    """Upper bounds, valid despite rounding, on h(direction / |direction|) (N,)."""
    return epsilon_kernels.certified_upper_batch(
        rows.normal_rows, rows.tangent_rows, rows.mu, rows.wrench_scale, rows.problem,
        kernel_array(directions))


def _to_frame(wrench: np.ndarray, centre: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Caller-frame wrenches (force, torque about the origin) (N, 6) as unit directions
    in the frame (c, L): the same work vector a_i = w_f + w_t x p_i at every contact is
    u_f + u_t x (p_i - c) / L with u_t = L w_t and u_f = w_f + w_t x c."""
    torque = wrench[:, 3:] * scale[:, None]
    force = wrench[:, :3] + np.cross(wrench[:, 3:], centre)
    direction = np.concatenate([force, torque], axis=1)
    return kernel_array(direction / np.linalg.norm(direction, axis=1, keepdims=True))


def _budget_is_linf(budget: str) -> bool:
    if budget not in BUDGETS:
        raise ValueError(f"budget must be one of {BUDGETS}, got {budget!r}")
    return budget == "linf"


def _checked_rtol(rtol: float) -> float:
    value = float(rtol)
    if not MIN_RTOL <= value < 1.0:
        raise ValueError(f"rtol must be in [{MIN_RTOL:g}, 1), got {rtol!r}")
    return value


def _centres(center: npt.ArrayLike, n_grasps: int) -> np.ndarray:
    """``center`` as (N, 3): one for all grasps or one per grasp, finite and within
    MAX_ABS_COORDINATE."""
    value = np.asarray(center)
    if np.iscomplexobj(value) or not np.issubdtype(value.dtype, np.number):
        raise ValueError(f"center must be real numbers, got {value.dtype}")
    value = value.astype(np.float64)
    if value.shape not in ((3,), (n_grasps, 3)):
        raise ValueError(f"center must have shape (3,) or ({n_grasps}, 3), got {value.shape}")
    value = np.broadcast_to(value, (n_grasps, 3))
    bad = ~(np.abs(value) <= MAX_ABS_COORDINATE).all(axis=1)
    if bad.any():
        g = int(np.flatnonzero(bad)[0])
        raise ValueError(f"center of grasp {g} is not finite or beyond "
                         f"+-{MAX_ABS_COORDINATE:.3g}: {value[g].tolist()}")
    return np.ascontiguousarray(value)


def _torque_scales(torque_scale: npt.ArrayLike | None, positions: np.ndarray,
                   centre: np.ndarray) -> np.ndarray:
    """L per grasp (N,): the given one (> 0, finite) or the largest |p_i - c|."""
    n_grasps = positions.shape[0]
    if torque_scale is None:
        offsets = positions - centre[:, None, :]
        largest = np.abs(offsets).max(axis=(1, 2))
        safe = np.where(largest > 0, largest, 1.0)
        # Divide by the largest coordinate first: squares of ~1e300 overflow.
        norms = np.linalg.norm(offsets / safe[:, None, None], axis=-1).max(axis=1) * safe
        return np.where(largest > 0, norms, 1.0)
    value = np.asarray(torque_scale)
    if np.iscomplexobj(value) or not np.issubdtype(value.dtype, np.number):
        raise ValueError(f"torque_scale must be real numbers, got {value.dtype}")
    value = value.astype(np.float64)
    if value.shape not in ((), (n_grasps,)):
        raise ValueError(f"torque_scale must be a number or have shape ({n_grasps},), "
                         f"got {value.shape}")
    value = np.broadcast_to(value, (n_grasps,))
    bad = ~((value > 0) & np.isfinite(value))
    if bad.any():
        g = int(np.flatnonzero(bad)[0])
        raise ValueError(f"torque_scale of grasp {g} must be a finite length > 0, "
                         f"got {value[g]!r}")
    return np.ascontiguousarray(value)
