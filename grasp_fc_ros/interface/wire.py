"""Single-grasp queries and verdicts straight from and to their serialized (CDR) form.

rclpy turns every ``ContactArray`` it takes into ~20 Python objects (the message, its
header, and a point, a vector and a contact per finger), and every verdict back from
one; at thousands of queries per second that, not the force-closure test, is the
node's cost. This module reads many serialized queries at once with numpy into a
:class:`~grasp_fc_ros.engine.evaluation.PackedGrasps` and writes each verdict's bytes
directly, copying the query's header, ``client_id`` and ``id`` bytes verbatim.

The layout is the plain little-endian CDR (XCDR1) that rmw_fastrtps writes (checked
here; other rmws that write the same pass the check below too): a 4-byte encapsulation
header, then each field aligned to its own size, counted from after that header.
Padding bytes are not initialised by rclpy, so nothing here reads or compares them.
:func:`layout_matches` checks the layout against rclpy's own serialization at start-up
(the node and the client use rclpy's messages if it does not match); a query in another
layout (say big-endian, from another machine) is listed as undecoded, for rclpy to read.

Imports the message types only (for :func:`decode_verdict`), not rclpy (except in
the layout check and for verdict arrays full of messages, which rclpy handles).
"""

from __future__ import annotations

import array
import functools
import math
import struct
from dataclasses import dataclass

import numpy as np
from grasp_fc_msgs.msg import (
    Contact,
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from numpy.typing import ArrayLike
from std_msgs.msg import Header

from grasp_fc_ros.interface import message_slots as slots
from grasp_fc_ros.interface.conversions import BatchArrays, batch_msg, grasps_to_batch_msg
from grasp_fc_ros.packed import PackedGrasps, Verdicts

__all__ = ["ContactQueries", "decode_contact_array_batch", "decode_contact_arrays",
           "decode_verdict", "decode_verdict_array", "encode_contact_array",
           "encode_verdict_array",
           "encode_verdicts", "layout_matches", "verdict_ids"]

# Encapsulation header of little-endian plain CDR (kind 0x0001, options 0).
CDR_LE = b"\x00\x01\x00\x00"
_ENCAPSULATION = 4
# float64 values per Contact: position xyz, normal xyz, friction_coefficient,
# torsional_friction (all 8-aligned, so a contact is 64 contiguous bytes).
CONTACT_VALUES = 8
_CONTACT_BYTES = 8 * CONTACT_VALUES
# Offsets counted from after the encapsulation header: Header.stamp (int32 sec, uint32
# nanosec), then frame_id's uint32 length (including its NUL) and characters.
_FRAME_LENGTH_AT = 8
_FRAME_AT = 12
# Smallest ContactArray: empty frame_id ("\0"), ids, an empty contact sequence.
_MIN_QUERY_BYTES = _ENCAPSULATION + 16 + 16 + 4
# The verdict after the query's header, client_id and id (which end 8-aligned): bool
# force_closure, uint8 status, pad to 8, float64 margin, then string message.
_VERDICT_HEAD = struct.Struct("<BB6xd")
# After the message: pad to 4, uint32 0 (no contact_forces), uint32 0 (no
# contact_torques), pad to 8, then the float64 tail: separating_wrench (6 values),
# min_friction, epsilon_lower and epsilon_upper, all NaN: no certificate, not computed.
_NAN = struct.pack("<d", math.nan)
_TAIL_VALUES = 9


def _align(offset: int, size: int) -> int:
    return -(-offset // size) * size


@dataclass
class ContactQueries:
    """Serialized ContactArray queries, decoded.

    Attributes
    ----------
    packed : PackedGrasps
        The grasps of the queries that decoded (``name_by_id`` set), in order.
    torsional : (K,) float64
        The contacts' torsional_friction, in the order of ``packed``'s contacts.
    prefixes : list of bytes
        Per decoded query, its encapsulation, header, client_id and id bytes: the first
        bytes of its verdict.
    client_ids : (N,) uint64
    index : (N,) int64
        Position of each decoded query in the list given to the decoder.
    undecoded : (M,) int64
        Positions of the queries not in the expected layout.
    """

    packed: PackedGrasps
    torsional: np.ndarray
    prefixes: list
    client_ids: np.ndarray
    index: np.ndarray
    undecoded: np.ndarray


def _gather(buffer: np.ndarray, offsets: np.ndarray, dtype: str) -> np.ndarray:
    """Values of ``dtype`` starting at byte ``offsets`` of ``buffer`` (any alignment)."""
    size = np.dtype(dtype).itemsize
    return buffer[offsets[:, None] + np.arange(size)].view(dtype).reshape(-1)


def decode_contact_arrays(raws: list[bytes]) -> ContactQueries:
    """Decode serialized ``grasp_fc_msgs/msg/ContactArray`` messages at once.

    Parameters
    ----------
    raws : list of bytes
        Serialized messages, as a raw subscription gives them.

    Returns
    -------
    ContactQueries
        Queries whose bytes are exactly the little-endian CDR layout are decoded; the
        others are listed in ``undecoded`` (for rclpy's ``deserialize_message``).
    """
    n = len(raws)
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=n)
    starts = np.cumsum(lengths) - lengths
    # Zero padding: offsets of too-short queries (masked out) stay inside the buffer.
    buffer = np.frombuffer(b"".join(raws) + bytes(_MIN_QUERY_BYTES), dtype=np.uint8)
    ok = lengths >= _MIN_QUERY_BYTES
    base = np.where(ok, starts, 0) + _ENCAPSULATION  # CDR offset 0 of each query
    ok &= _gather(buffer, base - _ENCAPSULATION, "<u4") == np.frombuffer(CDR_LE, "<u4")[0]
    frame = np.where(ok, _gather(buffer, base + _FRAME_LENGTH_AT, "<u4"), 1).astype(np.int64)
    ids_at = _align_array(_FRAME_AT + frame, 8)  # client_id, then id
    count_at = ids_at + 16
    ok &= (frame >= 1) & (_ENCAPSULATION + count_at + 4 <= lengths)
    count_at = np.where(ok, count_at, 0)
    counts = np.where(ok, _gather(buffer, base + count_at, "<u4"), 0).astype(np.int64)
    contacts_at = count_at + 8  # the first Contact is 8-aligned
    expected = _ENCAPSULATION + np.where(counts > 0, contacts_at + _CONTACT_BYTES * counts,
                                         count_at + 4)
    # Trailing padding of at most 7 bytes is allowed, nothing else.
    ok &= (expected <= lengths) & (lengths - expected < 8)
    ok &= buffer[np.where(ok, base + _FRAME_AT + frame - 1, 0)] == 0  # frame_id's NUL
    index = np.flatnonzero(ok)
    base, ids_at, counts = base[index], ids_at[index], counts[index]
    values = _contact_values(buffer, base + contacts_at[index], counts)
    prefixes = [raws[i][:_ENCAPSULATION + a + 16]
                for i, a in zip(index.tolist(), ids_at.tolist(), strict=True)]
    packed = PackedGrasps(ids=_gather(buffer, base + ids_at + 8, "<u8").astype(np.uint64),
                          counts=counts, positions=values[:, 0:3], normals=values[:, 3:6],
                          mu=values[:, 6], name_by_id=True)
    return ContactQueries(packed=packed, torsional=values[:, 7], prefixes=prefixes,
                          client_ids=_gather(buffer, base + ids_at, "<u8").astype(np.uint64),
                          index=index, undecoded=np.flatnonzero(~ok))


def _align_array(offsets: np.ndarray, size: int) -> np.ndarray:
    return (offsets + size - 1) // size * size


def _contact_values(buffer: np.ndarray, first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(K, 8) float64 contacts of queries whose contacts start at byte ``first``."""
    sizes = _CONTACT_BYTES * counts
    total = int(sizes.sum())
    # Byte k of the output comes from first[q] + (k - out_start[q]) for its query q.
    shift = np.repeat(first - (np.cumsum(sizes) - sizes), sizes)
    data = buffer[shift + np.arange(total)]
    return data.view("<f8").reshape(-1, CONTACT_VALUES).astype(np.float64, copy=False)


def encode_verdicts(prefixes: list[bytes], force_closure: ArrayLike, status: ArrayLike,
                    margin: ArrayLike, messages: list[str]) -> list[bytes]:
    """Serialized ``ForceClosureVerdict`` messages, one per query, without certificates.

    Parameters
    ----------
    prefixes : list of bytes
        Per query, :attr:`ContactQueries.prefixes`: encapsulation, header, client_id, id.
    force_closure : (N,) bool
    status : (N,) uint8
    margin : (N,) float64
    messages : list of str
        Per verdict, its message ('' for none).

    Returns
    -------
    list of bytes
        contact_forces and contact_torques empty; separating_wrench, min_friction and
        the epsilon bounds NaN.
    """
    out = []
    empty_tail = _message_tail("")
    for prefix, fc, st, m, text in zip(prefixes, np.asarray(force_closure).tolist(),
                                       np.asarray(status).tolist(),
                                       np.asarray(margin, dtype=np.float64).tolist(), messages,
                                       strict=True):
        tail = empty_tail if not text else _message_tail(text)
        out.append(prefix + _VERDICT_HEAD.pack(fc, st, m) + tail)
    return out


def _message_tail(text: str) -> bytes:
    """The verdict's bytes from its string message on (at an offset = 0 mod 8)."""
    data = text.encode("utf-8") + b"\0"
    at = 16  # after _VERDICT_HEAD
    tail = struct.pack("<I", len(data)) + data
    pad4 = _align(at + len(tail), 4) - (at + len(tail))
    tail += b"\0" * pad4 + struct.pack("<II", 0, 0)
    pad8 = _align(at + len(tail), 8) - (at + len(tail))
    return tail + b"\0" * pad8 + _NAN * _TAIL_VALUES


@functools.cache
def layout_matches() -> bool:
    """True when this module reads rclpy's serialized sample queries, verdict arrays and
    batches, and writes verdicts and verdict arrays that rclpy reads back as they were
    meant (single verdicts in the same number of bytes).

    False, not an error, where rclpy cannot even read what this module writes: the node
    and the client then use rclpy's messages. Computed once per process: the rmw does
    not change.
    """
    try:
        return _single_layout_matches() and _array_layout_matches() and _batch_layout_matches()
    except Exception:  # noqa: BLE001 - e.g. rclpy's RMWError on bytes it cannot read
        return False


def _single_layout_matches() -> bool:
    """:func:`layout_matches` for single queries and verdicts."""
    from rclpy.serialization import deserialize_message, serialize_message

    for frame_id, n_contacts, text in (("", 2, ""), ("world", 3, "x"), ("abcdefg", 0, "ab")):
        query = ContactArray(client_id=2**63 + 5, id=2**40 + 3)
        query.header.frame_id = frame_id
        query.header.stamp.sec, query.header.stamp.nanosec = -7, 123
        query.contacts = [Contact(friction_coefficient=0.5 + k, torsional_friction=0.25)
                          for k in range(n_contacts)]
        for k, contact in enumerate(query.contacts):
            contact.position.x, contact.normal.z = 1.0 + k, -2.0 - k
        decoded = decode_contact_arrays([serialize_message(query)])
        if len(decoded.undecoded) or decoded.packed.ids.tolist() != [query.id]:
            return False
        values = np.concatenate([decoded.packed.positions, decoded.packed.normals,
                                 decoded.packed.mu[:, None], decoded.torsional[:, None]], axis=1)
        if values.tolist() != [[c.position.x, c.position.y, c.position.z, c.normal.x,
                                c.normal.y, c.normal.z, c.friction_coefficient,
                                c.torsional_friction] for c in query.contacts]:
            return False
        ours = encode_verdicts(decoded.prefixes, [True], [1], [0.125], [text])[0]
        back = deserialize_message(ours, ForceClosureVerdict)
        wrench = back.separating_wrench
        if ((back.header, back.client_id, back.id, back.force_closure, back.status,
             back.margin, back.message, list(back.contact_forces), list(back.contact_torques))
                != (query.header, query.client_id, query.id, True, 1, 0.125, text, [], [])
                or not all(math.isnan(v) for v in (
                    wrench.force.x, wrench.force.y, wrench.force.z, wrench.torque.x,
                    wrench.torque.y, wrench.torque.z, back.min_friction, back.epsilon_lower,
                    back.epsilon_upper))):
            return False
        # Same length as rclpy's own (their padding bytes are not initialised, so the
        # bytes themselves cannot be compared).
        if len(ours) != len(serialize_message(ForceClosureVerdict(
                header=query.header, client_id=query.client_id, id=query.id, message=text))):
            return False
    return True


def _array_layout_matches() -> bool:
    """:func:`layout_matches` for verdict arrays: ours read by rclpy, rclpy's by us."""
    from rclpy.serialization import deserialize_message, serialize_message

    from grasp_fc_ros.interface.conversions import verdict_array_to_numpy, verdicts_to_array_msg

    header = Header(frame_id="abc")
    header.stamp.sec, header.stamp.nanosec = -3, 77
    one_message = [""] * 20
    one_message[7] = "é x"
    for messages, certificates in (([], False), (["", ""], False), (one_message, True)):
        n = len(messages)
        verdicts = Verdicts(
            ids=np.arange(n, dtype=np.uint64) + 2**40, force_closure=np.arange(n) % 2 == 0,
            status=np.arange(n, dtype=np.uint8), margin=np.linspace(-1.0, 1.0, n),
            messages=messages)
        if certificates:
            verdicts.contact_forces = np.arange(6.0 * n).reshape(-1, 3)
            verdicts.separating_wrench = np.full((n, 6), 0.5)
            verdicts.min_friction = np.full(n, 0.25)
            verdicts.epsilon_lower = np.linspace(0.0, 0.5, n)
            verdicts.epsilon_upper = np.linspace(0.5, 1.0, n)
        reference = verdicts_to_array_msg(verdicts)
        reference.header, reference.client_id, reference.request_id = header, 2**63 + 1, 9
        # (rclpy's serialized arrays end in unused buffer bytes: lengths are not compared.)
        ours = encode_verdict_array(header, 2**63 + 1, 9, verdicts)
        theirs = serialize_message(reference)
        if deserialize_message(ours, type(reference)) != reference:
            return False
        client_id, request_id, back = decode_verdict_array(theirs)
        expected = verdict_array_to_numpy(reference)
        if (client_id, request_id, back.messages) != (2**63 + 1, 9, expected.messages):
            return False
        for name in ("ids", "force_closure", "status", "margin", "contact_forces",
                     "contact_torques", "separating_wrench", "min_friction",
                     "epsilon_lower", "epsilon_upper"):
            a, b = getattr(back, name), getattr(expected, name)
            if (a is None) != (b is None) or (a is not None and not np.array_equal(a, b)):
                return False
    return True


def _batch_layout_matches() -> bool:
    """:func:`layout_matches` for contact batches: rclpy's read by us."""
    from rclpy.serialization import serialize_message

    for frame_id, counts, mu, gamma in (("", [], None, None), ("ab", [2, 3], 0.5, None),
                                        ("world", [4], [0.1, 0.2, 0.3, 0.4], 0.01)):
        n_contacts = sum(counts)
        positions = np.arange(3.0 * n_contacts).reshape(-1, 3) - 2**40
        normals = -positions / 3
        ids = np.arange(len(counts), dtype=np.uint64) + 2**63
        reference = grasps_to_batch_msg(ids, positions, normals, mu, counts,
                                        client_id=2**63 + 1, request_id=7,
                                        torsional_friction=gamma)
        reference.header.frame_id = frame_id
        reference.header.stamp.sec, reference.header.stamp.nanosec = -3, 77
        if decode_contact_array_batch(serialize_message(reference)) != reference:
            return False
    return True


# --- batch verdicts: ForceClosureVerdictArray ------------------------------------------
#
# rclpy converts each of a verdict array's string[] messages and bool[] force_closure
# elements one Python object at a time, holding the GIL (the node's service thread
# waits meanwhile), and as long again for a client to take it. Written and read here
# with numpy instead (docs/performance.md#wire-format).

_UINT32 = struct.Struct("<I")
# Above this share of distinct non-empty messages (e.g. a batch of invalid grasps, each
# naming its grasp) rclpy's own serialization is the faster one: numpy pays per string
# here (docs/performance.md#wire-format).
MAX_MESSAGE_SHARE = 1 / 16
# An empty string in a string[]: length 1 (its NUL), the NUL, padding to 4.
_EMPTY_STRING = b"\x01\0\0\0\0\0\0\0"


class _Cdr:
    """Appends plain little-endian CDR to a buffer (offsets from after the encapsulation)."""

    def __init__(self) -> None:
        self.parts: list[bytes] = [CDR_LE]
        self.at = 0

    def put(self, data: bytes, align: int = 1) -> None:
        pad = _align(self.at, align) - self.at
        if pad:
            self.parts.append(bytes(pad))
        self.parts.append(data)
        self.at += pad + len(data)

    def string(self, text: str) -> None:
        data = text.encode("utf-8") + b"\0"
        self.put(_UINT32.pack(len(data)), 4)
        self.put(data)

    def sequence(self, values: np.ndarray, dtype: str) -> None:
        """A sequence of numbers: uint32 count, then (if any) the values, aligned."""
        values = np.ascontiguousarray(values, dtype=dtype).reshape(-1)
        self.put(_UINT32.pack(len(values)), 4)
        if len(values):
            self.put(values.tobytes(), values.itemsize)

    def strings(self, texts: list[str], full: np.ndarray) -> None:
        """A string[] whose non-empty strings are at indices ``full``
        (:func:`_non_empty`), placed with numpy: a batch's messages are mostly empty."""
        self.put(_UINT32.pack(len(texts)), 4)
        if not len(full):
            self.put(_EMPTY_STRING * len(texts))
            return
        encoded = [texts[i].encode("utf-8") for i in full.tolist()]
        sizes = np.fromiter(map(len, encoded), np.int64, len(encoded))
        lengths = np.ones(len(texts), np.int64)  # with the NUL
        lengths[full] = sizes + 1
        slots = 4 + 4 * ((lengths + 3) // 4)
        starts = np.concatenate(([0], np.cumsum(slots)[:-1]))
        buffer = np.zeros(int(slots.sum()), np.uint8)
        buffer.view("<u4")[starts // 4] = lengths
        # Every character of the non-empty strings to its place after its length.
        first = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        places = np.repeat(starts[full] + 4 - first, sizes) + np.arange(int(sizes.sum()))
        buffer[places] = np.frombuffer(b"".join(encoded), np.uint8)
        self.put(buffer.tobytes())

    def same_strings(self, text: str, n: int) -> None:
        """A string[] of ``n`` copies of ``text`` (one slot repeated: no object per
        string)."""
        data = text.encode("utf-8") + b"\0"
        self.put(_UINT32.pack(n), 4)
        self.put((_UINT32.pack(len(data)) + data + bytes(-len(data) % 4)) * n)

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _non_empty(texts: list[str]) -> np.ndarray:
    """Indices of the non-empty strings (the usual all-empty case in one C-level scan)."""
    if not any(texts):
        return np.empty(0, np.int64)
    return np.flatnonzero(np.fromiter(map(bool, texts), bool, len(texts)))


def encode_verdict_array(header: Header, client_id: int, request_id: int,
                         verdicts: Verdicts) -> bytes:
    """A serialized ``ForceClosureVerdictArray`` of ``verdicts`` (as
    :func:`~grasp_fc_ros.interface.conversions.verdicts_to_array_msg` fills it).

    Parameters
    ----------
    header : std_msgs/Header
        Copied (the batch query's).
    client_id, request_id : int
        uint64, copied from the query.
    verdicts : Verdicts
        Its optional fields that are None go as empty sequences.
    """
    messages = verdicts.messages
    # A refusal or failure: the same message for every grasp, written in bulk.
    uniform = len(messages) > 1 and messages.count(messages[0]) == len(messages)
    full = np.empty(0, np.int64) if uniform else _non_empty(messages)
    if len(full) > MAX_MESSAGE_SHARE * len(messages):
        from rclpy.serialization import serialize_message

        from grasp_fc_ros.interface.conversions import verdicts_to_array_msg

        msg = verdicts_to_array_msg(verdicts)
        msg.header, msg.client_id, msg.request_id = header, client_id, request_id
        return serialize_message(msg)
    out = _Cdr()
    out.put(_STAMP.pack(header.stamp.sec, header.stamp.nanosec))
    out.string(header.frame_id)
    out.put(_IDS.pack(client_id, request_id), 8)
    out.sequence(verdicts.ids, "<u8")
    out.sequence(np.asarray(verdicts.force_closure, bool).view(np.uint8), "u1")
    out.sequence(verdicts.status, "u1")
    out.sequence(verdicts.margin, "<f8")
    if uniform:
        out.same_strings(messages[0], len(messages))
    else:
        out.strings(messages, full)
    for values in (verdicts.contact_forces, verdicts.contact_torques,
                   verdicts.separating_wrench, verdicts.min_friction,
                   verdicts.epsilon_lower, verdicts.epsilon_upper):
        out.sequence(np.empty(0) if values is None else values, "<f8")
    return out.bytes()


class _ManyMessages(Exception):
    """More non-empty strings than numpy reading pays for (rclpy reads them)."""


class _CdrReader:
    """Reads plain little-endian CDR from a serialized message (after its encapsulation)."""

    def __init__(self, raw: bytes) -> None:
        if raw[:_ENCAPSULATION] != CDR_LE:
            raise ValueError("not little-endian plain CDR")
        self.view = memoryview(raw)[_ENCAPSULATION:]
        self.at = 0

    def take(self, fmt: struct.Struct, align: int) -> tuple:
        self.at = _align(self.at, align)
        values = fmt.unpack_from(self.view, self.at)
        self.at += fmt.size
        return values

    def string(self) -> str:
        self.at = _align(self.at, 4)
        text, self.at = _string(self.view, self.at)
        return text

    def sequence(self, dtype: str, copy: bool = True) -> np.ndarray:
        """A sequence of numbers: a copy, or a read-only view of the bytes."""
        (count,) = self.take(_UINT32, 4)
        if not count:
            return np.empty(0, dtype)
        size = np.dtype(dtype).itemsize
        self.at = _align(self.at, size)
        if self.at + count * size > len(self.view):
            raise ValueError(f"truncated sequence of {count} at offset {self.at}")
        values = np.frombuffer(self.view, dtype, count, self.at)
        self.at += count * size
        return values.copy() if copy else values

    def strings(self) -> list[str]:
        """A string[]; runs of empty strings (most of a batch's) are measured with numpy.

        An empty string is 8 bytes: length 1, its NUL, 3 padding bytes (not compared:
        rclpy leaves them uninitialised).
        """
        (count,) = self.take(_UINT32, 4)
        texts: list[str] = []
        budget = 16 + MAX_MESSAGE_SHARE * count  # non-empty strings read one by one
        while len(texts) < count:
            self.at = _align(self.at, 4)
            run = self._empty_run(count - len(texts))
            if run:
                texts.extend([""] * run)
                self.at += 8 * run
                continue
            budget -= 1
            if budget < 0:
                raise _ManyMessages()
            text, self.at = _string(self.view, self.at)
            texts.append(text)
        return texts

    def _empty_run(self, limit: int) -> int:
        """How many empty strings (at most ``limit``) start at the current offset."""
        if (self.at + 8 > len(self.view) or _UINT32.unpack_from(self.view, self.at)[0] != 1
                or self.view[self.at + 4] != 0):
            return 0
        limit = min(limit, (len(self.view) - self.at) // 8)
        pairs = np.frombuffer(self.view, "<u4", 2 * limit, self.at).reshape(-1, 2)
        ends = np.flatnonzero((pairs[:, 0] != 1) | ((pairs[:, 1] & 0xFF) != 0))
        return int(ends[0]) if len(ends) else limit


def decode_verdict_array(raw: bytes) -> tuple[int, int, Verdicts]:
    """(client_id, request_id, verdicts) of a serialized ``ForceClosureVerdictArray``.

    The verdicts as :func:`~grasp_fc_ros.interface.conversions.verdict_array_to_numpy` reads them:
    ``contact_forces`` (K, 3), ``separating_wrench`` (N, 6), ``contact_torques``,
    ``min_friction``, ``epsilon_lower`` and ``epsilon_upper``, each None where the
    message carries none.

    Raises
    ------
    ValueError
        For bytes that are not a whole verdict array in that layout.
    """
    try:
        return _decode_verdict_array(raw)
    except _ManyMessages:
        from rclpy.serialization import deserialize_message

        from grasp_fc_ros.interface.conversions import verdict_array_to_numpy

        msg = deserialize_message(raw, ForceClosureVerdictArray)
        return msg.client_id, msg.request_id, verdict_array_to_numpy(msg)


def _decode_verdict_array(raw: bytes) -> tuple[int, int, Verdicts]:
    reader = _CdrReader(raw)
    try:
        reader.take(_STAMP, 4)
        reader.string()
        client_id, request_id = reader.take(_IDS, 8)
        ids = reader.sequence("<u8")
        force_closure = reader.sequence("u1").astype(bool)
        status = reader.sequence("u1")
        margin = reader.sequence("<f8")
        messages = reader.strings()
        forces, torques, wrenches, min_friction, lower, upper = (
            reader.sequence("<f8") for _ in range(6))
    except struct.error as exc:
        raise ValueError(f"truncated verdict array of {len(raw)} bytes: {exc}") from None
    return client_id, request_id, Verdicts(
        ids=ids, force_closure=force_closure, status=status, margin=margin,
        messages=messages,
        contact_forces=forces.reshape(-1, 3) if len(forces) else None,
        contact_torques=torques if len(torques) else None,
        separating_wrench=wrenches.reshape(-1, 6) if len(wrenches) else None,
        min_friction=min_friction if len(min_friction) else None,
        epsilon_lower=lower if len(lower) else None,
        epsilon_upper=upper if len(upper) else None)


# --- batches of grasps: ContactArrayBatch ----------------------------------------------
#
# The node takes batches serialized and reads them here: less than half the CPU of
# taking rclpy's message, CPU the node's workers need. The client still publishes
# messages: rclpy's raw publish cost more than its message publish
# (docs/performance.md#wire-format).


# Wire types of BatchArrays' fields, in message order.
_BATCH_DTYPES = ("<u8", "<u4", "<f8", "<f8", "<f8", "<f8")


def decode_contact_array_batch(raw: bytes) -> ContactArrayBatch:
    """A serialized little-endian CDR ``ContactArrayBatch`` as a message object, its
    sequences copied into their ``array.array`` fields with numpy (node side).

    Raises
    ------
    ValueError
        For bytes that are not a whole batch in that layout (rclpy's
        ``deserialize_message`` reads other layouts).
    """
    reader = _CdrReader(raw)
    try:
        sec, nanosec = reader.take(_STAMP, 4)
        frame_id = reader.string()
        client_id, request_id = reader.take(_IDS, 8)
        sequences = [reader.sequence(dtype, copy=False) for dtype in _BATCH_DTYPES]
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"not a whole contact batch of {len(raw)} bytes: {exc}") from None
    return batch_msg(BatchArrays(*sequences), client_id=client_id, request_id=request_id,
                     header=slots.header(slots.time_msg(sec, nanosec), frame_id))


# --- the client's side: queries out, verdicts in ---------------------------------------

_STAMP = struct.Struct("<iI")
_IDS = struct.Struct("<QQ")


def encode_contact_array(query_id: int, client_id: int, contacts: np.ndarray,
                         frame_id: str = "", stamp: tuple[int, int] = (0, 0)) -> bytes:
    """A serialized ``ContactArray``.

    Parameters
    ----------
    query_id, client_id : int
        uint64 values.
    contacts : (n, 8) float64
        Per contact: position xyz (m), normal xyz, friction_coefficient,
        torsional_friction (:data:`CONTACT_VALUES` columns).
    frame_id : str
    stamp : (int, int)
        Header stamp: seconds (int32) and nanoseconds (uint32).
    """
    frame = frame_id.encode("utf-8") + b"\0"
    head = CDR_LE + _STAMP.pack(*stamp) + struct.pack("<I", len(frame)) + frame
    head += bytes(_align(len(head) - _ENCAPSULATION, 8) - (len(head) - _ENCAPSULATION))
    contacts = np.ascontiguousarray(contacts, dtype="<f8").reshape(-1, CONTACT_VALUES)
    # uint32 count, then 4 bytes of padding: the first contact is 8-aligned.
    count = struct.pack("<I", len(contacts)) + (bytes(4) if len(contacts) else b"")
    return head + _IDS.pack(client_id, query_id) + count + contacts.tobytes()


def verdict_ids(raw: bytes) -> tuple[int, int]:
    """(client_id, id) of a serialized ForceClosureVerdict (or ContactArray)."""
    (frame,) = struct.unpack_from("<I", raw, _ENCAPSULATION + _FRAME_LENGTH_AT)
    return _IDS.unpack_from(raw, _ENCAPSULATION + _align(_FRAME_AT + frame, 8))


_VERDICT_BODY = struct.Struct("<?B6xdI")
# The float64 tail of a verdict (see _TAIL_VALUES): separating_wrench, min_friction,
# epsilon_lower, epsilon_upper.
_TAIL = struct.Struct(f"<{_TAIL_VALUES}d")


def decode_verdict(raw: bytes) -> ForceClosureVerdict:
    """A serialized little-endian CDR ``ForceClosureVerdict`` as a message object.

    Builds the message from its fields (:mod:`grasp_fc_ros.interface.message_slots`):
    a fraction of rclpy's ``deserialize_message`` for a verdict without certificates
    (docs/performance.md#wire-format).

    Raises
    ------
    ValueError
        For bytes that are not a whole verdict in that layout.
    """
    if raw[:_ENCAPSULATION] != CDR_LE:
        raise ValueError("not little-endian plain CDR")
    try:
        return _fill_verdict(memoryview(raw)[_ENCAPSULATION:])
    except struct.error as exc:
        raise ValueError(f"truncated verdict of {len(raw)} bytes: {exc}") from None


def _fill_verdict(view: memoryview) -> ForceClosureVerdict:
    sec, nanosec = _STAMP.unpack_from(view, 0)
    frame_id, at = _string(view, _FRAME_LENGTH_AT)
    at = _align(at, 8)
    client_id, query_id = _IDS.unpack_from(view, at)
    force_closure, status, margin, _ = _VERDICT_BODY.unpack_from(view, at + 16)
    message, at = _string(view, at + 16 + _VERDICT_BODY.size - 4)
    at = _align(at, 4)
    (n_forces,) = struct.unpack_from("<I", view, at)
    at += 4
    forces = []
    if n_forces:
        at = _align(at, 8)
        forces = [slots.vector3(x, y, z) for x, y, z in
                  np.frombuffer(view, "<f8", 3 * n_forces, at).reshape(-1, 3).tolist()]
        at += 24 * n_forces
    at = _align(at, 4)
    (n_torques,) = struct.unpack_from("<I", view, at)
    at += 4
    torques = array.array("d")
    if n_torques:
        at = _align(at, 8)
        torques.extend(np.frombuffer(view, "<f8", n_torques, at).tolist())
        at += 8 * n_torques
    at = _align(at, 8)
    w = _TAIL.unpack_from(view, at)
    if len(view) - (at + _TAIL.size) not in range(8):
        raise ValueError(f"verdict of {len(view)} bytes after its encapsulation, "
                         f"{at + _TAIL.size} expected")
    return slots.verdict(
        slots.header(slots.time_msg(sec, nanosec), frame_id), client_id, query_id,
        force_closure, status, margin, message, forces, torques,
        slots.wrench(slots.vector3(*w[0:3]), slots.vector3(*w[3:6])), w[6], w[7], w[8])


def _string(view: memoryview, at: int) -> tuple[str, int]:
    """The CDR string whose uint32 length is at ``at``, and the offset after it."""
    (length,) = struct.unpack_from("<I", view, at)
    if length < 1 or at + 4 + length > len(view) or view[at + 3 + length] != 0:
        raise ValueError(f"bad string at offset {at}")
    return bytes(view[at + 4:at + 3 + length]).decode("utf-8"), at + 4 + length
