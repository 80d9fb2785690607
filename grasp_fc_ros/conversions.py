"""Conversions between grasp_fc_msgs messages and numpy arrays.

The node works on a *packed* representation of many grasps (:class:`PackedGrasps`):
all contacts of all grasps stacked grasp after grasp, plus one contact count per
grasp, the same layout as ``ContactArrayBatch``. The packed batch message converts
with ``np.frombuffer`` on its array fields, without a Python object per contact.

This module only moves data; it holds no force-closure mathematics.
"""

from __future__ import annotations

import array
from dataclasses import dataclass, field

import numpy as np

from grasp_fc_msgs.msg import (
    Contact,
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)

# array.array type codes of the generated message fields.
_TYPECODE_FLOAT64 = "d"
_TYPECODE_UINT64 = "Q"
_TYPECODE_UINT32 = "I"
_TYPECODE_UINT8 = "B"


@dataclass
class PackedGrasps:
    """Many grasp queries, stacked contact after contact.

    Attributes
    ----------
    ids : (N,) uint64
        Query id of each grasp.
    counts : (N,) int64
        Number of contacts of each grasp (0 where the grasp could not be read).
    positions : (K, 3) float64
        Contact positions (m), grasp after grasp; K = counts.sum().
    normals : (K, 3) float64
        Inward contact normals, any length (validated later).
    mu : (K,) float64
        Friction coefficient per contact; finite values <= 0 mean "node default"
        (NaN and +-inf are invalid).
    unreadable : dict[int, str]
        Grasp index -> reason, for grasps whose data could not be read from the
        message (their ``counts`` entry is 0).
    notes : list[str]
        Batch-level remarks worth a warning (e.g. unused trailing values).
    name_by_id : bool
        True when the grasps are separate single-grasp topic queries: messages then
        name a grasp by its query id only, since its position among the queued
        queries means nothing to the client.
    """

    ids: np.ndarray
    counts: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    unreadable: dict[int, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    name_by_id: bool = False

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def starts(self) -> np.ndarray:
        """(N,) int64 index of each grasp's first contact in the stacked arrays."""
        return np.concatenate(([0], np.cumsum(self.counts)[:-1])).astype(np.int64)


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
    """

    ids: np.ndarray
    force_closure: np.ndarray
    status: np.ndarray
    margin: np.ndarray
    messages: list[str]

    def __len__(self) -> int:
        return len(self.ids)


def _as_numpy(values, dtype) -> np.ndarray:
    """View a message array field (array.array or sequence) as a numpy array."""
    if isinstance(values, array.array):
        return np.frombuffer(values, dtype=dtype) if len(values) else np.empty(0, dtype)
    return np.asarray(values, dtype=dtype)


def _to_field(typecode: str, values: np.ndarray) -> array.array:
    """Build an array.array for a message field from numpy data, without a per-item loop."""
    out = array.array(typecode)
    out.frombytes(np.ascontiguousarray(values, dtype=np.dtype(typecode)).tobytes())
    return out


def batch_to_packed(msg: ContactArrayBatch) -> PackedGrasps:
    """Read a ContactArrayBatch into a :class:`PackedGrasps`.

    A malformed batch (contact counts that do not add up to the array lengths,
    fewer counts than ids, arrays of different lengths) never raises: every grasp
    whose contacts lie fully inside all arrays is read, the others are listed in
    ``unreadable`` with the reason.
    """
    ids = _as_numpy(msg.ids, np.uint64)
    n_grasps = len(ids)
    declared = _as_numpy(msg.contact_counts, np.uint32).astype(np.int64)
    flat_positions = _as_numpy(msg.positions, np.float64)
    flat_normals = _as_numpy(msg.normals, np.float64)
    flat_mu = _as_numpy(msg.friction_coefficients, np.float64)

    counts = np.zeros(n_grasps, dtype=np.int64)
    counts[: min(n_grasps, len(declared))] = declared[:n_grasps]
    ends = np.cumsum(counts)
    # Contacts present in every array (positions and normals hold 3 values per contact).
    available = min(len(flat_positions) // 3, len(flat_normals) // 3)
    if len(flat_mu):
        available = min(available, len(flat_mu))

    # Contacts are stored in grasp order, so the readable grasps form a prefix.
    has_count = np.arange(n_grasps) < len(declared)
    readable = has_count & (ends <= available)
    unreadable: dict[int, str] = {}
    for i in np.flatnonzero(~readable):
        if not has_count[i]:
            unreadable[int(i)] = (f"grasp {i}: no contact count "
                                  f"(batch has {len(declared)} counts for {n_grasps} ids)")
        else:
            unreadable[int(i)] = (
                f"grasp {i}: contacts {ends[i] - counts[i]}..{ends[i] - 1} lie beyond the batch "
                f"arrays (positions {len(flat_positions)}, normals {len(flat_normals)}, "
                f"friction_coefficients {len(flat_mu)} values)")
    counts[~readable] = 0
    total = int(counts.sum())

    notes = []
    declared_total = int(declared.sum())
    if len(declared) > n_grasps:
        notes.append(f"{len(declared) - n_grasps} contact counts without an id were ignored")
    if (len(flat_positions) != 3 * declared_total or len(flat_normals) != 3 * declared_total
            or len(flat_mu) not in (0, declared_total)):
        notes.append(
            f"array lengths (positions {len(flat_positions)}, normals {len(flat_normals)}, "
            f"friction_coefficients {len(flat_mu)}) do not match the {declared_total} contacts "
            "declared by contact_counts")
    return PackedGrasps(
        ids=ids,
        counts=counts,
        positions=flat_positions[: 3 * total].reshape(total, 3),
        normals=flat_normals[: 3 * total].reshape(total, 3),
        mu=flat_mu[:total] if len(flat_mu) else np.zeros(total),
        unreadable=unreadable,
        notes=notes,
    )


def contact_arrays_to_packed(grasps: list[ContactArray], name_by_id: bool = False
                             ) -> PackedGrasps:
    """Stack single-grasp queries (topic messages or a service request) into a PackedGrasps.

    ``name_by_id`` is passed on to :class:`PackedGrasps` (True for topic queries).
    """
    ids = np.fromiter((g.id for g in grasps), dtype=np.uint64, count=len(grasps))
    counts = np.fromiter((len(g.contacts) for g in grasps), dtype=np.int64, count=len(grasps))
    total = int(counts.sum())
    values = np.fromiter(
        (v for g in grasps for c in g.contacts
         for v in (c.position.x, c.position.y, c.position.z,
                   c.normal.x, c.normal.y, c.normal.z, c.friction_coefficient)),
        dtype=np.float64, count=7 * total).reshape(total, 7)
    return PackedGrasps(ids=ids, counts=counts, positions=values[:, 0:3],
                        normals=values[:, 3:6], mu=values[:, 6], name_by_id=name_by_id)


def verdicts_to_array_msg(verdicts: Verdicts, header=None) -> ForceClosureVerdictArray:
    """Pack verdicts into a ForceClosureVerdictArray (header copied from the query)."""
    msg = ForceClosureVerdictArray()
    if header is not None:
        msg.header = header
    msg.ids = _to_field(_TYPECODE_UINT64, verdicts.ids)
    msg.force_closure = np.asarray(verdicts.force_closure, dtype=bool).tolist()
    msg.status = _to_field(_TYPECODE_UINT8, verdicts.status)
    msg.margin = _to_field(_TYPECODE_FLOAT64, verdicts.margin)
    msg.messages = list(verdicts.messages)
    return msg


def verdicts_to_msgs(verdicts: Verdicts) -> list[ForceClosureVerdict]:
    """One ForceClosureVerdict message per grasp, in order."""
    return [
        ForceClosureVerdict(id=int(i), force_closure=bool(fc), status=int(st),
                            margin=float(m), message=text)
        for i, fc, st, m, text in zip(verdicts.ids.tolist(), verdicts.force_closure.tolist(),
                                      verdicts.status.tolist(), verdicts.margin.tolist(),
                                      verdicts.messages)
    ]


def verdict_array_to_numpy(msg: ForceClosureVerdictArray) -> Verdicts:
    """Read a ForceClosureVerdictArray back into numpy arrays (client side)."""
    return Verdicts(
        ids=_as_numpy(msg.ids, np.uint64).copy(),
        force_closure=np.asarray(msg.force_closure, dtype=bool),
        status=_as_numpy(msg.status, np.uint8).copy(),
        margin=_as_numpy(msg.margin, np.float64).copy(),
        messages=list(msg.messages),
    )


def grasps_to_batch_msg(ids, positions, normals, mu=None, counts=None) -> ContactArrayBatch:
    """Build a ContactArrayBatch (client side).

    Parameters
    ----------
    ids : (N,) int
    positions, normals : (N, n, 3) float, or (K, 3) stacked when ``counts`` is given
    mu : None, scalar, or one value per contact; None or empty means node default
    counts : (N,) int, optional
        Contacts per grasp for stacked (K, 3) input of mixed sizes.

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
    n_contacts = positions.size // 3
    msg = ContactArrayBatch()
    msg.ids = _to_field(_TYPECODE_UINT64, ids)
    msg.contact_counts = _to_field(_TYPECODE_UINT32, np.asarray(counts))
    msg.positions = _to_field(_TYPECODE_FLOAT64, positions.reshape(-1))
    msg.normals = _to_field(_TYPECODE_FLOAT64, normals.reshape(-1))
    if mu is not None and np.size(mu):
        mu = np.asarray(mu, dtype=np.float64)
        if mu.size != n_contacts:
            mu = np.broadcast_to(mu, positions.shape[:-1])
        msg.friction_coefficients = _to_field(_TYPECODE_FLOAT64, mu.reshape(-1))
    return msg


def grasp_to_contact_array(grasp_id, positions, normals, mu=0.0) -> ContactArray:
    """Build a single-grasp ContactArray (client side).

    Parameters
    ----------
    grasp_id : int
    positions, normals : (n, 3) float
    mu : scalar or (n,) float; a finite value <= 0 means node default
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    mus = np.broadcast_to(np.asarray(mu, dtype=np.float64), (len(positions),))
    msg = ContactArray(id=int(grasp_id))
    contacts = []
    for p, nrm, m in zip(positions.tolist(), normals.tolist(), mus.tolist()):
        c = Contact(friction_coefficient=m)
        c.position.x, c.position.y, c.position.z = p
        c.normal.x, c.normal.y, c.normal.z = nrm
        contacts.append(c)
    msg.contacts = contacts
    return msg
