"""Take a serialized message from an rclpy subscription without holding the GIL.

rclpy's ``take_message(..., raw=True)`` holds the GIL while rcl copies the message out
of the middleware and again while it copies it into a ``bytes`` object: for a batch of
tens of MB long enough to hold up every other thread of the process, the node's service
thread included (measured: docs/performance.md#raw-one-message-batches).
:func:`take_serialized` calls rcl's C function ``rcl_take_serialized_message`` through
ctypes, which releases the GIL for the call, and copies the result into a ``bytes``
object with ``ctypes.memmove``, which releases it too. The library is the ``librcl.so``
rclpy has already loaded (found by its soname); the structures below are those of rcl
and rcutils, whose layout has not changed since ROS 2 Dashing (rclpy is pinned in
requirements.txt).
"""

from __future__ import annotations

import ctypes
from typing import Any

# rcl_ret_t values (rcl/types.h).
_RCL_RET_OK = 0
_RCL_RET_SUBSCRIPTION_TAKE_FAILED = 401


class _Allocator(ctypes.Structure):
    """rcutils_allocator_t."""

    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p),
                ("reallocate", ctypes.c_void_p), ("zero_allocate", ctypes.c_void_p),
                ("state", ctypes.c_void_p)]


class _Uint8Array(ctypes.Structure):
    """rcutils_uint8_array_t, which rcl_serialized_message_t is."""

    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _ErrorString(ctypes.Structure):
    """rcutils_error_string_t."""

    _fields_ = [("text", ctypes.c_char * 1024)]


class _Rcl:
    """The C functions used, bound once (:func:`_rcl`)."""

    def __init__(self) -> None:
        rcl = ctypes.CDLL("librcl.so")
        rcutils = ctypes.CDLL("librcutils.so")
        self.take = rcl.rcl_take_serialized_message
        self.take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Uint8Array),
                              ctypes.c_void_p, ctypes.c_void_p]
        self.take.restype = ctypes.c_int
        self.default_allocator = rcutils.rcutils_get_default_allocator
        self.default_allocator.restype = _Allocator
        self.init = rcutils.rcutils_uint8_array_init
        self.init.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t,
                              ctypes.POINTER(_Allocator)]
        self.init.restype = ctypes.c_int
        self.fini = rcutils.rcutils_uint8_array_fini
        self.fini.argtypes = [ctypes.POINTER(_Uint8Array)]
        self.fini.restype = ctypes.c_int
        self.error_string = rcutils.rcutils_get_error_string
        self.error_string.restype = _ErrorString
        self.reset_error = rcutils.rcutils_reset_error
        self.reset_error.restype = None
        # Python's own C function, called with the GIL held: a new bytes object of a
        # given size, left unwritten when given no source (NULL).
        self.new_bytes = ctypes.pythonapi.PyBytes_FromStringAndSize
        self.new_bytes.argtypes = [ctypes.c_void_p, ctypes.c_ssize_t]
        self.new_bytes.restype = ctypes.py_object

    def failure(self, what: str, ret: int) -> RuntimeError:
        text = self.error_string().text.decode(errors="replace")
        self.reset_error()
        return RuntimeError(f"{what} failed ({ret}): {text}")


_bound: _Rcl | None = None


def _rcl() -> _Rcl:
    global _bound
    if _bound is None:
        _bound = _Rcl()
    return _bound


def take_serialized(handle: Any) -> bytes | None:
    """The oldest message of a subscription, serialized; None if it holds none.

    Parameters
    ----------
    handle : rclpy's subscription handle (``Subscription.handle``)
        Held (``with handle:``) by the caller, so that it is not destroyed meanwhile.

    Raises
    ------
    RuntimeError
        If rcl fails otherwise (e.g. the subscription was destroyed), with rcl's message.
    """
    rcl = _rcl()
    message = _Uint8Array()
    allocator = rcl.default_allocator()
    ret = rcl.init(ctypes.byref(message), 0, ctypes.byref(allocator))
    if ret != _RCL_RET_OK:
        raise rcl.failure("rcutils_uint8_array_init", ret)
    try:
        ret = rcl.take(handle.pointer, ctypes.byref(message), None, None)
        if ret == _RCL_RET_SUBSCRIPTION_TAKE_FAILED:
            return None
        if ret != _RCL_RET_OK:
            raise rcl.failure("rcl_take_serialized_message", ret)
        size = message.buffer_length
        taken: bytes = rcl.new_bytes(None, size)
        # Written once, here, before any other code can see it (as C code fills the
        # result of PyBytes_FromStringAndSize(NULL, size)); the copy runs without the GIL.
        ctypes.memmove(ctypes.c_char_p(taken), message.buffer, size)
        return taken
    finally:
        rcl.fini(ctypes.byref(message))
