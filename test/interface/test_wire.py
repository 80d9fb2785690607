"""grasp_fc_ros.interface.wire against rclpy's own (de)serialization, on random messages."""

from __future__ import annotations

import array
import math
import struct

import numpy as np
import pytest
from grasp_fc_msgs.msg import Contact, ContactArray, ForceClosureVerdict
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message

from grasp_fc_ros.interface import wire

UINT64 = st.integers(0, 2**64 - 1)
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
# ROS strings are C strings: no NUL inside.
TEXT = st.text(st.characters(blacklist_characters="\0", blacklist_categories=("Cs",)),
               max_size=12)


@st.composite
def queries(draw):
    msg = ContactArray(client_id=draw(UINT64), id=draw(UINT64))
    msg.header.frame_id = draw(TEXT)
    msg.header.stamp.sec = draw(st.integers(-2**31, 2**31 - 1))
    msg.header.stamp.nanosec = draw(st.integers(0, 2**32 - 1))
    contacts = []
    for _ in range(draw(st.integers(0, 7))):
        values = draw(st.lists(FLOATS, min_size=8, max_size=8))
        contact = Contact(friction_coefficient=values[6], torsional_friction=values[7])
        contact.position.x, contact.position.y, contact.position.z = values[0:3]
        contact.normal.x, contact.normal.y, contact.normal.z = values[3:6]
        contacts.append(contact)
    msg.contacts = contacts
    return msg


def contact_values(msg: ContactArray) -> list[list[float]]:
    return [[c.position.x, c.position.y, c.position.z, c.normal.x, c.normal.y, c.normal.z,
             c.friction_coefficient, c.torsional_friction] for c in msg.contacts]


def test_layout_matches_this_rmw():
    assert wire.layout_matches()


@settings(max_examples=60, deadline=None)
@given(st.lists(queries(), max_size=6))
def test_decode_equals_rclpy_deserialization(msgs):
    raws = [serialize_message(m) for m in msgs]
    decoded = wire.decode_contact_arrays(raws)
    assert decoded.index.tolist() == list(range(len(msgs)))
    assert decoded.undecoded.tolist() == []
    packed = decoded.packed
    assert packed.name_by_id
    assert packed.ids.tolist() == [deserialize_message(r, ContactArray).id for r in raws]
    assert decoded.client_ids.tolist() == [m.client_id for m in msgs]
    assert packed.counts.tolist() == [len(m.contacts) for m in msgs]
    expected = np.array([v for m in msgs for v in contact_values(m)]).reshape(-1, 8)
    got = np.concatenate([packed.positions, packed.normals, packed.mu[:, None],
                          decoded.torsional[:, None]], axis=1)
    np.testing.assert_array_equal(got, expected)  # NaN equal to NaN, bit-exact otherwise


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(queries(), st.booleans(), st.integers(0, 4), FLOATS, TEXT),
                min_size=1, max_size=5))
def test_encoded_verdicts_equal_rclpy_serialization(cases):
    msgs = [c[0] for c in cases]
    decoded = wire.decode_contact_arrays([serialize_message(m) for m in msgs])
    ours = wire.encode_verdicts(decoded.prefixes, [c[1] for c in cases], [c[2] for c in cases],
                                [c[3] for c in cases], [c[4] for c in cases])
    for raw, (query, fc, status, margin, text) in zip(ours, cases, strict=True):
        verdict = deserialize_message(raw, ForceClosureVerdict)
        assert (verdict.header.frame_id, verdict.header.stamp.sec, verdict.header.stamp.nanosec,
                verdict.client_id, verdict.id) == (
            query.header.frame_id, query.header.stamp.sec, query.header.stamp.nanosec,
            query.client_id, query.id)
        assert (verdict.force_closure, verdict.status, verdict.message) == (fc, status, text)
        assert verdict.margin == margin or (math.isnan(margin) and math.isnan(verdict.margin))
        assert list(verdict.contact_forces) == []
        wrench = verdict.separating_wrench
        assert all(math.isnan(v) for v in (wrench.force.x, wrench.force.y, wrench.force.z,
                                           wrench.torque.x, wrench.torque.y, wrench.torque.z,
                                           verdict.min_friction, verdict.epsilon_lower,
                                           verdict.epsilon_upper))
        # As long as rclpy's own (its padding bytes are uninitialised memory, so the
        # bytes cannot be compared).
        assert len(serialize_message(verdict)) == len(raw)


@settings(max_examples=40, deadline=None)
@given(queries(), st.data())
def test_damaged_queries_are_set_aside_and_the_others_decoded(msg, data):
    good = serialize_message(msg)
    cut = data.draw(st.integers(0, len(good) - 1))
    damaged = [good[:cut], b"\x01" + good[1:], good + bytes(8)]
    decoded = wire.decode_contact_arrays([good] + damaged + [good])
    assert decoded.index.tolist() == [0, 4]
    assert decoded.undecoded.tolist() == [1, 2, 3]
    assert decoded.packed.counts.tolist() == [len(msg.contacts)] * 2


def test_no_queries():
    decoded = wire.decode_contact_arrays([])
    assert len(decoded.packed) == 0 and decoded.prefixes == []
    assert wire.encode_verdicts([], [], [], [], []) == []


@pytest.mark.parametrize("frame_id", ["", "a", "abc", "abcd", "abcdefgh"])
def test_every_frame_id_alignment(frame_id):
    msg = ContactArray(id=1, client_id=2)
    msg.header.frame_id = frame_id
    msg.contacts = [Contact(friction_coefficient=0.5)]
    decoded = wire.decode_contact_arrays([serialize_message(msg)])
    assert decoded.packed.ids.tolist() == [1] and decoded.client_ids.tolist() == [2]


@settings(max_examples=60, deadline=None)
@given(queries())
def test_encoded_query_equals_what_rclpy_reads(msg):
    contacts = np.array(contact_values(msg)).reshape(-1, 8)
    stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
    raw = wire.encode_contact_array(msg.id, msg.client_id, contacts, msg.header.frame_id, stamp)
    back = deserialize_message(raw, ContactArray)
    assert (back.header.frame_id, back.header.stamp.sec, back.header.stamp.nanosec,
            back.client_id, back.id) == (msg.header.frame_id, *stamp, msg.client_id, msg.id)
    np.testing.assert_array_equal(np.array(contact_values(back)).reshape(-1, 8), contacts)
    assert len(raw) == len(serialize_message(msg))
    assert wire.verdict_ids(raw) == (msg.client_id, msg.id)
    verdict = ForceClosureVerdict(header=msg.header, client_id=msg.client_id, id=msg.id,
                                  message="why")
    assert wire.verdict_ids(serialize_message(verdict)) == (msg.client_id, msg.id)


@settings(max_examples=60, deadline=None)
@given(queries(), st.booleans(), st.integers(0, 255), FLOATS, TEXT,
       st.lists(st.lists(FLOATS, min_size=3, max_size=3), max_size=4),
       st.lists(FLOATS, min_size=9, max_size=9))
def test_decoded_verdict_equals_rclpy_deserialization(query, fc, status, margin, text, forces,
                                                      wrench):
    from geometry_msgs.msg import Vector3

    verdict = ForceClosureVerdict(header=query.header, client_id=query.client_id, id=query.id,
                                  force_closure=fc, status=status, margin=margin, message=text,
                                  contact_forces=[Vector3(x=x, y=y, z=z) for x, y, z in forces],
                                  min_friction=wrench[6], epsilon_lower=wrench[7],
                                  epsilon_upper=wrench[8])
    w = verdict.separating_wrench
    w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z = wrench[:6]
    raw = serialize_message(verdict)
    ours, theirs = wire.decode_verdict(raw), deserialize_message(raw, ForceClosureVerdict)
    # NaN != NaN: compare the bytes each serializes to, minus the padding (uninitialised).
    assert repr(ours) == repr(theirs)
    with pytest.raises(ValueError):
        wire.decode_verdict(raw[:-8])


# --- batch verdicts -------------------------------------------------------------------


@st.composite
def verdict_arrays(draw):
    """(header, client_id, request_id, Verdicts) with any mix of messages (mostly empty
    or not, so that both the numpy and the rclpy paths run) and optional certificates."""
    from std_msgs.msg import Header

    from grasp_fc_ros.packed import Verdicts

    n = draw(st.integers(0, 40))
    header = Header(frame_id=draw(TEXT))
    header.stamp.sec = draw(st.integers(-2**31, 2**31 - 1))
    header.stamp.nanosec = draw(st.integers(0, 2**32 - 1))
    share = draw(st.sampled_from([0.0, 0.03, 1.0, "same"]))
    if share == "same":  # a refusal: one text for every grasp (written in bulk)
        messages = [draw(TEXT)] * n
    else:
        messages = [draw(TEXT) if draw(st.floats(0, 1)) < share else "" for _ in range(n)]
    floats = st.lists(FLOATS, min_size=n, max_size=n)
    verdicts = Verdicts(
        ids=np.array(draw(st.lists(UINT64, min_size=n, max_size=n)), np.uint64),
        force_closure=np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), bool),
        status=np.array(draw(st.lists(st.integers(0, 255), min_size=n, max_size=n)), np.uint8),
        margin=np.array(draw(floats), np.float64), messages=messages)
    if draw(st.booleans()):
        k = draw(st.integers(0, 3 * n))
        verdicts.contact_forces = np.array(draw(st.lists(FLOATS, min_size=3 * k,
                                                         max_size=3 * k))).reshape(-1, 3)
        if draw(st.booleans()):
            verdicts.contact_torques = np.array(draw(st.lists(FLOATS, min_size=k, max_size=k)))
        verdicts.separating_wrench = np.full((n, 6), draw(FLOATS))
        verdicts.min_friction = np.array(draw(floats), np.float64)
    if draw(st.booleans()):
        verdicts.epsilon_lower = np.array(draw(floats), np.float64)
        verdicts.epsilon_upper = np.array(draw(floats), np.float64)
    return header, draw(UINT64), draw(UINT64), verdicts


def same_field(a, b) -> bool:
    if a is None or b is None or (len(a) == 0 and len(b) == 0):
        return (a is None or len(a) == 0) and (b is None or len(b) == 0)
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


@settings(max_examples=80, deadline=None)
@given(verdict_arrays())
def test_encoded_verdict_array_reads_back_in_rclpy_as_the_message(case):
    from grasp_fc_msgs.msg import ForceClosureVerdictArray

    from grasp_fc_ros.interface.conversions import verdict_array_to_numpy, verdicts_to_array_msg

    header, client_id, request_id, verdicts = case
    back = deserialize_message(wire.encode_verdict_array(header, client_id, request_id,
                                                         verdicts), ForceClosureVerdictArray)
    expected = verdicts_to_array_msg(verdicts)
    assert (back.header, back.client_id, back.request_id) == (header, client_id, request_id)
    got, want = verdict_array_to_numpy(back), verdict_array_to_numpy(expected)
    assert got.messages == want.messages
    for name in ("ids", "force_closure", "status", "margin", "contact_forces",
                 "contact_torques", "separating_wrench", "min_friction", "epsilon_lower",
                 "epsilon_upper"):
        assert same_field(getattr(got, name), getattr(want, name)), name


@pytest.mark.parametrize("text", ["", "7 grasps exceed max_batch=3", "ü", "abc"])
def test_a_refusal_is_encoded_in_bulk_and_reads_back_in_rclpy(text):
    from grasp_fc_msgs.msg import ForceClosureVerdictArray
    from std_msgs.msg import Header

    from grasp_fc_ros.packed import Verdicts

    raw = wire.encode_verdict_array(Header(frame_id="palm"), 5, 6,
                                    Verdicts.failed(np.arange(7) + 3, 1, text))
    back = deserialize_message(raw, ForceClosureVerdictArray)
    assert (back.header.frame_id, back.client_id, back.request_id) == ("palm", 5, 6)
    assert list(back.ids) == list(range(3, 10)) and list(back.status) == [1] * 7
    assert list(back.messages) == [text] * 7 and np.isnan(back.margin).all()
    assert not any(back.force_closure) and len(back.separating_wrenches) == 0


@settings(max_examples=80, deadline=None)
@given(verdict_arrays())
def test_decoded_verdict_array_equals_rclpy_deserialization(case):
    from grasp_fc_ros.interface.conversions import verdict_array_to_numpy, verdicts_to_array_msg

    header, client_id, request_id, verdicts = case
    msg = verdicts_to_array_msg(verdicts)
    msg.header, msg.client_id, msg.request_id = header, client_id, request_id
    got_client, got_request, got = wire.decode_verdict_array(serialize_message(msg))
    want = verdict_array_to_numpy(msg)
    assert (got_client, got_request) == (client_id, request_id)
    assert got.messages == want.messages
    for name in ("ids", "force_closure", "status", "margin", "contact_forces",
                 "contact_torques", "separating_wrench", "min_friction", "epsilon_lower",
                 "epsilon_upper"):
        assert same_field(getattr(got, name), getattr(want, name)), name


def test_a_truncated_verdict_array_is_refused():
    from std_msgs.msg import Header

    from grasp_fc_ros.packed import Verdicts

    raw = wire.encode_verdict_array(Header(), 1, 2, Verdicts.failed(np.arange(5), 1, ""))
    with pytest.raises(ValueError):
        wire.decode_verdict_array(raw[:40])
    with pytest.raises(ValueError):
        wire.decode_verdict_array(b"\x01\x00\x00\x00" + raw[4:])  # big-endian


# --- batches of grasps: ContactArrayBatch ----------------------------------------------

# Any float64, and many near the extremes (negative, huge, tiny).
BATCH_FLOATS = st.one_of(FLOATS, st.sampled_from([-0.0, -1e308, 1e308, -2.0**62, 5e-324,
                                                  -math.inf, math.nan]))
# Frame ids with non-ASCII characters (several UTF-8 bytes each: every alignment).
FRAME_IDS = st.one_of(TEXT, st.sampled_from(["", "é", "wrist_ü", "手首", "a🦾", "abcdefg"]))
BATCH_TYPECODES = ("Q", "I", "d", "d", "d", "d")


@st.composite
def batches(draw):
    """Arguments of grasps_to_batch_msg / batch_arrays for 0..6 grasps of 1..8 contacts,
    with the header and ids of a batch query."""
    counts = draw(st.lists(st.integers(1, 8), max_size=6))
    k = sum(counts)
    per_contact = st.lists(BATCH_FLOATS, min_size=k, max_size=k)
    positions = np.array(draw(st.lists(BATCH_FLOATS, min_size=3 * k, max_size=3 * k)),
                         np.float64).reshape(k, 3)
    normals = np.array(draw(st.lists(BATCH_FLOATS, min_size=3 * k, max_size=3 * k)),
                       np.float64).reshape(k, 3)
    mu = draw(st.one_of(st.none(), BATCH_FLOATS, per_contact))
    gamma = draw(st.one_of(st.none(), BATCH_FLOATS))
    ids = np.array(draw(st.lists(UINT64, min_size=len(counts), max_size=len(counts))),
                   np.uint64)
    stamp = (draw(st.integers(-2**31, 2**31 - 1)), draw(st.integers(0, 2**32 - 1)))
    return dict(ids=ids, positions=positions, normals=normals, mu=mu, counts=counts,
                torsional_friction=gamma, client_id=draw(UINT64), request_id=draw(UINT64),
                frame_id=draw(FRAME_IDS), stamp=stamp)


def batch_reference(case):
    """The batch as grasps_to_batch_msg builds it, with the case's header."""
    from grasp_fc_ros.interface.conversions import grasps_to_batch_msg

    msg = grasps_to_batch_msg(case["ids"], case["positions"], case["normals"], case["mu"],
                              case["counts"], client_id=case["client_id"],
                              request_id=case["request_id"],
                              torsional_friction=case["torsional_friction"])
    msg.header.frame_id = case["frame_id"]
    msg.header.stamp.sec, msg.header.stamp.nanosec = case["stamp"]
    return msg


def fields_of(case):
    from grasp_fc_ros.interface.conversions import batch_arrays

    return batch_arrays(case["ids"], case["positions"], case["normals"], case["mu"],
                        case["counts"], case["torsional_friction"])


def assert_same_batch(got, want):
    """Equal ContactArrayBatch messages, the float sequences bit for bit (NaN too), each
    sequence an array.array of its field's type code."""
    from grasp_fc_msgs.msg import ContactArrayBatch

    assert type(got) is ContactArrayBatch
    assert (got.header.frame_id, got.header.stamp.sec, got.header.stamp.nanosec) == (
        want.header.frame_id, want.header.stamp.sec, want.header.stamp.nanosec)
    assert (got.client_id, got.request_id) == (want.client_id, want.request_id)
    for name, typecode in zip(("ids", "contact_counts", "positions", "normals",
                               "friction_coefficients", "torsional_friction"),
                              BATCH_TYPECODES, strict=True):
        a, b = getattr(got, name), getattr(want, name)
        assert type(a) is array.array and a.typecode == typecode, name
        assert (len(a), a.tobytes()) == (len(b), b.tobytes()), name


@settings(max_examples=150, deadline=None)
@given(batches())
def test_decoded_batch_equals_rclpy_deserialization(case):
    from grasp_fc_msgs.msg import ContactArrayBatch

    reference = batch_reference(case)
    raw = serialize_message(reference)
    decoded = wire.decode_contact_array_batch(raw)
    assert_same_batch(decoded, reference)
    assert_same_batch(decoded, deserialize_message(raw, ContactArrayBatch))
    # The decoded message is a message like any other: rclpy serializes it, its setters work.
    assert_same_batch(deserialize_message(serialize_message(decoded), ContactArrayBatch),
                      reference)
    decoded.request_id = 3
    assert decoded.request_id == 3


@settings(max_examples=100, deadline=None)
@given(batches(), st.data())
def test_a_damaged_batch_is_refused_with_value_error(case, data):
    # rclpy's bytes end in unused buffer bytes: cut into the message, refused; cut in
    # those bytes only, the same message. The message's own length is that of its
    # big-endian form.
    length = len(big_endian_batch(fields_of(case), case["client_id"], case["request_id"],
                                  case["frame_id"], case["stamp"]))
    theirs = serialize_message(batch_reference(case))
    cut = data.draw(st.integers(0, len(theirs) - 1))
    if cut < length:
        with pytest.raises(ValueError):
            wire.decode_contact_array_batch(theirs[:cut])
    else:
        assert_same_batch(wire.decode_contact_array_batch(theirs[:cut]), batch_reference(case))
    with pytest.raises(ValueError):  # big-endian CDR
        wire.decode_contact_array_batch(b"\x00\x00\x00\x00" + theirs[4:])
    with pytest.raises(ValueError):  # not plain CDR
        wire.decode_contact_array_batch(b"\x01\x00\x00\x00" + theirs[4:])


def big_endian_batch(fields, client_id, request_id, frame_id, stamp) -> bytes:
    """A serialized ContactArrayBatch in big-endian plain CDR (as another machine may
    send it), written here independently of wire."""
    out = bytearray()

    def pad(size):
        out.extend(bytes(-len(out) % size))

    frame = frame_id.encode("utf-8") + b"\0"
    out += struct.pack(">iII", *stamp, len(frame)) + frame
    pad(8)
    out += struct.pack(">QQ", client_id, request_id)
    for values, dtype in zip(fields, (">u8", ">u4", ">f8", ">f8", ">f8", ">f8"), strict=True):
        pad(4)
        out += struct.pack(">I", len(values))
        if len(values):
            pad(np.dtype(dtype).itemsize)
            out += np.asarray(values).astype(dtype).tobytes()
    return b"\x00\x00\x00\x00" + bytes(out)


@settings(max_examples=40, deadline=None)
@given(batches())
def test_a_big_endian_batch_is_left_to_rclpy(case):
    from grasp_fc_msgs.msg import ContactArrayBatch

    raw = big_endian_batch(fields_of(case), case["client_id"], case["request_id"], case["frame_id"],
                           case["stamp"])
    assert_same_batch(deserialize_message(raw, ContactArrayBatch), batch_reference(case))
    with pytest.raises(ValueError):
        wire.decode_contact_array_batch(raw)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=80))
def test_arbitrary_bytes_decode_to_a_batch_or_value_error(tail):
    from grasp_fc_msgs.msg import ContactArrayBatch

    try:
        decoded = wire.decode_contact_array_batch(wire.CDR_LE + tail)
    except ValueError:
        return
    assert type(decoded) is ContactArrayBatch


@st.composite
def mis_packed_batches(draw):
    """ContactArrayBatch fields of any lengths, mostly not matching each other."""
    n = draw(st.integers(0, 4))
    counts = draw(st.lists(st.integers(0, 5), max_size=5))
    k = draw(st.integers(0, 12))
    floats = st.floats(-1e3, 1e3)
    return (np.array(draw(st.lists(UINT64, min_size=n, max_size=n)), np.uint64),
            np.array(counts, np.uint32),
            np.array(draw(st.lists(floats, min_size=3 * k, max_size=3 * k + 2)), np.float64),
            np.array(draw(st.lists(floats, min_size=3 * k, max_size=3 * k + 2)), np.float64),
            np.array(draw(st.lists(floats, max_size=k + 1)), np.float64),
            np.array(draw(st.lists(floats, max_size=k + 1)), np.float64))


@settings(max_examples=150, deadline=None)
@given(mis_packed_batches(), UINT64, UINT64)
def test_an_inconsistent_batch_decodes_as_rclpy_reads_it_and_is_malformed(sequences, client_id,
                                                                         request_id):
    from grasp_fc_msgs.msg import ContactArrayBatch

    from grasp_fc_ros.interface.conversions import (
        BatchArrays,
        MalformedBatch,
        batch_msg,
        batch_to_packed,
    )

    reference = batch_msg(BatchArrays(*sequences), client_id=client_id, request_id=request_id)
    reference.header.frame_id = "palm"
    raw = serialize_message(reference)
    theirs = deserialize_message(raw, ContactArrayBatch)
    assert_same_batch(theirs, reference)
    ours = wire.decode_contact_array_batch(raw)
    assert_same_batch(ours, theirs)
    assert ours == theirs
    ids, counts, positions, normals, mu, gamma = sequences
    total = int(counts.sum())
    consistent = (len(counts) == len(ids) and len(positions) == len(normals) == 3 * total
                  and len(mu) in (0, total) and len(gamma) in (0, total))
    if consistent:
        packed = batch_to_packed(ours)
        np.testing.assert_array_equal(packed.ids, ids)
        np.testing.assert_array_equal(packed.positions.reshape(-1), positions)
    else:
        with pytest.raises(MalformedBatch) as ours_error:
            batch_to_packed(ours)
        with pytest.raises(MalformedBatch) as their_error:
            batch_to_packed(theirs)
        assert str(ours_error.value) == str(their_error.value)


def test_batch_layout_check_fails_on_a_wrong_layout(monkeypatch):
    assert wire._batch_layout_matches()
    # Same sizes, other byte order: rclpy reads other positions, we read other ones.
    monkeypatch.setattr(wire, "_BATCH_DTYPES", ("<u8", "<u4", ">f8", "<f8", "<f8", "<f8"))
    assert not wire._batch_layout_matches()
    assert not wire.layout_matches.__wrapped__()  # (uncached: the rmw's answer stays)
