"""Conversions between grasp_fc_msgs messages and numpy arrays.

The node works on the packed representation of :mod:`grasp_fc_ros.engine.evaluation`
(:class:`PackedGrasps`, :class:`Verdicts`), the layout of ``ContactArrayBatch``: the
packed batch message converts with ``np.frombuffer`` on its array fields, without a
Python object per contact.

This module only moves data; it holds no force-closure mathematics.
"""

from __future__ import annotations

import array
import math
from typing import Any, NamedTuple

import numpy as np
from geometry_msgs.msg import Vector3
from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from numpy.typing import ArrayLike, DTypeLike
from std_msgs.msg import Header

from grasp_fc_ros.interface import message_slots as slots
from grasp_fc_ros.packed import (
    ASSESSMENT_FIELDS,
    OPTIONAL_FIELDS,
    Assessments,
    PackedGrasps,
    Verdicts,
)

__all__ = [
    "BatchArrays", "MalformedBatch", "PackedGrasps", "Verdicts", "assessment_response",
    "assessment_to_numpy", "batch_arrays",
    "batch_ids", "batch_msg", "batch_size", "batch_to_packed",
    "contact_arrays_to_packed", "grasp_to_contact_array", "grasps_to_batch_msg",
    "verdict_array_to_numpy", "verdict_msgs_to_numpy", "verdicts_to_array_msg",
    "verdicts_to_msgs",
]

# array.array type codes of the generated message fields.
_TYPECODE_FLOAT64 = "d"
_TYPECODE_UINT64 = "Q"
_TYPECODE_UINT32 = "I"
_TYPECODE_UINT8 = "B"


def _as_numpy(values: Any, dtype: DTypeLike) -> np.ndarray:
    """View a message array field (array.array or sequence) as a numpy array."""
    if isinstance(values, array.array):
        return np.frombuffer(values, dtype=dtype) if len(values) else np.empty(0, dtype)
    return np.asarray(values, dtype=dtype)


def _to_field(typecode: str, values: np.ndarray) -> array.array:
    """Build an array.array for a message field from numpy data, without a per-item loop."""
    out = array.array(typecode)
    # The array's own buffer (.data): no intermediate copy.
    out.frombytes(np.ascontiguousarray(values, dtype=np.dtype(typecode)).reshape(-1)
                  .view(np.uint8).data)
    return out


class MalformedBatch(ValueError):
    """A ContactArrayBatch whose counts do not match its arrays (no grasp can be trusted)."""


def batch_size(msg: ContactArrayBatch) -> int:
    """Number of grasps a batch claims to hold (len(ids)), read without converting it."""
    return len(msg.ids)


def batch_contacts(msg: ContactArrayBatch) -> int:
    """Number of contacts a batch carries (its positions over 3), read without
    converting it."""
    return len(msg.positions) // 3


def batch_ids(msg: ContactArrayBatch) -> np.ndarray:
    """The (N,) uint64 ids of a batch, without copying them."""
    return _as_numpy(msg.ids, np.uint64)


def batch_to_packed(msg: ContactArrayBatch) -> PackedGrasps:
    """Read a ContactArrayBatch into a :class:`PackedGrasps`.

    Raises
    ------
    MalformedBatch
        If the batch is mis-packed: not one contact count per id, or positions,
        normals, friction coefficients or torsional friction coefficients not exactly
        as long as the counts declare (the last two may also be empty).
        Contacts are stored grasp after grasp, so one wrong count shifts every later
        grasp: no grasp of such a batch is decided.
    """
    ids = _as_numpy(msg.ids, np.uint64)
    counts = _as_numpy(msg.contact_counts, np.uint32).astype(np.int64)
    flat_positions = _as_numpy(msg.positions, np.float64)
    flat_normals = _as_numpy(msg.normals, np.float64)
    flat_mu = _as_numpy(msg.friction_coefficients, np.float64)
    flat_torsional = _as_numpy(msg.torsional_friction, np.float64)
    if len(counts) != len(ids):
        raise MalformedBatch(f"malformed batch: {len(counts)} contact counts for "
                             f"{len(ids)} ids")
    total = int(counts.sum())
    if (len(flat_positions) != 3 * total or len(flat_normals) != 3 * total
            or len(flat_mu) not in (0, total)):
        raise MalformedBatch(
            f"malformed batch: contact_counts declare {total} contacts, but positions has "
            f"{len(flat_positions)} values, normals {len(flat_normals)}, "
            f"friction_coefficients {len(flat_mu)} (need {3 * total}, {3 * total}, "
            f"{total} or 0)")
    if len(flat_torsional) not in (0, total):
        raise MalformedBatch(
            f"malformed batch: contact_counts declare {total} contacts, but "
            f"torsional_friction has {len(flat_torsional)} values (need {total} or 0)")
    return PackedGrasps(
        ids=ids,
        counts=counts,
        positions=flat_positions.reshape(total, 3),
        normals=flat_normals.reshape(total, 3),
        mu=flat_mu if len(flat_mu) else np.zeros(total),
        torsional=_soft_or_none(flat_torsional),
    )


def _soft_or_none(torsional: np.ndarray) -> np.ndarray | None:
    """Per-contact gamma (K,), or None when empty or all exactly 0 (every contact hard:
    the node's hard path, unchanged). Bad values are kept for validation to name."""
    return torsional if torsional.any() else None  # NaN counts as non-zero


def contact_arrays_to_packed(grasps: list[ContactArray], name_by_id: bool = False
                             ) -> PackedGrasps:
    """Stack single-grasp queries (topic messages or a service request) into a PackedGrasps.

    ``name_by_id`` is passed on to :class:`PackedGrasps` (True for topic queries).
    """
    ids = np.fromiter((g.id for g in grasps), dtype=np.uint64, count=len(grasps))
    counts = np.fromiter((len(g.contacts) for g in grasps), dtype=np.int64, count=len(grasps))
    # A list extended in a loop, then one array: faster than a generator into
    # np.fromiter (docs/performance.md#wire-format).
    flat: list[float] = []
    for grasp in grasps:
        for contact in grasp.contacts:
            position, normal = contact.position, contact.normal
            flat += (position.x, position.y, position.z, normal.x, normal.y, normal.z,
                     contact.friction_coefficient, contact.torsional_friction)
    values = np.array(flat, dtype=np.float64).reshape(-1, 8)
    return PackedGrasps(ids=ids, counts=counts, positions=values[:, 0:3],
                        normals=values[:, 3:6], mu=values[:, 6], name_by_id=name_by_id,
                        torsional=_soft_or_none(values[:, 7]))


def verdicts_to_array_msg(verdicts: Verdicts, query: ContactArrayBatch | None = None
                          ) -> ForceClosureVerdictArray:
    """Pack verdicts into a ForceClosureVerdictArray answering batch ``query``.

    The query's header, client_id and request_id are copied.
    """
    msg = ForceClosureVerdictArray()
    if query is not None:
        msg.header = query.header
        msg.client_id = query.client_id
        msg.request_id = query.request_id
    msg.ids = _to_field(_TYPECODE_UINT64, verdicts.ids)
    msg.force_closure = np.asarray(verdicts.force_closure, dtype=bool).tolist()
    msg.status = _to_field(_TYPECODE_UINT8, verdicts.status)
    msg.margin = _to_field(_TYPECODE_FLOAT64, verdicts.margin)
    msg.messages = list(verdicts.messages)
    if verdicts.contact_forces is not None:
        msg.contact_forces = _to_field(_TYPECODE_FLOAT64, verdicts.contact_forces.reshape(-1))
    if verdicts.contact_torques is not None:
        msg.contact_torques = _to_field(_TYPECODE_FLOAT64, verdicts.contact_torques)
    if verdicts.separating_wrench is not None:
        msg.separating_wrenches = _to_field(_TYPECODE_FLOAT64,
                                            verdicts.separating_wrench.reshape(-1))
    if verdicts.min_friction is not None:
        msg.min_friction = _to_field(_TYPECODE_FLOAT64, verdicts.min_friction)
    if verdicts.epsilon_lower is not None and verdicts.epsilon_upper is not None:
        msg.epsilon_lower = _to_field(_TYPECODE_FLOAT64, verdicts.epsilon_lower)
        msg.epsilon_upper = _to_field(_TYPECODE_FLOAT64, verdicts.epsilon_upper)
    return msg


def _vectors(rows: np.ndarray) -> list[Vector3]:
    return [slots.vector3(x, y, z) for x, y, z in rows.tolist()]


def _set_wrench(reply: ForceClosureVerdict, values: list[float]) -> None:
    """Write 6 values into the message's own separating_wrench (in place)."""
    force, torque = reply.separating_wrench.force, reply.separating_wrench.torque
    force.x, force.y, force.z, torque.x, torque.y, torque.z = values


def _set_certificates(reply: ForceClosureVerdict, forces: np.ndarray | None,
                      torques: np.ndarray | None, wrench: np.ndarray | None,
                      min_friction: float, epsilon: tuple[float, float]) -> None:
    """Fill the certificate fields of one verdict message made by
    :func:`verdicts_to_msgs` (NaN wrench, min_friction and epsilon, no forces).

    ``forces`` (n, 3) and ``torques`` (n,) or None are sent only for a FORCE_CLOSURE
    verdict (empty otherwise); ``wrench`` (6,) or None (the NaN stays); ``min_friction``
    and ``epsilon`` (lower, upper) as they are (NaN: not computed).
    """
    if forces is not None and reply.status == ForceClosureVerdict.FORCE_CLOSURE:
        reply.contact_forces = _vectors(forces)
        if torques is not None:
            reply.contact_torques = torques.tolist()
    if wrench is not None and not np.isnan(wrench).any():
        _set_wrench(reply, wrench.tolist())
    reply.min_friction = min_friction
    reply.epsilon_lower, reply.epsilon_upper = epsilon


def verdicts_to_msgs(verdicts: Verdicts, queries: list[ContactArray] | None = None
                     ) -> list[ForceClosureVerdict]:
    """One ForceClosureVerdict message per grasp, in order.

    ``queries`` (one per verdict) are the single-grasp queries answered: their header
    and client_id are copied into the verdicts. The certificate fields follow
    ForceClosureVerdict's conventions: ``contact_forces`` (split by the queries' contact
    counts, so ``queries`` are needed with them) only for FORCE_CLOSURE verdicts,
    ``separating_wrench``, ``min_friction`` and the epsilon bounds NaN where there is
    none.

    Raises
    ------
    ValueError
        If ``verdicts`` carry contact forces but no ``queries`` are given.
    """
    if queries is None:
        headers_and_clients = [(Header(), 0) for _ in range(len(verdicts))]
    else:
        if len(queries) != len(verdicts):
            raise ValueError(f"{len(queries)} queries for {len(verdicts)} verdicts")
        headers_and_clients = [(query.header, query.client_id) for query in queries]
    # Without certificates (NaN wrench and min_friction), which _certificates_to_msgs
    # fills in where there are some.
    out = [
        slots.verdict(head, client, i, fc, st, m, text, [], array.array("d"),
                      slots.nan_wrench(), math.nan)
        for (head, client), i, fc, st, m, text in zip(
            headers_and_clients, verdicts.ids.tolist(), verdicts.force_closure.tolist(),
            verdicts.status.tolist(), verdicts.margin.tolist(), verdicts.messages, strict=True)
    ]
    _certificates_to_msgs(verdicts, queries, out)
    return out


def _certificates_to_msgs(verdicts: Verdicts, queries: list[ContactArray] | None,
                          out: list[ForceClosureVerdict]) -> None:
    if all(getattr(verdicts, name) is None for name in OPTIONAL_FIELDS):
        return  # the common case, on the single-query hot path
    forces: list[np.ndarray | None] = [None] * len(out)
    ends = np.cumsum([len(q.contacts) for q in queries]) if queries is not None else None
    if verdicts.contact_forces is not None:
        if queries is None:
            raise ValueError("contact forces need the queries (their contact counts) to be "
                             "split into verdict messages")
        assert ends is not None
        forces = list(np.split(verdicts.contact_forces, ends[:-1]))
    torques: list[np.ndarray | None] = [None] * len(out)
    if verdicts.contact_torques is not None and ends is not None:
        torques = list(np.split(verdicts.contact_torques, ends[:-1]))
    wrenches: list[np.ndarray | None] = (list(verdicts.separating_wrench)
                                         if verdicts.separating_wrench is not None
                                         else [None] * len(out))
    min_friction = (verdicts.min_friction.tolist() if verdicts.min_friction is not None
                    else [math.nan] * len(out))
    epsilon = (list(zip(verdicts.epsilon_lower.tolist(), verdicts.epsilon_upper.tolist(),
                        strict=True))
               if verdicts.epsilon_lower is not None and verdicts.epsilon_upper is not None
               else [(math.nan, math.nan)] * len(out))
    for reply, f, t, w, m, e in zip(out, forces, torques, wrenches, min_friction, epsilon,
                                    strict=True):
        _set_certificates(reply, f, t, w, m, e)


def verdict_array_to_numpy(msg: ForceClosureVerdictArray) -> Verdicts:
    """Read a ForceClosureVerdictArray back into numpy arrays (client side).

    The certificate fields become ``contact_forces`` (K, 3), ``contact_torques`` (K,),
    ``separating_wrench`` (N, 6), ``min_friction``, ``epsilon_lower`` and
    ``epsilon_upper`` (N,), or None where the message carries none (empty).
    """
    def optional(values: Any, width: int) -> np.ndarray | None:
        if not len(values):
            return None
        flat = _as_numpy(values, np.float64).copy()
        return flat.reshape(-1, width) if width else flat

    return Verdicts(
        ids=_as_numpy(msg.ids, np.uint64).copy(),
        force_closure=np.asarray(msg.force_closure, dtype=bool),
        status=_as_numpy(msg.status, np.uint8).copy(),
        margin=_as_numpy(msg.margin, np.float64).copy(),
        messages=list(msg.messages),
        contact_forces=optional(msg.contact_forces, 3),
        contact_torques=optional(msg.contact_torques, 0),
        separating_wrench=optional(msg.separating_wrenches, 6),
        min_friction=optional(msg.min_friction, 0),
        epsilon_lower=optional(msg.epsilon_lower, 0),
        epsilon_upper=optional(msg.epsilon_upper, 0),
    )


def verdict_msgs_to_numpy(replies: list[ForceClosureVerdict], counts: ArrayLike) -> Verdicts:
    """Read single verdict messages (e.g. a service response) into numpy arrays.

    Parameters
    ----------
    replies : list of ForceClosureVerdict
        N verdicts.
    counts : (N,) int
        Contacts of each answered grasp (a verdict carries contact forces only when it
        is FORCE_CLOSURE, so the counts come from the queries).

    Returns
    -------
    Verdicts
        With ``contact_forces`` (K, 3) (NaN rows for grasps without forces),
        ``separating_wrench`` (N, 6), ``min_friction``, ``epsilon_lower`` and
        ``epsilon_upper`` (N,) always set: single
        verdicts carry NaN, not "absent", where there is none; ``contact_torques`` (K,)
        (NaN where there are none) when any verdict carries them, else None.

    Raises
    ------
    ValueError
        If a verdict's contact forces do not match its grasp's contact count.
    """
    counts = np.asarray(counts, dtype=np.int64).reshape(-1)
    if len(counts) != len(replies):
        raise ValueError(f"{len(counts)} contact counts for {len(replies)} verdicts")
    forces = np.full((int(counts.sum()), 3), np.nan)
    torques = np.full(int(counts.sum()), np.nan)
    start = 0
    for k, (reply, count) in enumerate(zip(replies, counts.tolist(), strict=True)):
        if reply.contact_forces:
            if len(reply.contact_forces) != count:
                raise ValueError(f"verdict {k} (id {reply.id}) has "
                                 f"{len(reply.contact_forces)} contact forces for "
                                 f"{count} contacts")
            forces[start:start + count] = [(v.x, v.y, v.z) for v in reply.contact_forces]
        if len(reply.contact_torques):
            if len(reply.contact_torques) != count:
                raise ValueError(f"verdict {k} (id {reply.id}) has "
                                 f"{len(reply.contact_torques)} contact torques for "
                                 f"{count} contacts")
            torques[start:start + count] = reply.contact_torques
        start += count
    wrench = np.array([(r.separating_wrench.force.x, r.separating_wrench.force.y,
                        r.separating_wrench.force.z, r.separating_wrench.torque.x,
                        r.separating_wrench.torque.y, r.separating_wrench.torque.z)
                       for r in replies], dtype=np.float64).reshape(-1, 6)
    return Verdicts(
        ids=np.array([r.id for r in replies], dtype=np.uint64),
        force_closure=np.array([r.force_closure for r in replies], dtype=bool),
        status=np.array([r.status for r in replies], dtype=np.uint8),
        margin=np.array([r.margin for r in replies], dtype=np.float64),
        messages=[r.message for r in replies],
        contact_forces=forces,
        contact_torques=torques if any(len(r.contact_torques) for r in replies) else None,
        separating_wrench=wrench,
        min_friction=np.array([r.min_friction for r in replies], dtype=np.float64),
        epsilon_lower=np.array([r.epsilon_lower for r in replies], dtype=np.float64),
        epsilon_upper=np.array([r.epsilon_upper for r in replies], dtype=np.float64))


# The AssessRobustness response's fields for Assessments' fields (the same names, but
# the wrenches in the plural as in ForceClosureVerdictArray); their array.array type
# codes.
_RESPONSE_FIELDS = {name: name for name in ASSESSMENT_FIELDS} | {
    "separating_wrench": "separating_wrenches"}
_RESPONSE_TYPECODES = {"holds": _TYPECODE_UINT8}


def assessment_response(verdicts: Verdicts, response: Any) -> Any:
    """Fill an AssessRobustness response from verdicts carrying ``robustness``.

    Parallel arrays, one entry per grasp (the witness: 3 or 1 values per contact, the
    wrenches 6 per grasp), laid out as in ForceClosureVerdictArray.
    """
    assessments = verdicts.robustness
    if assessments is None:
        raise ValueError("verdicts without robustness assessments")
    response.ids = _to_field(_TYPECODE_UINT64, verdicts.ids)
    response.force_closure = np.asarray(verdicts.force_closure, dtype=bool).tolist()
    response.status = _to_field(_TYPECODE_UINT8, verdicts.status)
    response.messages = list(verdicts.messages)
    for name, field in _RESPONSE_FIELDS.items():
        values = getattr(assessments, name)
        if name == "holds_bound":
            setattr(response, field, [str(value) for value in values])
        else:
            setattr(response, field, _to_field(_RESPONSE_TYPECODES.get(name, _TYPECODE_FLOAT64),
                                               values.reshape(-1)))
    return response


def assessment_to_numpy(response: Any) -> Verdicts:
    """Read an AssessRobustness response back into numpy arrays (client side):
    :class:`Verdicts` (``margin`` NaN: the response carries none) with ``robustness``.

    Raises
    ------
    ValueError
        If its arrays do not have one entry per grasp (and the witness the same number
        of contacts in its three arrays).
    """
    n_grasps = len(response.ids)
    columns: dict[str, Any] = {}
    for name, field in _RESPONSE_FIELDS.items():
        values = getattr(response, field)
        if name == "holds_bound":
            columns[name] = np.array(list(values), dtype=object)
            continue
        array_ = _as_numpy(values, np.uint8 if name == "holds" else np.float64).copy()
        columns[name] = array_.reshape(-1, 3 if name in ("witness_positions",
                                                          "witness_normals")
                                       else 6 if name == "separating_wrench" else 1)
        if columns[name].shape[1] == 1:
            columns[name] = columns[name][:, 0]
    lengths = {name: len(values) for name, values in columns.items()}
    contacts = lengths["witness_friction"]
    wrong = [f"{name} {length}" for name, length in lengths.items()
             if length != (contacts if name.startswith("witness") else n_grasps)]
    if wrong or len(response.status) != n_grasps or len(response.messages) != n_grasps:
        raise ValueError(f"malformed AssessRobustness response for {n_grasps} grasps: "
                         + ", ".join(wrong or ["status or messages"]))
    return Verdicts(ids=_as_numpy(response.ids, np.uint64).copy(),
                    force_closure=np.asarray(response.force_closure, dtype=bool),
                    status=_as_numpy(response.status, np.uint8).copy(),
                    margin=np.full(n_grasps, np.nan), messages=list(response.messages),
                    robustness=Assessments(**columns))


class BatchArrays(NamedTuple):
    """The sequence fields of a ContactArrayBatch as flat numpy arrays.

    ``ids`` (N,) uint64, ``contact_counts`` (N,) uint32, ``positions`` and ``normals``
    (3K,) float64 (m; xyz contact after contact), ``friction_coefficients`` and
    ``torsional_friction`` (K,) float64 or empty (node default; hard contacts).
    """

    ids: np.ndarray
    contact_counts: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    friction_coefficients: np.ndarray
    torsional_friction: np.ndarray


def batch_arrays(ids: ArrayLike, positions: ArrayLike, normals: ArrayLike,
                 mu: ArrayLike | None = None, counts: ArrayLike | None = None,
                 torsional_friction: ArrayLike | None = None) -> BatchArrays:
    """The fields of a ContactArrayBatch of these grasps (client side).

    Parameters
    ----------
    ids : (N,) int
    positions, normals : (N, n, 3) float, or (K, 3) stacked when ``counts`` is given
    mu : None, scalar, or one value per contact; None, empty or 0 means the node's
        friction_coefficient (a negative value: INVALID_INPUT)
    counts : (N,) int, optional
        Contacts per grasp for stacked (K, 3) input of mixed sizes.
    torsional_friction : None, scalar, or one value per contact
        gamma of soft contacts (m); None or empty: every contact hard.

    Raises
    ------
    ValueError
        If ``positions`` is not (N, n, 3) and no ``counts`` are given: the grasps'
        sizes would be unknown.
    """
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    ids = np.asarray(ids, dtype=np.uint64).reshape(-1)
    if counts is None:
        if positions.ndim != 3:
            raise ValueError(f"positions of shape {positions.shape} need counts (contacts per "
                             "grasp); without counts pass (N, n, 3)")
        counts = np.full(len(ids), positions.shape[1])
    return BatchArrays(
        ids=ids, contact_counts=np.asarray(counts, dtype=np.uint32).reshape(-1),
        positions=positions.reshape(-1), normals=normals.reshape(-1),
        friction_coefficients=_per_contact(mu, positions.shape),
        torsional_friction=_per_contact(torsional_friction, positions.shape))


def _per_contact(values: ArrayLike | None, shape: tuple[int, ...]) -> np.ndarray:
    """(K,) float64 of a scalar or per-contact ``values`` for contacts of ``shape``
    (..., 3); empty for None or empty."""
    if values is None or not np.size(values):
        return np.empty(0)
    array_ = np.asarray(values, dtype=np.float64)
    if array_.size * 3 != int(np.prod(shape)):
        array_ = np.broadcast_to(array_, shape[:-1])
    return array_.reshape(-1)


def grasps_to_batch_msg(ids: ArrayLike, positions: ArrayLike, normals: ArrayLike,
                        mu: ArrayLike | None = None, counts: ArrayLike | None = None, *,
                        client_id: int = 0, request_id: int = 0,
                        torsional_friction: ArrayLike | None = None) -> ContactArrayBatch:
    """Build a ContactArrayBatch (client side).

    Parameters as :func:`batch_arrays`, and ``client_id``, ``request_id`` (int), echoed
    in the verdict array, so that the client recognises its reply.
    """
    return batch_msg(batch_arrays(ids, positions, normals, mu, counts, torsional_friction),
                     client_id=client_id, request_id=request_id)


def batch_msg(fields: BatchArrays, *, client_id: int = 0, request_id: int = 0,
              header: Header | None = None) -> ContactArrayBatch:
    """A ContactArrayBatch holding ``fields`` (``header`` default: empty)."""
    return slots.contact_array_batch(
        Header() if header is None else header, int(client_id), int(request_id),
        [_to_field(typecode, values)
         for typecode, values in zip(_BATCH_TYPECODES, fields, strict=True)])


# array.array type codes of BatchArrays' fields.
_BATCH_TYPECODES = (_TYPECODE_UINT64, _TYPECODE_UINT32) + (_TYPECODE_FLOAT64,) * 4


def friction_or_default(mu: ArrayLike | None) -> ArrayLike:
    """``mu`` as sent in a Contact: None becomes 0, which the node reads as its
    ``friction_coefficient`` parameter (a negative value is INVALID_INPUT there)."""
    return 0.0 if mu is None else mu


def grasp_to_contact_array(grasp_id: int, positions: ArrayLike, normals: ArrayLike,
                           mu: ArrayLike | None = None, *, client_id: int = 0,
                           torsional_friction: ArrayLike = 0.0) -> ContactArray:
    """Build a single-grasp ContactArray (client side).

    Parameters
    ----------
    grasp_id : int
    positions, normals : (n, 3) float
    mu : None, scalar or (n,) float; None or 0: the node's friction_coefficient
    client_id : int
        Echoed in the verdict.
    torsional_friction : scalar or (n,) float
        gamma of soft contacts (m); 0: hard.
    """
    points = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    mus = np.broadcast_to(np.asarray(friction_or_default(mu), dtype=np.float64),
                          (len(points),))
    gammas = np.broadcast_to(np.asarray(torsional_friction, dtype=np.float64), (len(points),))
    msg = ContactArray(id=int(grasp_id), client_id=int(client_id))
    msg.contacts = [
        slots.contact(slots.point(px, py, pz), slots.vector3(nx, ny, nz), m, g)
        for (px, py, pz), (nx, ny, nz), m, g in zip(points.tolist(), directions.tolist(),
                                                    mus.tolist(), gammas.tolist(), strict=True)]
    return msg
