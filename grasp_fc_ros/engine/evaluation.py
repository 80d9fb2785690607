"""Packed grasps in, verdicts out: the node's evaluation, without ROS.

The node (and its worker processes) work on a *packed* representation of many grasps,
:class:`PackedGrasps`: all contacts of all grasps stacked grasp after grasp, plus one
contact count per grasp, the layout of ``ContactArrayBatch``. :func:`evaluate` decides
every grasp of it with :func:`grasp_fc_ros.core.check_force_closure`, one batched core
call per contact count, applies the default friction and says what is wrong with each
bad grasp as an :class:`InvalidGrasp` (grasp, contact, reason).

This module imports numpy and the core only, so worker processes can import it fast
and tests can call it without DDS.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from grasp_fc_ros.core import (
    Status,
    check_force_closure,
    minimum_friction,
    optimal_contact_forces,
    validate_grasps,
)
from grasp_fc_ros.core.tolerances import MARGIN_TOL

# A grasp needs at least two contacts (the core's own minimum, restated for messages).
MIN_CONTACTS = 2


@dataclass(frozen=True)
class Settings:
    """The parameters that decide queries; one snapshot decides a whole message.

    Attributes
    ----------
    friction_coefficient : float
        Used for contacts whose own coefficient is finite and <= 0.
    use_filter : bool
        Run the torque-space filter before the exact test where it pays for the grasp's
        contact count (the core's ``use_filter="auto"``); False: never.
    filter_origins : str
        Torque origins of the filter (``grasp_fc_ros.core.ORIGIN_CHOICES``).
    max_contacts : int
        Largest accepted number of contacts in one grasp.
    max_batch : int
        Largest accepted number of grasps in one message.
    certificates : bool
        Also return each verdict's certificate: contact forces of FORCE_CLOSURE grasps,
        separating wrenches of rejected ones (the core's ``certificates=True``).
    compute_min_friction : bool
        Also return each grasp's minimum friction coefficient (see :func:`evaluate`).
    """

    friction_coefficient: float = 0.5
    use_filter: bool = True
    filter_origins: str = "seed"
    max_contacts: int = 64
    max_batch: int = 100_000
    certificates: bool = False
    compute_min_friction: bool = False


@dataclass
class PackedGrasps:
    """Many grasp queries, stacked contact after contact.

    Attributes
    ----------
    ids : (N,) uint64
        Query id of each grasp.
    counts : (N,) int64
        Number of contacts of each grasp.
    positions : (K, 3) float64
        Contact positions (m), grasp after grasp; K = counts.sum().
    normals : (K, 3) float64
        Inward contact normals, any length (validated by :func:`evaluate`).
    mu : (K,) float64
        Friction coefficient per contact; finite values <= 0 mean "node default"
        (NaN and +-inf are invalid).
    name_by_id : bool
        True when the grasps are separate single-grasp topic queries: messages then
        name a grasp by its query id only ("query id 12"), since its place among the
        queued queries means nothing to the client; otherwise "grasp 3 (id 1003)".
    first_index : int
        Index of grasp 0 of this object in the message it came from (a chunk of a
        batch names its grasps by their index in the whole batch).
    torsional : (K,) float64 or None
        Torsional friction coefficient gamma per contact (m; 0: a hard contact; soft
        fingers, see ``grasp_fc_ros.core.contact_model``); None: every contact hard.
        Negative, NaN and inf are invalid.
    """

    ids: np.ndarray
    counts: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    name_by_id: bool = False
    first_index: int = 0
    torsional: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def starts(self) -> np.ndarray:
        """(N,) int64 index of each grasp's first contact in the stacked arrays."""
        return np.concatenate(([0], np.cumsum(self.counts)[:-1])).astype(np.int64)

    def label(self, index: int) -> str:
        """How messages name grasp ``index`` of this object."""
        if self.name_by_id:
            return f"query id {self.ids[index]}"
        return f"grasp {self.first_index + index} (id {self.ids[index]})"

    def chunks(self, max_contacts: int) -> list[PackedGrasps]:
        """Split into consecutive pieces of at most ``max_contacts`` contacts each.

        A grasp is never split; a single grasp larger than the bound is a chunk alone.
        """
        ends = np.cumsum(self.counts)
        pieces, first = [], 0
        while first < len(self):
            base = ends[first - 1] if first else 0
            last = int(np.searchsorted(ends, base + max_contacts, side="right"))
            last = max(last, first + 1)
            pieces.append(self.slice(first, last))
            first = last
        return pieces

    def slice(self, first: int, last: int) -> PackedGrasps:
        """Grasps ``first:last`` as a PackedGrasps of their own (arrays are views)."""
        starts = self.starts
        lo = int(starts[first]) if first < len(self) else 0
        hi = lo + int(self.counts[first:last].sum())
        return PackedGrasps(ids=self.ids[first:last], counts=self.counts[first:last],
                            positions=self.positions[lo:hi], normals=self.normals[lo:hi],
                            mu=self.mu[lo:hi], name_by_id=self.name_by_id,
                            first_index=self.first_index + first,
                            torsional=None if self.torsional is None else self.torsional[lo:hi])


@dataclass
class Verdicts:
    """One verdict per grasp, as parallel arrays (the ForceClosureVerdictArray layout).

    Attributes
    ----------
    ids : (N,) uint64
    force_closure : (N,) bool
    status : (N,) uint8
        ``grasp_fc_ros.core.Status`` codes.
    margin : (N,) float64
        NaN where the exact test was not run.
    messages : list[str]
        Length N; empty where there is nothing to say.
    contact_forces : (K, 3) float64 or None
        Certificates of FORCE_CLOSURE grasps: one internal force per contact (N per N of
        total grip), grasp after grasp in the query's contact order (K contacts in all);
        NaN rows for the contacts of other grasps. None: not computed.
    contact_torques : (K,) float64 or None
        With ``contact_forces`` where the query has soft-finger contacts: the moment
        about each contact's normal (N m per N of total grip; 0 at hard contacts).
        None: not computed, or every contact hard.
    separating_wrench : (N, 6) float64 or None
        Unit wrench (force N, torque N m about the origin) that FILTERED_OUT and
        NOT_FORCE_CLOSURE grasps cannot resist; NaN rows where there is none. None: not
        computed.
    min_friction : (N,) float64 or None
        Minimum friction coefficient mu* of each grasp; NaN where not computed (invalid
        input, or not certified). None: not computed for any grasp.
    """

    ids: np.ndarray
    force_closure: np.ndarray
    status: np.ndarray
    margin: np.ndarray
    messages: list[str]
    contact_forces: np.ndarray | None = None
    contact_torques: np.ndarray | None = None
    separating_wrench: np.ndarray | None = None
    min_friction: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def failed(cls, ids, status: Status, message: str) -> Verdicts:
        """Every grasp ``ids`` answered with ``status`` and the same ``message``."""
        ids = np.asarray(ids, dtype=np.uint64)
        n = len(ids)
        return cls(ids=ids, force_closure=np.zeros(n, bool),
                   status=np.full(n, status, dtype=np.uint8), margin=np.full(n, np.nan),
                   messages=[message] * n)

    @classmethod
    def failed_grasps(cls, packed: PackedGrasps, settings: Settings, status: Status,
                      message: str) -> Verdicts:
        """:meth:`failed` for every grasp of ``packed``, with the optional fields that
        ``settings`` ask for present and NaN (so that the verdicts of a failed part
        join those of the other parts of a message without emptying their fields)."""
        n_grasps, n_contacts = len(packed), len(packed.positions)
        verdicts = cls.failed(packed.ids, status, message)
        if settings.certificates:
            verdicts.contact_forces = np.full((n_contacts, 3), np.nan)
            if packed.torsional is not None:
                verdicts.contact_torques = np.full(n_contacts, np.nan)
            verdicts.separating_wrench = np.full((n_grasps, 6), np.nan)
        if settings.compute_min_friction:
            verdicts.min_friction = np.full(n_grasps, np.nan)
        return verdicts

    @classmethod
    def concatenate(cls, parts: list[Verdicts]) -> Verdicts:
        """The verdicts of ``parts``, one after the other."""
        if not parts:
            return cls.failed([], Status.INVALID_INPUT, "")
        return cls(ids=np.concatenate([p.ids for p in parts]),
                   force_closure=np.concatenate([p.force_closure for p in parts]),
                   status=np.concatenate([p.status for p in parts]),
                   margin=np.concatenate([p.margin for p in parts]),
                   messages=[m for p in parts for m in p.messages],
                   **{name: _concatenate_optional([getattr(p, name) for p in parts])
                      for name in OPTIONAL_FIELDS})


# The optional per-grasp results of Verdicts, computed only when the settings ask.
OPTIONAL_FIELDS = ("contact_forces", "contact_torques", "separating_wrench", "min_friction")


def _concatenate_optional(arrays: list) -> np.ndarray | None:
    """Concatenate an optional field of every part; None if any part lacks it (all
    parts of one message are decided with the same settings)."""
    if any(a is None for a in arrays):
        return None
    return np.concatenate(arrays)


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
    """Contact friction with finite values <= 0 replaced by ``default``; shape kept.

    NaN and +-inf stay, so that validation rejects them as not finite.
    """
    return np.where(np.isfinite(mu) & (mu <= 0), default, mu)


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
    for k, g in zip(bad_contacts.tolist(), owner.tolist()):
        if g in seen:
            continue  # report the first problem of a grasp only
        seen.add(g)
        # The core's reason reads "grasp k, contact 0: <what>"; keep <what>.
        what = doubled.reasons[k].split(": ", 1)[-1]
        problems.append(InvalidGrasp(g, k - int(starts[g]), what))
    return sorted(problems, key=lambda p: p.grasp)


def _all_contacts_valid(packed: PackedGrasps, mu: np.ndarray) -> bool:
    """True iff no contact has a problem: all contacts as one grasp through the core's
    :func:`validate_grasps`, whose all-valid fast path is cheaper than the per-contact
    call (measured: 23 against 28 us for one 6-finger grasp, 41 against 155 us for a
    chunk of 682)."""
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
        coefficient exceeds mu* (the others scaled along) and not below it.
    seconds : dict
        Time spent: ``validation_s`` (0 where the core validated the grasps inside its
        own call: one grasp, or grasps of one size), ``filter_s``, ``exact_s``
        (certificates included) and, if computed, ``min_friction_s`` (s).
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
    path only if the core finds an invalid grasp. Measured on a worker's chunk of 666
    6-finger grasps: the general path's validation, grouping and indexing took ~0.4 ms
    of its ~10 ms."""
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
    starts = packed.starts
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
            verdicts.contact_forces[rows] = result.contact_forces
            if verdicts.contact_torques is not None:
                verdicts.contact_torques[rows] = result.contact_torques
            verdicts.separating_wrench[group] = result.separating_wrench
        if settings.compute_min_friction:
            began = time.perf_counter()
            try:
                verdicts.min_friction[group] = group_min_friction(
                    packed.positions[rows], packed.normals[rows], mu[rows],
                    None if packed.torsional is None else packed.torsional[rows])
            except Exception as exc:  # noqa: BLE001 - an optional extra: verdicts stand
                for i in group:
                    verdicts.messages[i] = f"min_friction not computed: {exc}"
            seconds["min_friction_s"] += time.perf_counter() - began
    return verdicts, seconds


def _decide_lone_grasp(packed: PackedGrasps, settings: Settings
                       ) -> tuple[Verdicts, dict] | None:
    """:func:`evaluate` of one hard grasp with one friction coefficient and no extras, in
    one core call that also validates it; None where the general path must decide.

    A service call or a lone single query is such a grasp: one the general path would
    give the core in its one-grasp form (:func:`_core_arguments`). The general path
    validates it first (per contact, so that it can name a bad one) and then calls the
    core, which validates it again; this path makes the same core call
    (:func:`_check_group`) alone, so the verdict is the same. Measured on one 6-finger
    grasp: 35 against 117 us. Invalid input makes the core raise ValueError: the general
    path then decides the grasp again and says which contact is wrong.
    """
    if (len(packed) != 1 or settings.compute_min_friction
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


def _check_group(arguments: tuple, packed: PackedGrasps, rows: np.ndarray,
                 settings: Settings):
    """The core's result for the same-size grasps ``rows`` (G, n) of ``packed``, given
    their :func:`_core_arguments`, with the filter and certificates the settings ask."""
    return check_force_closure(
        *arguments, use_filter="auto" if settings.use_filter else False,
        origins=settings.filter_origins, certificates=settings.certificates,
        torsional_friction=0.0 if packed.torsional is None else packed.torsional[rows])


def _core_arguments(packed: PackedGrasps, rows: np.ndarray, mu: np.ndarray,
                    settings: Settings) -> tuple:
    """(positions, normals, mu) of the same-size grasps ``rows`` (G, n) for the core.

    A lone hard grasp with one friction coefficient, without certificates, goes as
    (n, 3) arrays and a float: the core's one-grasp compiled path (the same verdict),
    ~0.3 ms less than a batch of one, which a single query waits for.
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
        :func:`grasp_fc_ros.core.minimum_friction` with ``margin=MARGIN_TOL``: the
        boundary of the node's own verdicts (FORCE_CLOSURE needs a margin of
        MARGIN_TOL), so a verdict at friction above mu* is FORCE_CLOSURE and below it
        is not. The force-closure boundary itself (margin 0) lies a little lower
        (measured on 300 random 6-finger box grasps: median 3e-5 relative), and there
        check_force_closure still says no on 38 of them at mu*(1 + 1e-3). Always > 0;
        inf: no friction up to MU_CAP; NaN: not certified.
    """
    return minimum_friction(positions, normals, mu / mu.max(axis=1, keepdims=True),
                            margin=MARGIN_TOL,
                            torsional_friction=0.0 if torsional is None else torsional)


# --- contact forces for a load (the compute_contact_forces service) ----------------------

#: Names of the wrench's six components, for messages.
WRENCH_COMPONENTS = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")


@dataclass(frozen=True)
class ContactForces:
    """The answer to one grasp-force optimisation request.

    Attributes
    ----------
    feasible : bool
        Forces inside the cones (and under the limits) balance the load.
    max_normal_force : float
        The least largest normal force s* (N); inf when infeasible, NaN when the request
        is invalid or the solver could not decide.
    contact_forces : (n, 3) float64
        The optimal force per contact (N); shape (0, 3) unless feasible.
    contact_torques : (n,) float64
        The torsional moment about each contact's normal (N m; 0 at hard contacts);
        shape (0,) unless feasible.
    message : str
        Empty, or why there is no answer (naming the query and contact).
    """

    feasible: bool
    max_normal_force: float
    contact_forces: np.ndarray
    contact_torques: np.ndarray
    message: str = ""

    @classmethod
    def refused(cls, message: str) -> ContactForces:
        """No answer: ``message`` says why."""
        return cls(False, float("nan"), np.empty((0, 3)), np.empty(0), message)

    @classmethod
    def infeasible(cls, max_normal_force: float) -> ContactForces:
        """No forces hold the load (s* = inf), or none within the limits."""
        return cls(False, max_normal_force, np.empty((0, 3)), np.empty(0))


def contact_forces_for_load(packed: PackedGrasps, wrench, max_normal_forces,
                            settings: Settings) -> ContactForces:
    """Least-largest-normal-force contact forces of one grasp holding a load.

    Parameters
    ----------
    packed : PackedGrasps
        Exactly one grasp of n contacts (friction <= 0: the default of ``settings``).
    wrench : (6,) float
        External load: force (N) then torque (N m) about the frame's origin.
    max_normal_forces : (0,) or (n,) float
        Per-contact normal-force limits (N, >= 0, inf: none); empty for no limits.
    settings : Settings

    Returns
    -------
    ContactForces
        From :func:`grasp_fc_ros.core.optimal_contact_forces`; an invalid request is
        refused with a message naming the query, and the contact where one is at fault.
    """
    if len(packed) != 1:
        raise ValueError(f"one grasp expected, got {len(packed)}")
    mu = effective_friction(packed.mu, settings.friction_coefficient)
    problems = find_invalid(packed, mu, settings)
    if problems:
        return ContactForces.refused(problems[0].describe(packed))
    label = packed.label(0)
    wrench = np.asarray(wrench, dtype=np.float64).reshape(6)
    bad = np.flatnonzero(~np.isfinite(wrench))
    if bad.size:
        return ContactForces.refused(
            f"{label}: wrench {WRENCH_COMPONENTS[bad[0]]} is not finite ({wrench[bad[0]]})")
    limits = np.asarray(max_normal_forces, dtype=np.float64).reshape(-1)
    n_contacts = int(packed.counts[0])
    if len(limits) not in (0, n_contacts):
        return ContactForces.refused(f"{label}: {len(limits)} max_normal_forces for "
                                     f"{n_contacts} contacts (need one per contact or none)")
    bad = np.flatnonzero(np.isnan(limits) | (limits < 0))
    if bad.size:
        return ContactForces.refused(
            f"{label}, contact {bad[0]}: max_normal_force must be >= 0 (inf: no limit), "
            f"got {limits[bad[0]]}")
    torsional = np.zeros(n_contacts) if packed.torsional is None else packed.torsional
    s_star, forces, torques = optimal_contact_forces(
        packed.positions, packed.normals, mu, wrench, limits if len(limits) else None,
        torsional_friction=torsional)
    s_star = float(s_star)
    if math.isnan(s_star):
        return ContactForces.refused(f"{label}: the solver could not decide")
    if math.isinf(s_star):
        return ContactForces.infeasible(s_star)
    return ContactForces(True, s_star, forces, torques)
