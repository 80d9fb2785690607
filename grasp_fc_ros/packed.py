"""The data the node, its engine and its clients share, without ROS: packed grasps in,
verdicts out, the settings that decide them, and the contact forces that hold a load.

:class:`PackedGrasps` holds many grasps stacked contact after contact plus one contact
count per grasp, the layout of ``ContactArrayBatch``; :class:`Verdicts` the answers, one
row per grasp; :class:`ContactForces` the answer of ``compute_contact_forces``;
:func:`chunk_end` where a run of whole grasps within a budget of contacts ends. Only
numpy and the core's :class:`~grasp_fc_ros.core.Status`: a client imports this module
and no part of the node or its engine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from grasp_fc_ros.core import Status

# A grasp needs at least two contacts (the core's own minimum, restated for messages).
MIN_CONTACTS = 2


@dataclass(frozen=True)
class Settings:
    """The parameters that decide queries; one snapshot decides a whole message.

    Attributes
    ----------
    friction_coefficient : float
        Used for contacts whose own coefficient is 0 (not given).
    use_filter : bool
        Run the torque-space filter before the exact test where it pays for the grasp's
        contact count (the core's ``use_filter="auto"``); False: never.
    filter_origins : str
        Torque origins of the filter (``grasp_fc_ros.core.ORIGIN_CHOICES``).
    max_contacts : int
        Largest accepted number of contacts in one grasp.
    max_batch : int
        Largest accepted number of grasps in one message.
    max_message_contacts : int
        Largest accepted number of contacts in one batch message, label_grasps goal or
        check_force_closure request (0: no limit); the node refuses a larger one whole.
    certificates : bool
        Also return each verdict's certificate: contact forces of FORCE_CLOSURE grasps,
        separating wrenches of rejected ones (the core's ``certificates=True``).
    compute_min_friction : bool
        Also return each grasp's minimum friction coefficient (see :func:`evaluate`).
    compute_epsilon : bool
        Also return each grasp's certified Ferrari-Canny epsilon bounds (the core's
        :func:`~grasp_fc_ros.core.epsilon_quality`; see :func:`evaluate`).
    max_assessment_samples : int
        Largest number of samples (grasps x samples per grasp) one assess_robustness
        request may ask for; the node refuses a larger one whole.
    robustness : RobustnessQuery or None
        Not a parameter: set for an assess_robustness request, whose verdicts then carry
        each grasp's :class:`Assessments` (see :func:`evaluate`).
    """

    friction_coefficient: float = 0.5
    use_filter: bool = True
    filter_origins: str = "seed"
    max_contacts: int = 64
    max_batch: int = 100_000
    max_message_contacts: int = 491_520
    certificates: bool = False
    compute_min_friction: bool = False
    compute_epsilon: bool = False
    max_assessment_samples: int = 1_000_000
    robustness: RobustnessQuery | None = None


@dataclass(frozen=True)
class RobustnessQuery:
    """What an assess_robustness request asks of each of its grasps (the fields of
    ``AssessRobustness.srv``'s request; docs/robustness.md).

    Attributes
    ----------
    position_error, normal_error, friction_error : float
        The errors of :func:`~grasp_fc_ros.core.holds_under` (m, rad, unitless), >= 0.
    position_sigma, normal_sigma, friction_sigma : float
        The random errors of :func:`~grasp_fc_ros.core.probability_of_force_closure`,
        >= 0.
    samples : int
        Samples per grasp (0: no probability).
    confidence : float
        Confidence level of the probability's interval, in (0, 1).
    seed : int
        Root seed; grasp k of the request draws from stream k of it.
    """

    position_error: float = 0.0
    normal_error: float = 0.0
    friction_error: float = 0.0
    position_sigma: float = 0.0
    normal_sigma: float = 0.0
    friction_sigma: float = 0.0
    samples: int = 1000
    confidence: float = 0.95
    seed: int = 0

    def problem(self) -> str:
        """Why the query cannot be answered ('' if it can): which field, which value."""
        for name in ("position_error", "normal_error", "friction_error", "position_sigma",
                     "normal_sigma", "friction_sigma"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                return f"{name} must be finite and >= 0, got {value}"
        if not np.pi >= self.normal_error:
            return f"normal_error must be <= pi rad, got {self.normal_error}"
        if self.samples and not 0.0 < self.confidence < 1.0:
            return f"confidence must be in (0, 1), got {self.confidence}"
        return ""


@dataclass
class Assessments:
    """The robustness of each grasp of a message (an assess_robustness response's arrays
    beside the verdicts): one row per grasp, NaN (0 for ``holds``) where not computed.

    Attributes
    ----------
    normal_angle, position_radius, friction_drop : (N,) float64
        The certified radii of :func:`~grasp_fc_ros.core.robustness` (rad, m, unitless).
    holds : (N,) uint8
        :class:`~grasp_fc_ros.core.Holds` values; 0: not assessed.
    holds_bound : (N,) str
        The sound bound behind HOLDS, '' elsewhere.
    witness_positions, witness_normals : (K, 3) float64
        BREAKS: the witness grasp, grasp after grasp in the query's contact order; NaN
        rows for the contacts of other grasps.
    witness_friction : (K,) float64
        The witness's friction coefficients, laid out likewise.
    separating_wrench : (N, 6) float64
        The exact test's certificate on each witness; NaN rows elsewhere.
    probability, probability_lower, probability_upper : (N,) float64
        The probability of force closure and its Clopper-Pearson interval.
    probability_normal_bound : (N,) float64
        The sample-free lower bound where only normals are noisy; NaN elsewhere.
    """

    normal_angle: np.ndarray
    position_radius: np.ndarray
    friction_drop: np.ndarray
    holds: np.ndarray
    holds_bound: np.ndarray
    witness_positions: np.ndarray
    witness_normals: np.ndarray
    witness_friction: np.ndarray
    separating_wrench: np.ndarray
    probability: np.ndarray
    probability_lower: np.ndarray
    probability_upper: np.ndarray
    probability_normal_bound: np.ndarray

    def __len__(self) -> int:
        return len(self.holds)

    @classmethod
    def not_computed(cls, n_grasps: int, n_contacts: int) -> Assessments:
        """Rows of ``n_grasps`` grasps (``n_contacts`` contacts in all), nothing computed."""
        def nan(*shape: int) -> np.ndarray:
            return np.full(shape, np.nan)

        return cls(normal_angle=nan(n_grasps), position_radius=nan(n_grasps),
                   friction_drop=nan(n_grasps), holds=np.zeros(n_grasps, np.uint8),
                   holds_bound=np.full(n_grasps, "", dtype=object),
                   witness_positions=nan(n_contacts, 3), witness_normals=nan(n_contacts, 3),
                   witness_friction=nan(n_contacts),
                   separating_wrench=nan(n_grasps, 6), probability=nan(n_grasps),
                   probability_lower=nan(n_grasps), probability_upper=nan(n_grasps),
                   probability_normal_bound=nan(n_grasps))

    @classmethod
    def concatenate(cls, parts: list[Assessments]) -> Assessments:
        """The rows of ``parts``, one after the other."""
        return cls(**{name: np.concatenate([getattr(part, name) for part in parts])
                      for name in ASSESSMENT_FIELDS})


#: The fields of :class:`Assessments`, in order.
ASSESSMENT_FIELDS = ("normal_angle", "position_radius", "friction_drop", "holds",
                     "holds_bound", "witness_positions", "witness_normals",
                     "witness_friction", "separating_wrench", "probability",
                     "probability_lower", "probability_upper", "probability_normal_bound")


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
        Friction coefficient per contact; 0 means "node default" (negative values, NaN
        and +-inf are invalid).
    name_by_id : bool
        True when the grasps are separate single-grasp topic queries: messages then
        name a grasp by its query id only ("query id 12"), since its place among the
        queued queries means nothing to the client; otherwise "grasp 3 (id 1003)".
    first_index : int
        Index of grasp 0 of this object in the message it came from (a chunk of a
        batch names its grasps by their index in the whole batch).
    torsional : (K,) float64 or None
        Torsional friction coefficient gamma per contact (m; 0: a hard contact; soft
        fingers, see ``grasp_fc_ros.core.model.contact_model``); None: every contact hard.
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
    epsilon_lower, epsilon_upper : (N,) float64 or None
        Certified bounds lower <= epsilon <= upper on each grasp's Ferrari-Canny epsilon
        (the core's :func:`~grasp_fc_ros.core.epsilon_quality`: L1 budget, torques about
        the frame's origin over the grasp's largest contact distance from it; unitless);
        NaN where not computed (invalid input, a failure). None: not computed for any
        grasp.
    robustness : Assessments or None
        Each grasp's robustness, for an assess_robustness request (settings with a
        ``robustness`` query); None otherwise.
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
    epsilon_lower: np.ndarray | None = None
    epsilon_upper: np.ndarray | None = None
    robustness: Assessments | None = None

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def failed(cls, ids: ArrayLike, status: Status, message: str) -> Verdicts:
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
        if settings.compute_epsilon:
            verdicts.epsilon_lower = np.full(n_grasps, np.nan)
            verdicts.epsilon_upper = np.full(n_grasps, np.nan)
        if settings.robustness is not None:
            verdicts.robustness = Assessments.not_computed(n_grasps, n_contacts)
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
                   robustness=(None if any(p.robustness is None for p in parts)
                               else Assessments.concatenate([p.robustness for p in parts
                                                             if p.robustness is not None])),
                   **{name: _concatenate_optional([getattr(p, name) for p in parts])
                      for name in OPTIONAL_FIELDS})


# The optional per-grasp results of Verdicts, computed only when the settings ask.
OPTIONAL_FIELDS = ("contact_forces", "contact_torques", "separating_wrench", "min_friction",
                   "epsilon_lower", "epsilon_upper")


def _concatenate_optional(arrays: list) -> np.ndarray | None:
    """Concatenate an optional field of every part; None if any part lacks it (all
    parts of one message are decided with the same settings)."""
    if any(a is None for a in arrays):
        return None
    return np.concatenate(arrays)


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


def chunk_end(ends: np.ndarray, first: int, max_contacts: int) -> int:
    """End (exclusive) of the run of whole grasps starting at grasp ``first``: at most
    ``max_contacts`` contacts, and at least one grasp. ``ends`` is ``np.cumsum(counts)``.
    How the client cuts messages and a long job its chunks."""
    base = int(ends[first - 1]) if first else 0
    last = int(np.searchsorted(ends, base + max_contacts, side="right"))
    return max(last, first + 1)
