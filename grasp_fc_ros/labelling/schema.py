"""The output columns, one Arrow table per chunk.

Always written:

========================  =========================  =====================================
column                    type                       meaning
========================  =========================  =====================================
``id``                    uint64                     the grasp's id (input ``ids``, or the
                                                     running index across all inputs)
``force_closure``         bool                       the verdict
``status``                uint8                      :class:`~grasp_fc_ros.core.Status` code
``status_name``           dictionary<string>         its name, e.g. ``FILTERED_OUT``
``margin``                float64                    the exact test's optimum; NaN where the
                                                     filter decided
========================  =========================  =====================================

With grasps drawn on objects (``--objects``/``--mesh``), the grasps themselves too:
``object`` (string), ``mu`` (float64), ``positions`` and ``normals`` (fixed-size lists of
3n float64: x, y, z per contact, contact after contact -- the Parquet input layout, so the
output can be labelled again).

With ``--quality`` (:data:`QUALITY_FIELDS`, after ``margin``): the certified
Ferrari-Canny epsilon of :func:`grasp_fc_ros.core.epsilon_quality` (Q1 with circular
friction cones, the sum of normal forces <= 1), torques about the origin of the grasps'
frame divided by the grasp's largest contact distance from it:

========================  =========================  =====================================
``epsilon_lower``         float64                    lower <= epsilon; 0 where not force
                                                     closure
``epsilon_upper``         float64                    epsilon <= upper = h(direction)
``epsilon_direction``     fixed-size list of 6       the unit wrench (force, torque / L)
                          float64                    certifying upper (48 bytes a grasp)
========================  =========================  =====================================

With ``--robustness`` (after the epsilon columns; :mod:`grasp_fc_ros.core.robustness`):
the certified radii (:data:`RADII_FIELDS`) always; :data:`HOLDS_FIELDS` when an error is
given; :data:`PROBABILITY_FIELDS` when a noise sigma is given:

==================================  ===================  ===================================
``normal_angle``                    float64              rad: force closure for every choice
                                                         of normals each within this angle
``position_radius``                 float64              positions' unit: for every contact
                                                         moved within this ball
``friction_drop``                   float64              for every mu dropped by up to this
``holds``                           uint8                :class:`~grasp_fc_ros.core.Holds`
                                                         code under the given errors
``holds_name``                      dictionary<string>   its name: HOLDS, BREAKS, UNDECIDED
``holds_bound``                     string               the sound bound behind HOLDS
                                                         ('' otherwise)
``probability_estimate``            float64              successes / samples
``probability_lower``               float64              Clopper-Pearson bounds at the
``probability_upper``               float64              run's confidence
``probability_successes``           uint32               samples in force closure
``probability_undecided``           uint32               samples the solver could not
                                                         decide (in ``upper`` only; ~0)
``probability_normal_lower_bound``  float64              sample-free lower bound where only
                                                         normals are noisy; NaN otherwise
==================================  ===================  ===================================

Later columns (``min_friction``, certificates) are added as optional entries of
:func:`label_table`, without changing the existing ones.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa

from grasp_fc_ros.core import Status

if TYPE_CHECKING:
    from grasp_fc_ros.core import EpsilonResult, ForceClosureResult
    from grasp_fc_ros.core.robustness import (
        ForceClosureProbability,
        HoldsUnder,
        RobustnessRadii,
    )

    from .robustness import Robustness
    from .sources import GraspChunk

STATUS_NAMES = [status.name for status in sorted(Status)]

LABEL_FIELDS = [
    pa.field("id", pa.uint64(), nullable=False),
    pa.field("force_closure", pa.bool_(), nullable=False),
    pa.field("status", pa.uint8(), nullable=False),
    pa.field("status_name", pa.dictionary(pa.int8(), pa.string()), nullable=False),
    pa.field("margin", pa.float64(), nullable=False),
]


QUALITY_FIELDS = [
    pa.field("epsilon_lower", pa.float64(), nullable=False),
    pa.field("epsilon_upper", pa.float64(), nullable=False),
    pa.field("epsilon_direction", pa.list_(pa.float64(), 6), nullable=False),
]


RADII_FIELDS = [pa.field(name, pa.float64(), nullable=False)
                for name in ("normal_angle", "position_radius", "friction_drop")]

HOLDS_FIELDS = [
    pa.field("holds", pa.uint8(), nullable=False),
    pa.field("holds_name", pa.dictionary(pa.int8(), pa.string()), nullable=False),
    pa.field("holds_bound", pa.string(), nullable=False),
]

PROBABILITY_FIELDS = [
    pa.field("probability_estimate", pa.float64(), nullable=False),
    pa.field("probability_lower", pa.float64(), nullable=False),
    pa.field("probability_upper", pa.float64(), nullable=False),
    pa.field("probability_successes", pa.uint32(), nullable=False),
    pa.field("probability_undecided", pa.uint32(), nullable=False),
    pa.field("probability_normal_lower_bound", pa.float64(), nullable=False),
]


def robustness_fields(robustness: Robustness | None) -> list[pa.Field]:
    """The robustness columns that ``robustness`` asks for (none for None)."""
    if robustness is None:
        return []
    return (RADII_FIELDS + (HOLDS_FIELDS if robustness.holds else [])
            + (PROBABILITY_FIELDS if robustness.probability else []))


def grasp_fields(n_contacts: int) -> list[pa.Field]:
    """The columns that hold the grasps themselves (n contacts each)."""
    vectors = pa.list_(pa.float64(), 3 * n_contacts)
    return [pa.field("object", pa.string(), nullable=False),
            pa.field("mu", pa.float64(), nullable=False),
            pa.field("positions", vectors, nullable=False),
            pa.field("normals", vectors, nullable=False)]


def output_schema(with_grasps: bool, n_contacts: int, quality: bool = False,
                  robustness: Robustness | None = None) -> pa.Schema:
    """Schema of every part of one run."""
    return pa.schema(LABEL_FIELDS + (QUALITY_FIELDS if quality else [])
                     + robustness_fields(robustness)
                     + (grasp_fields(n_contacts) if with_grasps else []))


def label_table(chunk: GraspChunk, result: ForceClosureResult, object_name: str | None = None,
                epsilon: EpsilonResult | None = None, radii: RobustnessRadii | None = None,
                holds: HoldsUnder | None = None,
                probability: ForceClosureProbability | None = None) -> pa.Table:
    """One chunk's labels (and grasps, when ``object_name`` is given) as an Arrow table.

    Parameters
    ----------
    chunk : grasp_fc_ros.labelling.sources.GraspChunk
        The k grasps.
    result : grasp_fc_ros.core.ForceClosureResult
        Their verdicts, arrays of shape (k,).
    object_name : str or None
        The object the grasps were drawn on; None for grasps read from files.
    epsilon : grasp_fc_ros.core.EpsilonResult or None
        Their certified epsilon (``--quality``), arrays of shape (k,) and (k, 6).
    radii, holds, probability : results of grasp_fc_ros.core.robustness or None
        Their robustness radii, holds_under and probability of force closure
        (``--robustness``), arrays of shape (k,); holds and probability need radii.
    """
    status = np.asarray(result.status, dtype=np.uint8)
    names = pa.DictionaryArray.from_arrays(pa.array(status.astype(np.int8)),
                                           pa.array(STATUS_NAMES))
    fields = list(LABEL_FIELDS)
    columns = [pa.array(chunk.ids, pa.uint64()),
               pa.array(np.asarray(result.force_closure, dtype=bool)),
               pa.array(status, pa.uint8()), names,
               pa.array(np.asarray(result.margin, dtype=np.float64))]
    if epsilon is not None:
        direction = np.asarray(epsilon.direction, dtype=np.float64).reshape(-1)
        fields += QUALITY_FIELDS
        columns += [pa.array(np.asarray(epsilon.lower, dtype=np.float64)),
                    pa.array(np.asarray(epsilon.upper, dtype=np.float64)),
                    pa.FixedSizeListArray.from_arrays(pa.array(direction), 6)]
    if radii is not None:
        fields += RADII_FIELDS
        columns += [_floats(radii.normal_angle), _floats(radii.position_radius),
                    _floats(radii.friction_drop)]
    if holds is not None:
        fields += HOLDS_FIELDS
        columns += _holds_columns(holds)
    if probability is not None:
        fields += PROBABILITY_FIELDS
        columns += [_floats(probability.estimate), _floats(probability.lower),
                    _floats(probability.upper),
                    pa.array(np.asarray(probability.successes, dtype=np.uint32)),
                    pa.array(np.asarray(probability.undecided, dtype=np.uint32)),
                    _floats(probability.normal_lower_bound)]
    n_contacts = chunk.positions.shape[1]
    if object_name is not None:
        k = len(chunk.ids)
        mu = np.broadcast_to(chunk.mu, (k, n_contacts))[:, 0]
        fields += grasp_fields(n_contacts)
        columns += [pa.array([object_name] * k, pa.string()), pa.array(mu, pa.float64()),
                    _vectors(chunk.positions), _vectors(chunk.normals)]
    return pa.Table.from_arrays(columns, schema=pa.schema(fields))


def _holds_columns(holds: HoldsUnder) -> list[pa.Array]:
    from grasp_fc_ros.core.robustness import Holds

    codes = np.asarray(holds.status, dtype=np.uint8)
    # The dictionary is indexed by code: Holds counts from 1, so entry 0 is never used.
    names = pa.array(["", *(member.name for member in sorted(Holds))])
    return [pa.array(codes, pa.uint8()),
            pa.DictionaryArray.from_arrays(pa.array(codes.astype(np.int8)), names),
            pa.array(np.asarray(holds.bound, dtype=str), pa.string())]


def _floats(values: np.ndarray) -> pa.Array:
    return pa.array(np.asarray(values, dtype=np.float64))


def _vectors(values: np.ndarray) -> pa.FixedSizeListArray:
    k, n, _ = values.shape
    return pa.FixedSizeListArray.from_arrays(
        pa.array(np.ascontiguousarray(values, dtype=np.float64).reshape(-1)), 3 * n)
