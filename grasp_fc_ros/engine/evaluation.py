"""Packed grasps in, verdicts out: the node's evaluation, without ROS.

The node (and its worker processes) work on a *packed* representation of many grasps,
:class:`~.packed.PackedGrasps` (the layout of ``ContactArrayBatch``). :func:`evaluate` decides
every grasp of it with :func:`grasp_fc_ros.core.check_force_closure`, one batched core
call per contact count, applies the default friction and says what is wrong with each
bad grasp as an :class:`InvalidGrasp` (grasp, contact, reason).

This module imports numpy and the core only, so worker processes can import it fast
and tests can call it without DDS.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from grasp_fc_ros.core import (
    ForceClosureResult,
    Status,
    check_force_closure,
    epsilon_quality,
    minimum_friction,
    validate_grasps,
)
from grasp_fc_ros.core.tolerances import MARGIN_TOL
from grasp_fc_ros.engine.robustness import assess_group
from grasp_fc_ros.packed import (
    ASSESSMENT_FIELDS,
    MIN_CONTACTS,
    PackedGrasps,
    RobustnessQuery,
    Settings,
    Verdicts,
)

#: The fields of Assessments with one row per contact (the others have one per grasp).
_PER_CONTACT = ("witness_positions", "witness_normals", "witness_friction")


@dataclass(frozen=True)
class InvalidGrasp:
    """Why one grasp cannot be evaluated.

    Attributes
    ----------
    grasp : int
        Index of the grasp in its :class:`PackedGrasps`.
    contact : int or None
        Index of the first bad contact within the grasp, None for grasp-level problems.
    reason : str
        What is wrong, e.g. "normal has zero length".
    """

    grasp: int
    contact: int | None
    reason: str

    def describe(self, packed: PackedGrasps) -> str:
        """The verdict message: 'grasp 3 (id 1003), contact 2: normal has zero length'."""
        where = packed.label(self.grasp)
        if self.contact is not None:
            where += f", contact {self.contact}"
        return f"{where}: {self.reason}"


def effective_friction(mu: np.ndarray, default: float) -> np.ndarray:
    """Contact friction with values exactly 0 (the messages' "not given") replaced by
    ``default``; shape kept.

    Negative values, NaN and +-inf stay, so that validation rejects them (INVALID_INPUT).
    """
    return np.where(mu == 0, default, mu)


def find_invalid(packed: PackedGrasps, mu: np.ndarray, settings: Settings
                 ) -> list[InvalidGrasp]:
    """Every grasp of ``packed`` that cannot be evaluated, with its first problem.

    ``mu`` is the effective friction per contact, (K,). Contacts are checked one by one
    through the core's :func:`validate_grasps` in one vectorised call: each contact,
    doubled, is a two-contact grasp of its own, so the core names the bad contact's
    problem and this function knows its index without reading any message text.
    """
    problems = []
    counts = packed.counts
    wrong_size = (counts < MIN_CONTACTS) | (counts > settings.max_contacts)
    for g in np.flatnonzero(wrong_size):
        problems.append(InvalidGrasp(int(g), None, (
            f"{counts[g]} contacts; a grasp needs {MIN_CONTACTS} to "
            f"max_contacts={settings.max_contacts}")))
    if not len(mu) or _all_contacts_valid(packed, mu):
        return problems
    torsional = 0.0 if packed.torsional is None else np.repeat(
        packed.torsional[:, None], 2, axis=1)
    doubled = validate_grasps(np.repeat(packed.positions[:, None], 2, axis=1),
                              np.repeat(packed.normals[:, None], 2, axis=1),
                              np.repeat(mu[:, None], 2, axis=1), torsional)
    bad_contacts = np.flatnonzero(~doubled.valid)
    if not len(bad_contacts):
        return problems
    owner = np.searchsorted(np.cumsum(counts), bad_contacts, side="right")
    starts = packed.starts
    seen = set(np.flatnonzero(wrong_size).tolist())
    for k, g in zip(bad_contacts.tolist(), owner.tolist(), strict=True):
        if g in seen:
            continue  # report the first problem of a grasp only
        seen.add(g)
        # The core's reason reads "grasp k, contact 0: <what>"; keep <what>.
        what = doubled.reasons[k].split(": ", 1)[-1]
        if -np.inf < packed.mu[k] < 0:  # finite and negative: 0 was perhaps meant
            what += f" (0 uses the node's friction_coefficient, {settings.friction_coefficient:g})"
        problems.append(InvalidGrasp(g, k - int(starts[g]), what))
    return sorted(problems, key=lambda p: p.grasp)


def _all_contacts_valid(packed: PackedGrasps, mu: np.ndarray) -> bool:
    """True iff no contact has a problem: all contacts as one grasp through the core's
    :func:`validate_grasps`, whose all-valid fast path is cheaper than the per-contact
    call (tuned: docs/performance.md#worker-chunks)."""
    if len(mu) < MIN_CONTACTS:
        return False
    torsional = 0.0 if packed.torsional is None else packed.torsional[None]
    return bool(validate_grasps(packed.positions[None], packed.normals[None], mu[None],
                                torsional).valid[0])


def evaluate(packed: PackedGrasps, settings: Settings) -> tuple[Verdicts, dict]:
    """Decide every grasp of ``packed``; one verdict per grasp, in order.

    Parameters
    ----------
    packed : PackedGrasps
        N grasps, any mix of contact counts.
    settings : Settings
        Read once: every grasp is decided with the same values.

    Returns
    -------
    verdicts : Verdicts
        Length N. Invalid grasps get ``INVALID_INPUT`` and a message naming grasp and
        contact; a core failure in one contact-count group gets ``SOLVER_FAILURE`` for
        that group only. With ``settings.certificates`` it carries ``contact_forces``
        and ``separating_wrench`` (verified by the core in the query's frame, on exactly
        these arrays); with ``settings.compute_min_friction`` ``min_friction``: the
        core's :func:`minimum_friction` with ratios = each contact's effective friction
        over the grasp's largest, so the grasp is force closure when its largest
        coefficient exceeds mu* (the others scaled along) and not below it; with
        ``settings.compute_epsilon`` ``epsilon_lower`` and ``epsilon_upper``: the
        core's :func:`epsilon_quality` at its default accuracy, torques about the
        frame's origin (see :func:`group_epsilon`); with ``settings.robustness``
        ``robustness``, the grasps' :class:`~grasp_fc_ros.packed.Assessments`
        (:func:`.robustness.assess_group`; what could not be computed is said in the
        messages).
    seconds : dict
        Time spent: ``validation_s`` (0 where the core validated the grasps inside its
        own call: one grasp, or grasps of one size), ``filter_s``, ``exact_s``
        (certificates included) and, if computed, ``min_friction_s``, ``epsilon_s``
        and ``robustness_s`` (s).
    """
    lone = _decide_lone_grasp(packed, settings)
    if lone is not None:
        return lone
    n_grasps = len(packed)
    if n_grasps > settings.max_batch:
        verdicts = Verdicts.failed_grasps(packed, settings, Status.INVALID_INPUT, "")
        verdicts.messages = [f"{n_grasps} grasps exceed max_batch={settings.max_batch}"
                             ] * n_grasps
        return verdicts, {}
    mu = effective_friction(packed.mu, settings.friction_coefficient)
    if _one_size(packed, settings):
        try:
            return _decide_groups(packed, mu, settings, [np.arange(n_grasps)], 0.0,
                                  invalid_raises=True)
        except ValueError:
            pass  # an invalid grasp: the general path says which contact is wrong
    start = time.perf_counter()
    eligible = np.ones(n_grasps, bool)
    problems = find_invalid(packed, mu, settings)
    for problem in problems:
        eligible[problem.grasp] = False
    counts = packed.counts
    groups = [np.flatnonzero(eligible & (counts == n)) for n in np.unique(counts[eligible])]
    verdicts, seconds = _decide_groups(packed, mu, settings, groups,
                                       time.perf_counter() - start)
    for problem in problems:
        verdicts.messages[problem.grasp] = problem.describe(packed)
    return verdicts, seconds


def _one_size(packed: PackedGrasps, settings: Settings) -> bool:
    """Whether all grasps of ``packed`` have one accepted contact count: then
    :func:`evaluate` gives them to the core as they are, in one call that validates
    them (views of the packed arrays, no per-group indexing), and takes the general
    path only if the core finds an invalid grasp: no validation, grouping and indexing
    of its own (tuned: docs/performance.md#worker-chunks)."""
    counts = packed.counts
    return (len(counts) > 1 and MIN_CONTACTS <= counts[0] <= settings.max_contacts
            and bool((counts == counts[0]).all()))


def _decide_groups(packed: PackedGrasps, mu: np.ndarray, settings: Settings,
                   groups: list[np.ndarray], validation_s: float,
                   invalid_raises: bool = False) -> tuple[Verdicts, dict]:
    """Verdicts of ``packed`` with the grasps of each group (same contact count, in
    order) decided by one core call; grasps in no group stay ``INVALID_INPUT``.

    A core failure in a group makes that group ``SOLVER_FAILURE``; with
    ``invalid_raises`` a ValueError (the core's word for invalid input) is raised
    instead.
    """
    verdicts = Verdicts.failed_grasps(packed, settings, Status.INVALID_INPUT, "")
    seconds = {"validation_s": validation_s, "filter_s": 0.0, "exact_s": 0.0}
    if settings.compute_min_friction:
        seconds["min_friction_s"] = 0.0
    if settings.compute_epsilon:
        seconds["epsilon_s"] = 0.0
    if settings.robustness is not None:
        seconds["robustness_s"] = 0.0
    starts = packed.starts
    min_friction = verdicts.min_friction  # an array when the settings ask for mu*
    for group in groups:
        n = int(packed.counts[group[0]])
        rows = starts[group, None] + np.arange(n)
        try:
            result = _check_group(_core_arguments(packed, rows, mu, settings), packed, rows,
                                  settings)
        except Exception as exc:  # noqa: BLE001 - one group must not spoil the others
            if invalid_raises and isinstance(exc, ValueError):
                raise
            verdicts.status[group] = Status.SOLVER_FAILURE
            for i in group:
                verdicts.messages[i] = f"internal error: {exc}"
            continue
        verdicts.status[group] = result.status
        verdicts.force_closure[group] = result.force_closure
        verdicts.margin[group] = result.margin
        for key in ("filter_s", "exact_s"):
            seconds[key] += result.timing.get(key, 0.0)
        if settings.certificates:
            _store_certificates(verdicts, result, group, rows)
        if min_friction is not None:
            began = time.perf_counter()
            try:
                min_friction[group] = group_min_friction(
                    packed.positions[rows], packed.normals[rows], mu[rows],
                    None if packed.torsional is None else packed.torsional[rows])
            except Exception as exc:  # noqa: BLE001 - an optional extra: verdicts stand
                for i in group:
                    verdicts.messages[i] = f"min_friction not computed: {exc}"
            seconds["min_friction_s"] += time.perf_counter() - began
        if settings.compute_epsilon:
            seconds["epsilon_s"] += _store_epsilon(verdicts, packed, group, rows, mu)
        if settings.robustness is not None:
            seconds["robustness_s"] += _store_assessments(verdicts, packed, group, rows, mu,
                                                          settings.robustness)
    return verdicts, seconds


def _store_assessments(verdicts: Verdicts, packed: PackedGrasps, group: np.ndarray,
                       rows: np.ndarray, mu: np.ndarray, query: RobustnessQuery) -> float:
    """Put the robustness of the grasps ``group`` (contacts ``rows``) into ``verdicts``
    (made with rows not computed by :meth:`Verdicts.failed_grasps`); what could not be
    computed is said in the messages. Returns the seconds it took."""
    assessments = verdicts.robustness
    assert assessments is not None, "verdicts made without assessments"
    began = time.perf_counter()
    torsional = None if packed.torsional is None else packed.torsional[rows]
    try:
        found, problems = assess_group(
            packed.positions[rows], packed.normals[rows], mu[rows],
            torsional if torsional is not None and torsional.any() else None, query,
            packed.ids[group])
        for name in ASSESSMENT_FIELDS:
            getattr(assessments, name)[rows.reshape(-1) if name in _PER_CONTACT
                                       else group] = getattr(found, name)
    except Exception as exc:  # noqa: BLE001 - the verdicts stand; the message says why
        problems = [f"robustness not computed: {exc}"]
    for problem in problems:
        for i in group:
            verdicts.messages[i] = "; ".join(m for m in (verdicts.messages[i], problem) if m)
    return time.perf_counter() - began


def _store_epsilon(verdicts: Verdicts, packed: PackedGrasps, group: np.ndarray,
                   rows: np.ndarray, mu: np.ndarray) -> float:
    """Put the epsilon bounds of the grasps ``group`` (contacts ``rows``) into
    ``verdicts`` (made with NaN bounds by :meth:`Verdicts.failed_grasps`); a failure
    leaves them NaN and says so in the messages. Returns the seconds it took."""
    lower, upper = verdicts.epsilon_lower, verdicts.epsilon_upper
    assert lower is not None and upper is not None, "verdicts made without epsilon"
    began = time.perf_counter()
    try:
        lower[group], upper[group] = group_epsilon(
            packed.positions[rows], packed.normals[rows], mu[rows],
            None if packed.torsional is None else packed.torsional[rows])
    except Exception as exc:  # noqa: BLE001 - an optional extra: verdicts stand
        for i in group:
            verdicts.messages[i] = f"epsilon not computed: {exc}"
    return time.perf_counter() - began


def warm_up_epsilon() -> None:
    """Compile (or load from numba's cache) the epsilon kernels :func:`group_epsilon`
    uses, on a force-closure tetrahedron grasp: a cold compilation takes far longer
    than a chunk (docs/epsilon.md#cost)."""
    corners = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0],
                        [-1.0, -1.0, 1.0]])
    group_epsilon(corners[None], -corners[None], np.full((1, 4), 0.5))


def group_epsilon(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                  torsional: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Certified Ferrari-Canny epsilon bounds of validated same-size grasps.

    The core's :func:`epsilon_quality` with its defaults: the L1 budget (normal forces
    summing to at most 1), torques about the origin of the query's frame divided by the
    grasp's largest contact distance from it (so the bounds are unitless and do not
    change when the grasp is scaled about that origin), rtol 1e-3.

    Parameters
    ----------
    positions, normals : (G, n, 3) float64
    mu : (G, n) float64
        Effective friction per contact (> 0).
    torsional : (G, n) float64 or None
        Torsional friction per contact (m; 0 or None: hard contacts).

    Returns
    -------
    lower, upper : (G,) float64
        lower <= epsilon <= upper; lower > 0 only for force-closure grasps.
    """
    result = epsilon_quality(positions, normals, mu,
                             torsional_friction=0.0 if torsional is None else torsional)
    return result.lower, result.upper


def _store_certificates(verdicts: Verdicts, result: ForceClosureResult, group: np.ndarray,
                        rows: np.ndarray) -> None:
    """Copy the certificates of the grasps ``group`` (contacts ``rows``) from the core's
    ``result`` into ``verdicts`` (made with certificates by
    :meth:`Verdicts.failed_grasps`)."""
    forces, wrenches = verdicts.contact_forces, verdicts.separating_wrench
    assert forces is not None and wrenches is not None, "verdicts made without certificates"
    forces[rows] = result.contact_forces
    if verdicts.contact_torques is not None:
        verdicts.contact_torques[rows] = result.contact_torques
    wrenches[group] = result.separating_wrench


def _decide_lone_grasp(packed: PackedGrasps, settings: Settings
                       ) -> tuple[Verdicts, dict] | None:
    """:func:`evaluate` of one hard grasp with one friction coefficient and no extras, in
    one core call that also validates it; None where the general path must decide.

    A service call or a lone single query is such a grasp: one the general path would
    give the core in its one-grasp form (:func:`_core_arguments`). The general path
    validates it first (per contact, so that it can name a bad one) and then calls the
    core, which validates it again; this path makes the same core call
    (:func:`_check_group`) alone, so the verdict is the same, sooner (tuned:
    docs/performance.md#one-grasp). Invalid input makes the core raise ValueError: the
    general path then decides the grasp again and says which contact is wrong.
    """
    if (len(packed) != 1 or settings.compute_min_friction or settings.compute_epsilon
            or settings.robustness is not None
            or not MIN_CONTACTS <= packed.counts[0] <= settings.max_contacts):
        return None
    mu = effective_friction(packed.mu, settings.friction_coefficient)
    rows = np.arange(packed.counts[0])[None]
    arguments = _core_arguments(packed, rows, mu, settings)
    if not isinstance(arguments[2], float):
        return None  # mixed friction, soft contacts or certificates
    try:
        result = _check_group(arguments, packed, rows, settings)
    except ValueError:  # invalid input: the general path says what and where
        return None
    except Exception as exc:  # noqa: BLE001 - as a failing group of the general path
        return Verdicts.failed(packed.ids, Status.SOLVER_FAILURE, f"internal error: {exc}"), {}
    verdicts = Verdicts(ids=packed.ids, force_closure=np.array([result.force_closure]),
                        status=np.array([result.status], dtype=np.uint8),
                        margin=np.array([result.margin], dtype=np.float64), messages=[""])
    # The core validated the grasp inside this call, not timed apart: validation_s 0.
    return verdicts, {"validation_s": 0.0, "filter_s": result.timing.get("filter_s", 0.0),
                      "exact_s": result.timing.get("exact_s", 0.0)}


# (positions, normals, mu) as the core takes them: see _core_arguments.
CoreArguments = tuple[np.ndarray, np.ndarray, "np.ndarray | float"]


def _check_group(arguments: CoreArguments, packed: PackedGrasps, rows: np.ndarray,
                 settings: Settings) -> ForceClosureResult:
    """The core's result for the same-size grasps ``rows`` (G, n) of ``packed``, given
    their :func:`_core_arguments`, with the filter and certificates the settings ask."""
    positions, normals, mu = arguments
    return check_force_closure(
        positions, normals, mu, use_filter="auto" if settings.use_filter else False,
        origins=settings.filter_origins, certificates=settings.certificates,
        torsional_friction=0.0 if packed.torsional is None else packed.torsional[rows])


def _core_arguments(packed: PackedGrasps, rows: np.ndarray, mu: np.ndarray,
                    settings: Settings) -> CoreArguments:
    """(positions, normals, mu) of the same-size grasps ``rows`` (G, n) for the core.

    A lone hard grasp with one friction coefficient, without certificates, goes as
    (n, 3) arrays and a float: the core's one-grasp compiled path (the same verdict),
    faster than a batch of one, which a single query waits for
    (docs/performance.md#one-grasp).
    """
    if (len(rows) == 1 and packed.torsional is None and not settings.certificates
            and (mu[rows[0]] == mu[rows[0, 0]]).all()):
        return packed.positions[rows[0]], packed.normals[rows[0]], float(mu[rows[0, 0]])
    if rows.size == len(packed.positions):  # every contact, in order: views, no copies
        shape = rows.shape
        return (packed.positions.reshape(*shape, 3), packed.normals.reshape(*shape, 3),
                mu.reshape(shape))
    return packed.positions[rows], packed.normals[rows], mu[rows]


def group_min_friction(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                       torsional: np.ndarray | None = None) -> np.ndarray:
    """mu* of validated same-size grasps, in units of each grasp's largest friction.

    Parameters
    ----------
    positions, normals : (G, n, 3) float64
    mu : (G, n) float64
        Effective friction per contact (> 0); the query's proportions between contacts
        are kept (ratios = mu / max mu of the grasp).
    torsional : (G, n) float64 or None
        Torsional friction per contact (m; 0 or None: hard contacts).

    Returns
    -------
    (G,) float64
        :func:`grasp_fc_ros.core.quality.minimum_friction` with ``margin=MARGIN_TOL``: the
        boundary of the node's own verdicts (FORCE_CLOSURE needs a margin of
        MARGIN_TOL), so a verdict at friction above mu* is FORCE_CLOSURE and below it
        is not. The force-closure boundary itself (margin 0) lies a little lower, where
        check_force_closure can still say no just above it
        (docs/performance.md#minimum-friction). Always > 0; inf: no friction up to
        MU_CAP; NaN: not certified.
    """
    return minimum_friction(positions, normals, mu / mu.max(axis=1, keepdims=True),
                            margin=MARGIN_TOL,
                            torsional_friction=0.0 if torsional is None else torsional)


# --- contact forces for a load (the compute_contact_forces service) ----------------------


