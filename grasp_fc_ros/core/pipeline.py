"""The filtered pipeline: the torque filter first, the exact test on the survivors
(paper section V, Fig. 4b), and on request the certificates behind each verdict.

The margin
----------
``margin`` is the force-closure margin t*: how deep inside every friction cone an
equilibrating internal force can be (mu f_n - |f_t|, normal forces summing to one; 0
for a grasp map of rank < 6). Both ends reported are certified:
``margin <= t* <= margin_upper``. ``margin="optimum"`` (default) narrows the interval to
MARGIN_ACCURACY (1e-8) where the fast stage decides (Clarabel's ~1e-8 accuracy on its
fallback grasps); ``margin="bound"`` stops at the verdict, which is faster
(docs/performance.md#exact-stage), and reports whatever interval was certified by then
(often wide).

Soft contacts
-------------
``torsional_friction`` (gamma, a length in the positions' unit, broadcastable like mu;
0 = hard, the default) makes contacts soft fingers (:mod:`.contact_model`): the margin
is then mu f_n - |(f_t, mu tau / gamma)|, the exact test runs on the Clarabel path
only, and certificates carry the torsional moments in ``contact_torques``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from ._kernels.jit import kernel_array
from .exact.certificates import normalise_positions, to_caller_wrench, verify_batch
from .exact.exact_test import MARGIN_CHOICES, ExactResult, solve_exact
from .exact.interior_point import FORCE_CLOSURE, NOT_FORCE_CLOSURE
from .filter.one_grasp_filter import MAX_FILTER_CONTACTS
from .filter.torque_space_filter import (
    FILTER_PAYS_UP_TO_CONTACTS,
    ORIGIN_CHOICES,
    passes_torque_filter,
    resolve_use_filter,
)
from .model.grasp_input import MIN_CONTACTS, GraspBatch, prepare_grasps
from .one_grasp import (
    ALL_ORIGINS,
    FILTERED_OUT,
    GENERAL_PATH,
    MAX_FAST_CONTACTS,
    SEED_ORIGINS,
    check_one,
    decide_one,
)


class Status(IntEnum):
    """How a grasp was decided; also the ``uint8`` status codes of the ROS messages.

    0 is UNKNOWN, so that a zero-initialised verdict never reads as a decision (the ROS
    message convention; interface 1.0, before which FORCE_CLOSURE was 0)."""

    UNKNOWN = 0            #: no verdict: a zero-initialised message (never produced)
    FORCE_CLOSURE = 1      #: the exact test found a verified strictly internal force
    NOT_FORCE_CLOSURE = 2  #: decided by the exact test (incl. a rank-deficient grasp map)
    FILTERED_OUT = 3       #: rejected by the torque filter: certainly not force closure
    INVALID_INPUT = 4      #: bad input (produced by callers that validate per grasp)
    SOLVER_FAILURE = 5     #: the solver could not decide, even after a retry


# Plain integers for the per-call path: an IntEnum attribute lookup is a noticeable part
# of a one-grasp call (docs/performance.md#one-grasp).
_FORCE_CLOSURE, _NOT_FORCE_CLOSURE, _FILTERED_OUT, _SOLVER_FAILURE = (
    int(Status.FORCE_CLOSURE), int(Status.NOT_FORCE_CLOSURE), int(Status.FILTERED_OUT),
    int(Status.SOLVER_FAILURE))

#: The one-grasp path's status scalars (numpy scalars are immutable: shared), by the
#: code of :mod:`.one_grasp`; and its NaN margin.
_STATUS = {FORCE_CLOSURE: np.uint8(_FORCE_CLOSURE), NOT_FORCE_CLOSURE: np.uint8(_NOT_FORCE_CLOSURE),
           FILTERED_OUT: np.uint8(_FILTERED_OUT)}
_NAN = np.float64(np.nan)
_FLOAT64 = np.dtype(np.float64)
_FLOATS, _INTEGERS = (float, np.floating), (int, np.integer)
# The one-grasp path's names, bound once: each global and attribute lookup is a
# noticeable part of its call (docs/performance.md#one-grasp).
_NDARRAY, _FLOAT, _TRUE, _FALSE = np.ndarray, np.float64, np.True_, np.False_
_clock = time.perf_counter


@dataclass(frozen=True)
class ForceClosureResult:
    """Verdicts of :func:`check_force_closure`: (N,) arrays for a batch, their elements
    (numpy scalars) for one grasp (annotated in the batch form, see :mod:`.grasp_input`).

    Attributes
    ----------
    force_closure : ndarray of bool
        The grasp is force closure.
    filtered_out : ndarray of bool
        Rejected by the torque filter; the exact test was not run.
    margin : ndarray of float
        A certified lower bound on the margin t* (see the module docstring).
        NaN where the exact test was not run.
    status : ndarray of uint8
        A :class:`Status` code per grasp.
    timing : dict
        Seconds spent in ``"filter_s"`` and ``"exact_s"``.
    margin_upper : ndarray of float
        A certified upper bound on t* (inf where none was found, NaN where the exact
        test was not run).
    contact_forces : ndarray, shape (n, 3) or (N, n, 3), or None
        With ``certificates=True``: for FORCE_CLOSURE grasps an internal force in the
        caller's frame (normal parts summing to one, in equilibrium about the caller's
        origin, strictly inside every cone), checked by
        :func:`.certificates.verify_certificates`; NaN for other grasps.
    separating_wrench : ndarray, shape (6,) or (N, 6), or None
        With ``certificates=True``: for FILTERED_OUT and NOT_FORCE_CLOSURE grasps a unit
        wrench (force, torque about the caller's origin) on which no contact force does
        positive work (within CERTIFICATE_TOL), checked likewise; NaN where none.
        Soft contacts count the work of their torsional moments too.
    marginal : ndarray of bool, or None
        With ``certificates=True``: NOT_FORCE_CLOSURE (or FILTERED_OUT) grasps without
        a separating wrench: 0 < t* < MARGIN_TOL, so internal forces exist but too close
        to the cone boundaries; or a grasp map of rank < 6 (e.g. collinear contacts)
        whose only separating wrenches do zero work at every contact, which rounding
        blurs beyond the relative CERTIFICATE_TOL check.
    contact_torques : ndarray, shape (n,) or (N, n), or None
        With ``certificates=True`` and soft contacts (some torsional_friction > 0): the
        torsional moment tau_i about each normal of ``contact_forces`` (force times the
        positions' unit; 0 at hard contacts), part of the same verified certificate;
        NaN where ``contact_forces`` is. None for hard grasps.
    """

    force_closure: np.ndarray
    filtered_out: np.ndarray
    margin: np.ndarray
    status: np.ndarray
    timing: dict[str, float] = field(default_factory=dict)
    margin_upper: np.ndarray | None = None
    contact_forces: np.ndarray | None = None
    separating_wrench: np.ndarray | None = None
    marginal: np.ndarray | None = None
    contact_torques: np.ndarray | None = None

    @classmethod
    def of_one(cls, force_closure: np.generic, filtered_out: np.generic, margin: np.generic,
               status: np.generic, margin_upper: np.generic,
               timing: dict[str, float]) -> ForceClosureResult:
        """The result of one grasp without certificates, from the numpy scalars a batch
        of one unbatches to (:meth:`.grasp_input.GraspBatch.unbatch`).

        Its fields are set in one step: the frozen ``__init__`` sets each of the ten
        through ``object.__setattr__``, a large part of a one-grasp call
        (docs/performance.md#one-grasp).
        """
        result = object.__new__(cls)
        object.__setattr__(result, "__dict__", {
            "force_closure": force_closure, "filtered_out": filtered_out, "margin": margin,
            "status": status, "timing": timing, "margin_upper": margin_upper,
            "contact_forces": None, "separating_wrench": None, "marginal": None,
            "contact_torques": None})
        return result


_of_one = ForceClosureResult.of_one


def check_force_closure(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                        use_filter: bool | str = "auto", origins: str = "seed",
                        margin: str = "optimum", certificates: bool = False,
                        torsional_friction: npt.ArrayLike | None = 0.0) -> ForceClosureResult:
    """Decide force closure of one grasp or a batch: the filter, then the exact test.

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    use_filter : bool or "auto"
        Run the torque filter first and the exact test only on the grasps it passes.
        The verdicts are the same either way; the filter only saves time. "auto" (the
        default) runs it only where it is measured to pay (:func:`filter_worthwhile`,
        by contact count: up to 4 contacts); its cost is bounded for every n anyway.
    origins : {"seed", "all"}
        Torque origins of the filter (see :func:`torque_filter`).
    margin : {"optimum", "bound"}
        How narrow the certified margin interval must be (see the module docstring).
    certificates : bool
        Also return contact forces, separating wrenches and the ``marginal`` flags,
        each verified in the caller's frame before it is returned.
    torsional_friction : float or array_like broadcastable to (N, n)
        Torsional friction coefficient gamma of each contact (>= 0, a length in the
        positions' unit); 0 (default) is a hard contact. See the module docstring.

    Returns
    -------
    ForceClosureResult

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact.

    Notes
    -----
    One grasp of float64 arrays (n, 3) with a scalar ``mu``, hard contacts and no
    certificates is decided by one compiled call (:mod:`.one_grasp`), the filter
    included where it is to run: the results a batch gives that grasp, without numpy's
    per-call overhead (docs/performance.md#one-grasp).
    """
    hard = torsional_friction is None or (type(torsional_friction) in (int, float)
                                          and torsional_friction == 0)
    quick = (_one_grasp(positions, normals, mu, use_filter, origins, margin)
             if hard and not certificates else None)
    if quick is not None:
        return quick
    return run_pipeline(prepare_grasps(positions, normals, mu, torsional_friction), use_filter,
                        origins, margin, certificates)


def _one_grasp(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
               use_filter: bool | str, origins: str, margin: str) -> ForceClosureResult | None:
    """The result for one grasp of float64 arrays (n, 3) and a scalar mu, decided on the
    compiled path of :mod:`.one_grasp` (the filter too, where it is to run and that path
    takes it); else None.

    ``timing`` puts the compiled call's time under "filter_s" for a grasp the filter
    rejects, under "exact_s" otherwise (the filter's part of it is not measured apart).
    Every step here is on the per-call budget (docs/performance.md#one-grasp).
    """
    if not (type(positions) is _NDARRAY and type(normals) is _NDARRAY
            and (isinstance(mu, _FLOATS)
                 # (a huge int would make float() raise: the general path words it)
                 or (isinstance(mu, _INTEGERS) and abs(int(mu)) <= 2 ** 53))
            # (native float64 arrays share this dtype object; others take the general path)
            and positions.dtype is _FLOAT64 and normals.dtype is _FLOAT64
            and margin in MARGIN_CHOICES):
        return None
    shape = positions.shape
    if not (len(shape) == 2 and shape[1] == 3 and normals.shape == shape
            and MIN_CONTACTS <= shape[0] <= MAX_FAST_CONTACTS):
        return None
    if use_filter == "auto":           # resolve_use_filter's answer, without its checks
        limit = FILTER_PAYS_UP_TO_CONTACTS.get(origins)
        if limit is None:                  # an unknown origins: the general path says so
            return None
        filtered = shape[0] <= limit
    else:
        filtered = resolve_use_filter(use_filter, shape[0], origins)
    if filtered and (shape[0] > MAX_FILTER_CONTACTS or origins not in ORIGIN_CHOICES):
        return None
    flags = positions.flags
    if not (flags.c_contiguous and flags.writeable):
        positions = kernel_array(positions)
    flags = normals.flags
    if not (flags.c_contiguous and flags.writeable):
        normals = kernel_array(normals)
    start = _clock()
    if filtered:
        decided = decide_one(positions, normals, float(mu),
                             ALL_ORIGINS if origins == "all" else SEED_ORIGINS,
                             margin == "optimum")
        if decided[0] == GENERAL_PATH:
            return None
    else:
        found = check_one(positions, normals, float(mu), margin == "optimum")
        if found is None:
            return None
        decided = found
    elapsed = _clock() - start
    code, t_lo, t_hi = decided
    if code == FILTERED_OUT:
        return _of_one(_FALSE, _TRUE, _NAN, _STATUS[code], _NAN,
                       {"filter_s": elapsed, "exact_s": 0.0})
    return _of_one(_TRUE if code == FORCE_CLOSURE else _FALSE, _FALSE,
                   _FLOAT(t_lo if t_lo > 0.0 else 0.0), _STATUS[code], _FLOAT(t_hi),
                   {"filter_s": 0.0, "exact_s": elapsed})


def run_pipeline(grasps: GraspBatch, use_filter: bool | str = True, origins: str = "seed",
                 margin: str = "optimum", certificates: bool = False) -> ForceClosureResult:
    """:func:`check_force_closure` on validated input."""
    n_grasps = grasps.positions.shape[0]
    use_filter = resolve_use_filter(use_filter, grasps.positions.shape[1], origins)
    start = time.perf_counter()
    filter_wrench = None
    if use_filter and certificates:
        passed, filter_wrench = passes_torque_filter(grasps, origins, certificates=True)
    elif use_filter:
        passed = passes_torque_filter(grasps, origins)
    else:
        passed = np.ones(n_grasps, dtype=bool)
    filtered = time.perf_counter()

    survivors = np.flatnonzero(passed)
    exact = solve_exact(grasps if survivors.size == n_grasps else _subset(grasps, survivors),
                        margin, certificates)
    finished = time.perf_counter()

    force_closure = np.zeros(n_grasps, dtype=bool)
    force_closure[survivors] = exact.force_closure
    lower, upper = np.full(n_grasps, np.nan), np.full(n_grasps, np.nan)
    lower[survivors], upper[survivors] = exact.margin, exact.margin_upper
    status = np.full(n_grasps, _FILTERED_OUT, dtype=np.uint8)
    status[survivors] = np.where(
        exact.solver_failure, _SOLVER_FAILURE,
        np.where(exact.force_closure, _FORCE_CLOSURE, _NOT_FORCE_CLOSURE))
    extra = {}
    if certificates:
        extra = _certificates(grasps, survivors, exact, filter_wrench, status)
    return ForceClosureResult(
        force_closure=grasps.unbatch(force_closure),
        filtered_out=grasps.unbatch(~passed),
        margin=grasps.unbatch(lower),
        status=grasps.unbatch(status),
        timing={"filter_s": filtered - start, "exact_s": finished - filtered},
        margin_upper=grasps.unbatch(upper),
        **{key: grasps.unbatch(value) for key, value in extra.items()})


def _subset(grasps: GraspBatch, indices: np.ndarray) -> GraspBatch:
    torsional = None if grasps.torsional is None else grasps.torsional[indices]
    return GraspBatch(grasps.positions[indices], grasps.normals[indices], grasps.mu[indices],
                      single=False, torsional=torsional)


def _certificates(grasps: GraspBatch, survivors: np.ndarray, exact: ExactResult,
                  filter_wrench: np.ndarray | None, status: np.ndarray) -> dict[str, np.ndarray]:
    """Contact forces, separating wrenches and marginal flags, each verified in the
    caller's frame (a certificate that fails its check is replaced by NaN).

    ``filter_wrench`` (N, 6) holds the filter's wrenches of the grasps it rejected
    (NaN rows elsewhere), or None when the filter did not run."""
    n_grasps, n_contacts = grasps.mu.shape
    forces = np.full((n_grasps, n_contacts, 3), np.nan)
    forces[survivors] = exact.forces
    wrench = np.full((n_grasps, 6), np.nan)
    _, centre, size = normalise_positions(grasps.positions[survivors])
    wrench[survivors] = to_caller_wrench(exact.wrench, centre, size)
    if filter_wrench is not None:
        rejected = status == Status.FILTERED_OUT
        wrench[rejected] = filter_wrench[rejected]
    rejected_any = (status == Status.NOT_FORCE_CLOSURE) | (status == Status.FILTERED_OUT)
    torques = None
    if grasps.torsional is not None:
        torques = np.full((n_grasps, n_contacts), np.nan)
        torques[survivors] = exact.torques
    forces_ok, wrench_ok = verify_batch(grasps.positions, grasps.normals, grasps.mu, forces,
                                        wrench, grasps.torsional, torques)
    forces[~forces_ok] = np.nan
    wrench[~wrench_ok] = np.nan
    extra = {"contact_forces": forces, "separating_wrench": wrench,
             "marginal": rejected_any & ~wrench_ok}
    if torques is not None:
        torques[~forces_ok] = np.nan
        extra["contact_torques"] = torques
    return extra


def exact_force_closure(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                        torsional_friction: npt.ArrayLike | None = 0.0) -> np.ndarray:
    """The exact force-closure test alone (no filter), verdicts only.

    The margin is not reported, so the fast stage stops at each verdict instead of
    narrowing the margin to MARGIN_ACCURACY first (``margin="bound"``; the verdicts are
    the same, docs/performance.md#exact-stage).

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
    normals : array_like, same shape as ``positions``
    mu : float or array_like broadcastable to (N, n)
    torsional_friction : float or array_like broadcastable to (N, n)
        gamma of soft contacts (a length); 0 (default): hard contacts.

    Returns
    -------
    numpy bool for one grasp, ndarray of bool, shape (N,), for a batch
        True where the grasp is force closure (with a verified witness).

    Raises
    ------
    ValueError
        On bad input, naming the grasp and contact.
    """
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    return grasps.unbatch(solve_exact(grasps, "bound").force_closure)
