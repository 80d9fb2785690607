"""message_slots: messages built from their fields equal those of the generated
constructors, field for field and byte for byte (no DDS)."""

from __future__ import annotations

import array
import math
import os

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3, Wrench
from grasp_fc_msgs.msg import Contact, ContactArrayBatch, ForceClosureVerdict
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header

from grasp_fc_ros.interface import message_slots as slots

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
# ROS strings are C strings: no NUL inside (rclpy's CDR ends them there, so a round
# trip of "\0" gives "").
TEXT = st.text(st.characters(blacklist_characters="\0", blacklist_categories=("Cs",)),
               max_size=12)


def built_and_constructed(sec, nanosec, frame, numbers, flags, text, forces, torques):
    """The same verdict (and its nested messages) from the builders and from the
    generated constructors."""
    x, y, z, margin, min_friction, lower, upper = numbers
    client_id, query_id, status = flags

    def verdict(time_msg, header, vector3, wrench, verdict_type):
        return verdict_type(
            header(time_msg(sec, nanosec), frame), client_id, query_id, status % 2 == 0,
            status, margin, text, [vector3(*f) for f in forces], array.array("d", torques),
            wrench(vector3(x, y, z), vector3(z, y, x)), min_friction, lower, upper)

    built = verdict(slots.time_msg, slots.header, slots.vector3, slots.wrench, slots.verdict)
    constructed = verdict(
        lambda s, n: Time(sec=s, nanosec=n), lambda s, f: Header(stamp=s, frame_id=f),
        lambda a, b, c: Vector3(x=a, y=b, z=c), lambda f, t: Wrench(force=f, torque=t),
        lambda *v: ForceClosureVerdict(**dict(zip(
            ForceClosureVerdict.get_fields_and_field_types(), v, strict=True))))
    return built, constructed


def round_trip(msg):
    return deserialize_message(serialize_message(msg), type(msg))


def test_this_rosidl_keeps_fields_in_underscore_slots():
    assert slots.FAST == (os.environ.get("ROS_PYTHON_CHECK_FIELDS", "") != "1")


@settings(max_examples=80, deadline=None)
@given(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1), TEXT,
       st.tuples(FLOATS, FLOATS, FLOATS, FLOATS, FLOATS, FLOATS, FLOATS),
       st.tuples(st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1), st.integers(0, 255)),
       TEXT, st.lists(st.tuples(FLOATS, FLOATS, FLOATS), max_size=4),
       st.lists(FLOATS, max_size=4))
def test_a_built_verdict_equals_the_constructed_one(sec, nanosec, frame, numbers, flags,
                                                    text, forces, torques):
    built, constructed = built_and_constructed(sec, nanosec, frame, numbers, flags, text,
                                               forces, torques)
    # NaN != NaN: compare what they print, also after a trip through rclpy's CDR (not
    # the bytes themselves: rclpy leaves padding bytes uninitialised).
    assert repr(built) == repr(constructed)
    assert repr(round_trip(built)) == repr(constructed)


def test_a_built_contact_equals_the_constructed_one_and_takes_new_values():
    built = slots.contact(slots.point(1.0, 2.0, 3.0), slots.vector3(0.0, 0.0, -1.0), 0.5, 0.01)
    constructed = Contact(position=Point(x=1.0, y=2.0, z=3.0),
                          normal=Vector3(x=0.0, y=0.0, z=-1.0), friction_coefficient=0.5,
                          torsional_friction=0.01)
    assert built == constructed
    built.position.x = 4.0  # the generated setters work on a built message
    constructed.position.x = 4.0
    assert round_trip(built) == constructed
    assert math.isnan(slots.nan_wrench().torque.z)


def test_without_the_slot_layout_the_builders_call_the_constructors(monkeypatch):
    monkeypatch.setattr(slots, "FAST", False)
    calls = []
    real = slots.Vector3

    def counted(**fields):
        calls.append(fields)
        return real(**fields)

    monkeypatch.setattr(slots, "Vector3", counted)
    assert slots.vector3(1.0, 2.0, 3.0) == Vector3(x=1.0, y=2.0, z=3.0)
    assert calls == [{"x": 1.0, "y": 2.0, "z": 3.0}]


@pytest.mark.parametrize("message_type", [Time, Header, Point, Vector3, Wrench, Contact,
                                          ContactArrayBatch, ForceClosureVerdict])
def test_every_built_type_has_the_slot_layout(message_type):
    assert slots._has_field_slots(message_type)


BATCH_FIELDS = ("ids", "contact_counts", "positions", "normals", "friction_coefficients",
                "torsional_friction")
BATCH_TYPECODES = ("Q", "I", "d", "d", "d", "d")


@pytest.mark.parametrize("fast", [True, False])
@settings(max_examples=40, deadline=None)
@given(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1), TEXT,
       st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1),
       st.lists(st.integers(0, 2**64 - 1), max_size=4),
       st.lists(st.integers(0, 2**32 - 1), max_size=4),
       st.lists(st.lists(FLOATS, max_size=7), min_size=4, max_size=4))
def test_a_built_batch_equals_the_constructed_one(fast, sec, nanosec, frame, client_id,
                                                  request_id, ids, counts, floats):
    if not fast and not slots.FAST:
        pytest.skip("the constructor path is the only one here")

    def sequences():  # fresh arrays per message: the built one may keep them
        return [array.array(code, values) for code, values in
                zip(BATCH_TYPECODES, [ids, counts, *floats], strict=True)]

    original, fast_flag = slots.FAST, (slots.FAST if fast else False)
    try:
        slots.FAST = fast_flag  # (not monkeypatch: hypothesis runs many examples per test)
        built = slots.contact_array_batch(Header(stamp=Time(sec=sec, nanosec=nanosec),
                                                 frame_id=frame), client_id, request_id,
                                          sequences())
    finally:
        slots.FAST = original
    constructed = ContactArrayBatch(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame),
        client_id=client_id, request_id=request_id,
        **dict(zip(BATCH_FIELDS, sequences(), strict=True)))
    for name, code in zip(BATCH_FIELDS, BATCH_TYPECODES, strict=True):
        field = getattr(built, name)
        assert type(field) is array.array and field.typecode == code, name
    # NaN != NaN: compare what they print, also after a trip through rclpy's CDR.
    assert repr(built) == repr(constructed)
    assert repr(round_trip(built)) == repr(constructed)
    if not any(math.isnan(v) for values in floats for v in values):
        assert built == constructed
    built.request_id = constructed.request_id = 5  # the generated setters work on it
    built.positions = constructed.positions = [1.5]
    assert repr(built) == repr(constructed)


def test_without_the_slot_layout_a_batch_is_built_by_its_constructor(monkeypatch):
    monkeypatch.setattr(slots, "FAST", False)
    calls = []

    def counted(**fields):
        calls.append(fields)
        return ContactArrayBatch(**fields)

    monkeypatch.setattr(slots, "ContactArrayBatch", counted)
    sequences = [array.array(code, [1] if code != "d" else [0.5]) for code in BATCH_TYPECODES]
    built = slots.contact_array_batch(Header(frame_id="f"), 3, 4, sequences)
    assert calls == [{"header": Header(frame_id="f"), "client_id": 3, "request_id": 4}]
    assert built == ContactArrayBatch(header=Header(frame_id="f"), client_id=3, request_id=4,
                                      **dict(zip(BATCH_FIELDS, sequences, strict=True)))
