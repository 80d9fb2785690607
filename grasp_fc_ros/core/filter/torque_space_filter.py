"""The torque-space filter: a necessary condition for force closure (paper section III).

If a grasp is force closure its wrenches positively span R^6, so their projections on
torque space positively span R^3 for every choice of origin (Proposition 3.1). The
filter tries a few origins placed at contact points (whose own torque set is then null
and is left out) and rejects the grasp when the torque sets of the other contacts fail
to positively span R^3 about any of them.

Origins:

* ``"seed"`` -- the paper's choice. q is the contact with the smallest x coordinate
  minus (1, 0, 0), a point outside the contacts' convex hull; the origins are the
  contacts nearest to and furthest from q.
* ``"all"`` -- every contact in turn (for more than ``MAX_ALL_ORIGINS`` contacts: the
  seed's two and contacts spread evenly over the list, ``MAX_ALL_ORIGINS`` in all).
  Still sound, and rejects more grasps that are not force closure, at n/2 times the
  cost.

Soft contacts (torsional friction gamma > 0, :mod:`.contact_model`): a soft contact's
torque set about an origin is {r x f + tau n} with (f, tau) in its elliptic cone, which
lies in its hard fan (plane, {0}) plus the line along its normal n. The filter uses
exactly that superset: every soft contact, the origin contact included, adds the line
{tau n} (generators n and -n, :func:`.torque_sets.normal_lines`). A rejection then
needs a direction c perpendicular (within SPAN_TOL) to every soft normal, so grasps with
three soft contacts of independent normals always pass (they are passed at once, without
their torque sets, :func:`soft_normals_span`); the filter stays sound and catches
non-force-closure grasps whose soft normals lie in one plane. Its
certificate wrenches are checked with the soft work term (:func:`does_no_positive_work`).

The seed origins depend on the coordinate frame and on the length unit (the offset
(1, 0, 0) is in the caller's unit), as in the paper: which non-force-closure grasps
the filter catches can change with them. Its soundness, and so every final verdict,
does not.

Certificates: a rejection about origin contact o comes with a separating direction c
of the torque sets; the pure torque c about o, written about the caller's origin, is a
wrench no contact force does positive work on (:func:`separating_wrench`), and it is
checked in numpy before it is returned (:func:`does_no_positive_work`).

Cost: bounded for every contact count (memory per pass by ``_MAX_LEVER_ARMS_PER_PASS``,
time per origin about O(n log n), see :mod:`.positive_span`), but it pays only while
its hit rate times the exact test's cost exceeds its own cost: the pipeline's
``use_filter="auto"`` asks :func:`filter_worthwhile`, whose numbers are the one table
``FILTER_PAYS_UP_TO_CONTACTS``. ``origins="all"`` costs n / 2 times ``"seed"``, at most
``MAX_ALL_ORIGINS`` / 2.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, TypeAlias, overload

import numpy as np
import numpy.typing as npt

from ..model.contact_model import largest_work
from ..model.grasp_input import GraspBatch, prepare_grasps
from ..tolerances import CERTIFICATE_TOL, SOFT_SPAN_TOL, WORK_ROUNDING_ULPS
from .positive_span import positively_spans
from .torque_sets import concatenate, cone_torque_sets, dot, friction_half_angle_sine, normal_lines

ORIGIN_CHOICES = ("seed", "all")

#: (origin (K,), grasp (K,)) -> (spans (K,), separating directions (3, K) or None without
#: certificates): do the other contacts' torque sets about contact origin[k] of
#: grasp[k] positively span R^3?
SpansAbout: TypeAlias = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray | None]]

#: What an origin schedule returns: passing (N,), and with certificates the origin each
#: rejected grasp failed about (N,) and the separating direction found there (3, N).
OriginVerdicts: TypeAlias = tuple[np.ndarray, np.ndarray | None, np.ndarray | None]

#: Most origins ``"all"`` tries. Each costs about O(n log n), so every contact as an
#: origin would cost O(n^2 log n), far more than the exact test of a grasp of thousands
#: of contacts (docs/performance.md#filter). Past 64 contacts the filter does not pay
#: anyway.
MAX_ALL_ORIGINS = 64

#: Largest contact count at which the filter saves more exact-test time than it costs
#: (hit rate x exact cost per grasp > filter cost per grasp), per origin choice, on
#: batches, against the fast exact stage (tuned: docs/performance.md#filter, from
#: benchmarks/bench_filter.py). Re-run the benchmark and update when either stage
#: changes.
FILTER_PAYS_UP_TO_CONTACTS = {"seed": 4, "all": 4}

#: From this many grasps on, origins are tried one after another so that grasps
#: already rejected skip the rest; below it, all origins go in one pass, which pays
#: numpy's per-call overhead once instead of once per origin (tuned:
#: docs/performance.md#filter).
_ONE_ORIGIN_AT_A_TIME_MIN_GRASPS = 256

#: Lever arms handled per vectorised pass (problems x contacts): bounds the memory of
#: the torque sets and their intermediates (a few tens of MB) whatever the batch size
#: and contact count; large enough that numpy's per-call overhead stays negligible.
_MAX_LEVER_ARMS_PER_PASS = 2 ** 17


def filter_worthwhile(n_contacts: int, origins: str = "seed") -> bool:
    """Whether running the filter before the exact test is expected to save time.

    Parameters
    ----------
    n_contacts : int
        Contacts per grasp.
    origins : {"seed", "all"}

    Returns
    -------
    bool
        True up to ``FILTER_PAYS_UP_TO_CONTACTS[origins]`` contacts.
    """
    if origins not in FILTER_PAYS_UP_TO_CONTACTS:
        raise ValueError(f"origins must be one of {ORIGIN_CHOICES}, got {origins!r}")
    return n_contacts <= FILTER_PAYS_UP_TO_CONTACTS[origins]


def resolve_use_filter(use_filter: bool | str, n_contacts: int, origins: str = "seed") -> bool:
    """``use_filter`` of the pipeline as a bool: True and False as given, "auto" by
    :func:`filter_worthwhile`.

    Raises
    ------
    ValueError
        For any other value.
    """
    if isinstance(use_filter, str):
        if use_filter != "auto":
            raise ValueError(f"use_filter must be True, False or 'auto', got {use_filter!r}")
        return filter_worthwhile(n_contacts, origins)
    return bool(use_filter)


def torque_filter(positions: npt.ArrayLike, normals: npt.ArrayLike, mu: npt.ArrayLike,
                  origins: str = "seed", certificates: bool = False,
                  torsional_friction: npt.ArrayLike = 0.0
                  ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Necessary condition for force closure: do the torque sets positively span R^3?

    Parameters
    ----------
    positions : array_like, shape (n, 3) or (N, n, 3)
        Contact positions (any length unit).
    normals : array_like, same shape as ``positions``
        Inward contact normals, any non-zero length.
    mu : float or array_like broadcastable to (N, n)
        Friction coefficients, > 0.
    origins : {"seed", "all"}
        Which contacts serve as torque origins (see module docstring).
    certificates : bool
        Also return a separating wrench for every rejected grasp.
    torsional_friction : float or array_like broadcastable to (N, n)
        gamma of soft contacts (a length, >= 0); 0 (default): hard contacts. Soft
        contacts' torque sets include the line along their normals (module docstring).

    Returns
    -------
    passed : ndarray of bool, shape () for one grasp or (N,)
        True: the grasp passes (it may be force closure). False: it is certainly not
        force closure.
    separating_wrench : ndarray, shape (6,) or (N, 6), only if ``certificates``
        See :func:`passes_torque_filter`.

    Raises
    ------
    ValueError
        On bad input (naming grasp and contact) or an unknown ``origins``.
    """
    grasps = prepare_grasps(positions, normals, mu, torsional_friction)
    if not certificates:
        return grasps.unbatch(passes_torque_filter(grasps, origins))
    passed, wrench = passes_torque_filter(grasps, origins, certificates=True)
    return grasps.unbatch(passed), grasps.unbatch(wrench)


@overload
def passes_torque_filter(grasps: GraspBatch, origins: str = "seed",
                         certificates: Literal[False] = False) -> np.ndarray: ...
@overload
def passes_torque_filter(grasps: GraspBatch, origins: str,
                         certificates: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def passes_torque_filter(grasps: GraspBatch, origins: str = "seed", *,
                         certificates: Literal[True]) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def passes_torque_filter(grasps: GraspBatch, origins: str,
                         certificates: bool) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...


def passes_torque_filter(grasps: GraspBatch, origins: str = "seed",
                         certificates: bool = False
                         ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`torque_filter` on validated input.

    Returns
    -------
    passed : ndarray of bool, shape (N,)
    separating_wrench : ndarray, shape (N, 6), only if ``certificates``
        For each rejected grasp a unit wrench (force part, torque part) in the caller's
        frame, about the caller's origin, that no contact force does positive work on
        (see :func:`separating_wrench`); NaN rows where the grasp passed. Every wrench is
        checked before it is returned; a rejection whose wrench fails the check (only
        nearly collinear grasps come close) is passed on instead, so with certificates
        every rejection has one.
    """
    if grasps.torsional is not None:
        spanned = soft_normals_span(grasps)
        if spanned.any():
            return _pass_spanned(grasps, spanned, origins, certificates)
    # Component-first copies, (3, n, N): the grasp axis becomes the contiguous one.
    points = np.ascontiguousarray(grasps.positions.transpose(2, 1, 0))
    normals = np.ascontiguousarray(grasps.normals.transpose(2, 1, 0))
    sin_half_angle = friction_half_angle_sine(np.ascontiguousarray(grasps.mu.T))
    n_contacts = points.shape[1]
    soft = None if grasps.torsional is None else np.ascontiguousarray(grasps.torsional.T) > 0
    per_pass = max(1, _MAX_LEVER_ARMS_PER_PASS // (n_contacts - 1))

    def spans_about(origin: np.ndarray,
                    grasp: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Do the other contacts' torque sets about contact origin[k] of grasp[k] span?
        With certificates also the separating directions (3, K). Bounded memory."""
        if origin.size > per_pass:
            parts = [spans_about(origin[start:start + per_pass], grasp[start:start + per_pass])
                     for start in range(0, origin.size, per_pass)]
            return (np.concatenate([spans for spans, _ in parts]),
                    np.concatenate([found for _, found in parts], axis=1)
                    if certificates else None)
        others = _other_contacts(origin, n_contacts)                   # (n-1, k)
        lever_arms = points[:, others, grasp] - points[:, origin, grasp][:, None]
        sets = cone_torque_sets(lever_arms, normals[:, others, grasp],
                                sin_half_angle[others, grasp])
        if soft is not None:
            # Every soft contact, the origin's own included, adds the line {tau n}.
            sets = concatenate([sets, normal_lines(normals[:, :, grasp], soft[:, grasp])])
        if certificates:
            return positively_spans(sets, directions=True)
        return positively_spans(sets), None

    origin = _origin_indices(points, origins)                          # (O, N)
    try_origins = (_all_origins_at_once if origin.shape[1] < _ONE_ORIGIN_AT_A_TIME_MIN_GRASPS
                   else _one_origin_at_a_time)
    passing, rejected_about, direction = try_origins(spans_about, origin, certificates)
    if rejected_about is None or direction is None:      # without certificates
        return passing
    return _certify(grasps, passing, rejected_about, direction)


def soft_normals_span(grasps: GraspBatch) -> np.ndarray:
    """Grasps (N,) whose soft contacts' normals span R^3 (within SOFT_SPAN_TOL).

    Their lines {tau n_i} alone positively span R^3 about every origin, so the filter
    passes them whatever the other torque sets are.
    """
    if grasps.torsional is None:
        return np.zeros(grasps.mu.shape[0], dtype=bool)
    soft = (grasps.torsional > 0).astype(np.float64)
    moment = np.einsum("gi,gij,gik->gjk", soft, grasps.normals, grasps.normals)
    return np.linalg.eigvalsh(moment)[:, 0] > SOFT_SPAN_TOL


def _pass_spanned(grasps: GraspBatch, spanned: np.ndarray, origins: str,
                  certificates: bool) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`passes_torque_filter` with the ``spanned`` grasps (N,) passed at once and
    the rest filtered."""
    if origins not in ORIGIN_CHOICES:
        raise ValueError(f"origins must be one of {ORIGIN_CHOICES}, got {origins!r}")
    n_grasps = spanned.size
    passed = np.ones(n_grasps, dtype=bool)
    wrench = np.full((n_grasps, 6), np.nan)
    rest = np.flatnonzero(~spanned)
    if rest.size:
        others = GraspBatch(grasps.positions[rest], grasps.normals[rest], grasps.mu[rest],
                            single=False,
                            torsional=None if grasps.torsional is None else grasps.torsional[rest])
        if certificates:
            passed[rest], wrench[rest] = passes_torque_filter(others, origins, True)
        else:
            passed[rest] = passes_torque_filter(others, origins)
    return (passed, wrench) if certificates else passed


def _all_origins_at_once(spans_about: SpansAbout, origin: np.ndarray,
                         certificates: bool) -> OriginVerdicts:
    """Every origin of every grasp in one pass: numpy's call overhead is paid once.

    Parameters
    ----------
    spans_about : callable
        (origin (K,), grasp (K,)) -> (spans (K,), directions (3, K) or None).
    origin : ndarray of int, shape (O, N)
    certificates : bool

    Returns
    -------
    passing : ndarray of bool, shape (N,)
    rejected_about : ndarray of int, shape (N,), or None without certificates
        The first origin each rejected grasp failed about.
    direction : ndarray, shape (3, N), or None without certificates
        The separating direction found there (NaN for passing grasps).
    """
    n_grasps = origin.shape[1]
    grasp = np.broadcast_to(np.arange(n_grasps), origin.shape)
    spans, found = spans_about(origin.ravel(), grasp.ravel())
    spans = spans.reshape(origin.shape)
    if found is None:                                    # without certificates
        return np.all(spans, axis=0), None, None
    first = (~spans).argmax(axis=0)
    return (np.all(spans, axis=0), origin[first, np.arange(n_grasps)],
            found.reshape((3,) + origin.shape)[:, first, np.arange(n_grasps)])


def _one_origin_at_a_time(spans_about: SpansAbout, origin: np.ndarray,
                          certificates: bool) -> OriginVerdicts:
    """One origin after another: a grasp rejected about one is not tried again.

    Same parameters and returns as :func:`_all_origins_at_once`.
    """
    n_grasps = origin.shape[1]
    passing = np.ones(n_grasps, dtype=bool)
    rejected_about = np.zeros(n_grasps, dtype=np.intp)
    direction = np.full((3, n_grasps), np.nan)
    for row in origin:
        grasp = np.flatnonzero(passing)
        spans, found = spans_about(row[grasp], grasp)
        if found is not None:                            # with certificates
            rejected = grasp[~spans]
            rejected_about[rejected] = row[rejected]
            direction[:, rejected] = found[:, ~spans]
        passing[grasp] = spans
    return (passing, rejected_about, direction) if certificates else (passing, None, None)


def _certify(grasps: GraspBatch, passing: np.ndarray, rejected_about: np.ndarray,
             direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Separating wrenches (N, 6) of the rejected grasps, checked; unchecked ones pass.

    ``direction`` (3, N) has every torque set of grasp g about contact
    ``rejected_about[g]`` on its side, so minus it is the separating torque.
    Returns the updated ``passing`` (N,) and the wrenches, NaN rows where passing.
    """
    wrench = np.full((passing.size, 6), np.nan)
    rejected = np.flatnonzero(~passing)
    origin = rejected_about[rejected]
    torque = -direction[:, rejected].T
    checked = does_no_positive_work(grasps, rejected, origin, torque)
    wrench[rejected[checked]] = separating_wrench(
        grasps.positions[rejected[checked], origin[checked]], torque[checked])
    passing = passing.copy()
    passing[rejected[~checked]] = True
    return passing, wrench


def separating_wrench(origin: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """The pure torque ``torque`` about the point ``origin`` as a unit wrench.

    Parameters
    ----------
    origin : ndarray, shape (R, 3)
        The point o the torque is about, in the caller's frame and length unit.
    torque : ndarray, shape (R, 3)
        Unit direction c, with c . (r_i x f) <= 0 for every force f of every contact's
        cone (r_i = p_i - o).

    Returns
    -------
    ndarray, shape (R, 6)
        w = (o x c, c) / |(o x c, c)|, (force part, torque part) about the caller's
        origin.

    Notes
    -----
    A force f at p does work w_force . f + w_torque . (p x f) on w = (w_force, w_torque)
    about the caller's origin, which is a . f with a = w_force + w_torque x p (cyclic
    triple product). For w = (o x c, c): a = c x p - c x o = c x (p - o), so the work is
    (c x r) . f = c . (r x f) <= 0, the filter's separation about o. The contact at o
    itself has r = 0, hence a = 0: it does no work at all. Scaling w by 1 / |w| keeps
    every sign. The largest work of a cone force with unit normal part,
    n . a + mu |a - (n . a) n|, is therefore <= 0 for every contact.

    A caller recomputing a_i = w_force + w_torque x p_i in floating point gets an
    absolute error of a few eps (|w_force| + |w_torque| |p_i|). Against
    1e-6 max_j |a_j| that matters only for grasps more than ~1e9 of their size away from
    the caller's origin, and for wrenches no contact can do any work on (every a_j
    zero, e.g. the torque about the line of a collinear grasp).
    """
    wrench = np.concatenate((np.cross(origin, torque), torque), axis=1)
    wrench /= np.abs(wrench).max(axis=1, keepdims=True)                # no overflow
    return wrench / np.linalg.norm(wrench, axis=1, keepdims=True)


def does_no_positive_work(grasps: GraspBatch, grasp: np.ndarray, origin: np.ndarray,
                          torque: np.ndarray) -> np.ndarray:
    """Check the pure torques ``torque`` about contacts ``origin`` of grasps ``grasp``.

    Parameters
    ----------
    grasps : GraspBatch
    grasp, origin : ndarray of int, shape (R,)
        Which grasp, and which of its contacts the torque is about.
    torque : ndarray, shape (R, 3)
        Unit torque directions c.

    Returns
    -------
    ndarray of bool, shape (R,)
        For every contact, with a_i = c x (p_i - o) computed with the lever arms scaled
        to at most one (a power of two, exact): n_i . a_i + mu_i |a_i - (n_i . a_i) n_i|
        <= CERTIFICATE_TOL max_j |a_j| + WORK_ROUNDING_ULPS eps (1 + mu_i). Soft batches:
        the work of the torsional moment counts too (gamma scaled like the lever arms,
        :func:`.contact_model.largest_work`), and max_j |a_j| becomes
        max_j |(a_j, gamma_j)|, with gamma_j of the rounding allowance added.
    """
    positions = grasps.positions[grasp]                                # (R, n, 3)
    lever_arms = positions - positions[np.arange(grasp.size), origin][:, None]
    _, exponent = np.frexp(np.abs(lever_arms).max(axis=(1, 2), initial=0.0))
    lever_arms = np.ldexp(lever_arms, -exponent[:, None, None])
    a = np.cross(torque[:, None], lever_arms)
    mu = grasps.mu[grasp]
    if grasps.torsional is None:
        most_work = largest_work(a, grasps.normals[grasp], mu)
        allowed = (CERTIFICATE_TOL * np.linalg.norm(a, axis=2).max(axis=1)[:, None]
                   + WORK_ROUNDING_ULPS * np.finfo(float).eps * (1.0 + mu))
        return (most_work <= allowed).all(axis=1)
    gamma = np.ldexp(grasps.torsional[grasp], -exponent[:, None])
    most_work = largest_work(a, grasps.normals[grasp], mu, torque, gamma)
    size = np.hypot(np.linalg.norm(a, axis=2), gamma).max(axis=1)
    allowed = (CERTIFICATE_TOL * size[:, None]
               + WORK_ROUNDING_ULPS * np.finfo(float).eps * (1.0 + mu + gamma))
    return (most_work <= allowed).all(axis=1)


def _origin_indices(points: np.ndarray, origins: str) -> np.ndarray:
    """Indices (O, N) of the contacts used as origins; ``points`` is (3, n, N)."""
    n_contacts, n_grasps = points.shape[1:]
    if origins == "all" and n_contacts <= MAX_ALL_ORIGINS:
        return np.broadcast_to(np.arange(n_contacts)[:, None], (n_contacts, n_grasps))
    if origins == "all":
        spread = np.linspace(0, n_contacts - 1, MAX_ALL_ORIGINS - 2).round().astype(np.intp)
        return np.concatenate((_origin_indices(points, "seed"),
                               np.broadcast_to(spread[:, None], (spread.size, n_grasps))))
    if origins != "seed":
        raise ValueError(f"origins must be one of {ORIGIN_CHOICES}, got {origins!r}")
    grasp = np.arange(n_grasps)
    q = points[:, points[0].argmin(axis=0), grasp]
    q[0] -= 1.0
    offset = points - q[:, None, :]
    # Scaling each grasp by a power of two is exact, keeps the order of distances, and
    # stops their squares from overflowing for coordinates beyond ~1e154.
    _, exponent = np.frexp(np.abs(offset).max(axis=(0, 1)))
    offset = np.ldexp(offset, -exponent)
    squared_distance = dot(offset, offset)                             # (n, N)
    return np.stack((squared_distance.argmin(axis=0), squared_distance.argmax(axis=0)))


def _other_contacts(origin: np.ndarray, n_contacts: int) -> np.ndarray:
    """Indices (n-1, K) of every contact except origin[k], in order, for each k.

    Computed per call rather than cached as an (n, n-1) table: that table alone is
    800 MB at the 10,000 contacts the node accepts.
    """
    index = np.arange(n_contacts - 1)[:, None]
    return index + (index >= origin[None, :])
