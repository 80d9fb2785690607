"""Build the hot message types from their fields without their generated constructors.

A rosidl-generated constructor builds a default for every field (a
``ForceClosureVerdict``: a header with its stamp, a wrench with two vectors, ...) and
sets each through a property that checks its type, before the caller replaces them.
That costs several times what is done here (docs/performance.md#wire-format): on the
one-grasp service path and for every single verdict, a measurable share of a query. The
builders below set the values straight into the message's slots: rosidl keeps field
``f`` in slot ``_f``, next to ``_check_fields``.

:data:`FAST` checks that layout for every type built here when this module is
imported. Where it does not hold, or where the user asked for field checks
(``ROS_PYTHON_CHECK_FIELDS=1``), each builder calls the constructor instead. The
builders take values already of their field's type (Python floats, ints, bools and
str, messages for nested messages, ``array.array("d")`` for float64 sequences).
"""

from __future__ import annotations

import array
import math
import os
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Vector3, Wrench
from grasp_fc_msgs.msg import Contact, ContactArrayBatch, ForceClosureVerdict
from std_msgs.msg import Header

# As the generated modules decide whether their setters check values.
_CHECK_FIELDS = os.getenv("ROS_PYTHON_CHECK_FIELDS", default="") == "1"


def _has_field_slots(message_type: Any) -> bool:
    fields = ["_" + name for name in message_type.get_fields_and_field_types()]
    return list(message_type.__slots__) == fields + ["_check_fields"]


#: True where the builders set slots directly (else they call the constructors).
FAST = not _CHECK_FIELDS and all(
    _has_field_slots(t) for t in (Time, Header, Point, Vector3, Wrench, Contact,
                                  ContactArrayBatch, ForceClosureVerdict))

_new = object.__new__


def time_msg(sec: int, nanosec: int) -> Time:
    if not FAST:
        return Time(sec=sec, nanosec=nanosec)
    msg = _new(Time)
    msg._sec, msg._nanosec, msg._check_fields = sec, nanosec, False
    return msg


def header(stamp: Time, frame_id: str) -> Header:
    if not FAST:
        return Header(stamp=stamp, frame_id=frame_id)
    msg = _new(Header)
    msg._stamp, msg._frame_id, msg._check_fields = stamp, frame_id, False
    return msg


def point(x: float, y: float, z: float) -> Point:
    if not FAST:
        return Point(x=x, y=y, z=z)
    msg = _new(Point)
    msg._x, msg._y, msg._z, msg._check_fields = x, y, z, False
    return msg


def vector3(x: float, y: float, z: float) -> Vector3:
    if not FAST:
        return Vector3(x=x, y=y, z=z)
    msg = _new(Vector3)
    msg._x, msg._y, msg._z, msg._check_fields = x, y, z, False
    return msg


def wrench(force: Vector3, torque: Vector3) -> Wrench:
    if not FAST:
        return Wrench(force=force, torque=torque)
    msg = _new(Wrench)
    msg._force, msg._torque, msg._check_fields = force, torque, False
    return msg


def nan_wrench() -> Wrench:
    """A Wrench of NaNs: the verdict messages' "no separating wrench"."""
    return wrench(vector3(math.nan, math.nan, math.nan), vector3(math.nan, math.nan, math.nan))


def contact(position: Point, normal: Vector3, friction_coefficient: float,
            torsional_friction: float) -> Contact:
    if not FAST:
        return Contact(position=position, normal=normal,
                       friction_coefficient=friction_coefficient,
                       torsional_friction=torsional_friction)
    msg = _new(Contact)
    msg._position, msg._normal = position, normal
    msg._friction_coefficient, msg._torsional_friction = friction_coefficient, torsional_friction
    msg._check_fields = False
    return msg


def verdict(header: Header, client_id: int, query_id: int, force_closure: bool, status: int,
            margin: float, message: str, contact_forces: list[Vector3],
            contact_torques: array.array, separating_wrench: Wrench,
            min_friction: float, epsilon_lower: float = math.nan,
            epsilon_upper: float = math.nan) -> ForceClosureVerdict:
    if not FAST:
        return ForceClosureVerdict(
            header=header, client_id=client_id, id=query_id, force_closure=force_closure,
            status=status, margin=margin, message=message, contact_forces=contact_forces,
            contact_torques=contact_torques, separating_wrench=separating_wrench,
            min_friction=min_friction, epsilon_lower=epsilon_lower,
            epsilon_upper=epsilon_upper)
    msg = _new(ForceClosureVerdict)
    msg._header, msg._client_id, msg._id = header, client_id, query_id
    msg._force_closure, msg._status, msg._margin = force_closure, status, margin
    msg._message, msg._contact_forces, msg._contact_torques = (message, contact_forces,
                                                               contact_torques)
    msg._separating_wrench, msg._min_friction = separating_wrench, min_friction
    msg._epsilon_lower, msg._epsilon_upper = epsilon_lower, epsilon_upper
    msg._check_fields = False
    return msg


def contact_array_batch(header: Header, client_id: int, request_id: int,
                        sequences: list[array.array]) -> ContactArrayBatch:
    """``sequences``: ids ("Q"), contact_counts ("I"), positions, normals,
    friction_coefficients, torsional_friction ("d"), in that order. The generated
    setters would copy each array.array again."""
    if not FAST:
        msg = ContactArrayBatch(header=header, client_id=client_id, request_id=request_id)
        (msg.ids, msg.contact_counts, msg.positions, msg.normals, msg.friction_coefficients,
         msg.torsional_friction) = sequences
        return msg
    msg = _new(ContactArrayBatch)
    msg._header, msg._client_id, msg._request_id = header, client_id, request_id
    (msg._ids, msg._contact_counts, msg._positions, msg._normals, msg._friction_coefficients,
     msg._torsional_friction) = sequences
    msg._check_fields = False
    return msg
