"""Serve and call rclpy services, and take topic messages, with a bare wait set
instead of an executor.

rclpy's executors rebuild their wait set from every entity of their nodes at each
wake-up and run each request and each response as a Task; for a one-grasp
``check_force_closure`` call that costs more than deciding the grasp
(docs/performance.md#service-latency).

:class:`ServiceLoop` takes one request at a time, calls its service's callback and sends
the response, as ``SingleThreadedExecutor`` would; :class:`ServiceCaller` sends a
request and waits for its response in the calling thread. Both use rclpy's wait-set,
service and client handles, which rclpy's own executors and ``rclpy.wait_for_message``
use too (rclpy is pinned in requirements.txt).

:class:`SubscriptionLoop` does the same for one busy subscription: it takes every
message the subscription holds at each wake-up and hands them over as one list. On the
node's executor each wake-up rebuilt a wait set of a dozen entities (parameter services,
timer, the batch topic) for what was often one query.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, cast

from rclpy.callback_groups import CallbackGroup
from rclpy.client import Client
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.service import Service
from rclpy.subscription import Subscription

from grasp_fc_ros.interface.rcl_take import take_serialized

# How long one wait lasts (ns) before the loop looks at its stop flag again (stop() also
# wakes it at once through a guard condition), or a caller at rclpy's state and at
# Python's signal handlers (Ctrl-C).
WAIT_NS = 100_000_000
# Until a caller's first response came, an unanswered request is sent again after this
# long (s), then after twice as long, and so on. rmw_fastrtps drops a response when the
# server has not yet discovered the client's response reader (it waits 100 ms, then
# rclpy warns "failed to send response (timeout): client will not receive response"):
# a new client's first request on a loaded machine. Once a response came, the server
# knows the reader and no request is sent twice. The services' queries are idempotent.
FIRST_RESPONSE_RESEND_S = 2.0


class _WaitSetThread:
    """A daemon thread that waits on a bare rclpy wait set until :meth:`stop`.

    Subclasses call :meth:`_start` with the wait set's sizes and say what it waits on
    (:meth:`_add_entities`) and what to do when it wakes (:meth:`_on_ready`).
    """

    def _start(self, context: Context, sizes: tuple[int, int, int, int, int, int],
               name: str) -> None:
        """Start the thread; ``sizes``: subscriptions, guard conditions, timers,
        clients, services and events of the wait set, the guard condition included."""
        self._context = context
        self._sizes = sizes
        self._stopping = False
        self._wake = GuardCondition(callback=None, callback_group=None, context=context)
        self._thread = threading.Thread(target=self._run, daemon=True, name=name)
        self._thread.start()

    @property
    def running(self) -> bool:
        """True until the thread has ended (after :meth:`stop`, or rclpy's shutdown)."""
        return self._thread.is_alive()

    def stop(self) -> None:
        """Let the work in progress finish, then end the thread (a second call does
        nothing)."""
        if self._stopping:
            return
        self._stopping = True
        self._wake.trigger()
        self._thread.join()
        self._wake.destroy()

    def _add_entities(self, wait_set: Any) -> None:
        raise NotImplementedError

    def _on_ready(self, wait_set: Any) -> None:
        raise NotImplementedError

    def _run(self) -> None:
        try:
            wait_set = _rclpy.WaitSet(*self._sizes, self._context.handle)
            while not self._stopping:
                wait_set.clear_entities()
                wait_set.add_guard_condition(self._wake.handle)
                self._add_entities(wait_set)
                wait_set.wait(WAIT_NS)
                self._on_ready(wait_set)
        except Exception:  # noqa: BLE001
            if self._context.ok() and not self._stopping:
                raise  # a bug, not a shutdown: the thread's traceback shows it


class ServiceLoop(_WaitSetThread):
    """Serve ``services`` on a daemon thread until :meth:`stop` (which lets the request
    in progress be answered).

    Parameters
    ----------
    services : list of rclpy.service.Service
        Created on a node that no executor spins (the loop takes their requests).
    context : rclpy.context.Context
    on_error : callable(Service, Exception)
        Called when a request cannot be served (its callback raised, or the response
        could not be sent); the loop goes on with the next request.
    name : str
        The thread's name.
    """

    def __init__(self, services: list[Service], context: Context,
                 on_error: Callable[[Service, Exception], None], name: str = "service"):
        self._services = list(services)
        self._on_error = on_error
        self._start(context, (0, 1, 0, 0, len(self._services), 0), name)

    def _add_entities(self, wait_set: Any) -> None:
        for service in self._services:
            wait_set.add_service(service.handle)

    def _on_ready(self, wait_set: Any) -> None:
        ready = wait_set.get_ready_entities("service")
        for service in self._services:
            if service.handle.pointer in ready:
                self._serve_one(service)

    def _serve_one(self, service: Service) -> None:
        srv_type: Any = service.srv_type  # a generated service type: Request, Response
        with service.handle:
            request, header = service.handle.service_take_request(srv_type.Request)
        if header is None:
            return  # the wait set saw a request that another reader took
        try:
            response = service.callback(request, srv_type.Response())
            service.send_response(response, header)
        except Exception as exc:  # noqa: BLE001 - one request must not end the loop
            if isinstance(exc, InvalidHandle) or not self._context.ok():
                raise  # destroyed or shut down: nothing more can be sent
            self._on_error(service, exc)  # e.g. the client left before its response


class ServiceCaller:
    """Call one service and wait for each response in the calling thread.

    Parameters
    ----------
    client : rclpy.client.Client
        Created on a node that no executor spins (this object takes its responses).

    Calls from several threads take turns: each holds a lock from its request to its
    response (the node serves one request at a time anyway); the requests of
    :meth:`call_each` take turns one by one, so another thread's call may go between
    them. A response that comes after its call timed out is dropped when the next call
    waits. Until the first response came, an unanswered request is sent again
    (:data:`FIRST_RESPONSE_RESEND_S`, doubling) and the first response to any copy is
    the call's.
    """

    def __init__(self, client: Client) -> None:
        self._client = client
        self._lock = threading.Lock()
        self._answered_once = False
        self._wait_set = _rclpy.WaitSet(0, 0, 0, 1, 0, 0, client.context.handle)

    def call(self, request: Any, timeout: float) -> Any:
        """The response to ``request``.

        Raises
        ------
        TimeoutError
            If it did not come within ``timeout`` seconds (a busy caller's time counts);
            the message names the service and says the node may be down.
        RuntimeError
            If rclpy shut down while waiting.
        """
        return self._call(request, time.monotonic() + timeout, timeout)

    def call_each(self, requests: list[Any], timeout: float) -> list[Any]:
        """The responses to ``requests``, sent one after the other (each once the one
        before was answered), within ``timeout`` seconds for them all.

        Raises
        ------
        TimeoutError, RuntimeError
            As :meth:`call` (the message names the whole ``timeout``); the responses
            that came are dropped.
        """
        deadline = time.monotonic() + timeout
        return [self._call(request, deadline, timeout) for request in requests]

    def _call(self, request: Any, deadline: float, timeout: float) -> Any:
        """The response to ``request`` by ``deadline`` (time.monotonic(), s);
        ``timeout`` is what the error names."""
        if not self._lock.acquire(timeout=max(deadline - time.monotonic(), 0.0)):
            raise TimeoutError(self._timed_out(timeout))
        try:
            handle = self._client.handle
            sequences: set[int] = set()
            resend_after = FIRST_RESPONSE_RESEND_S
            resend_at = time.monotonic()
            while True:
                now = time.monotonic()
                if now >= resend_at and (not sequences or not self._answered_once):
                    with handle:
                        sequences.add(handle.send_request(request))
                    resend_at, resend_after = now + resend_after, 2 * resend_after
                remaining = deadline - now
                if remaining <= 0:
                    raise TimeoutError(self._timed_out(timeout))
                if not self._client.context.ok():
                    raise RuntimeError("rclpy shut down while waiting for a response")
                self._wait_set.clear_entities()
                self._wait_set.add_client(handle)
                self._wait_set.wait(min(int(remaining * 1e9), WAIT_NS))
                if handle.pointer not in self._wait_set.get_ready_entities("client"):
                    continue
                srv_type: Any = self._client.srv_type
                with handle:
                    header, response = handle.take_response(srv_type.Response)
                if header is not None and header.request_id.sequence_number in sequences:
                    self._answered_once = True
                    return response
        finally:
            self._lock.release()

    def _timed_out(self, timeout: float) -> str:
        return (f"no response from service {self._client.srv_name} within {timeout} s: "
                f"its node may be down (or busy)")


class OwnThreadGroup(CallbackGroup):
    """A callback group that no executor runs: its entities are served by a loop of their
    own (:class:`SubscriptionLoop`), so an executor spinning their node skips them."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


class SubscriptionLoop(_WaitSetThread):
    """Subscribe to a topic and hand its messages over in lists, from a thread of its own.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that owns the subscription (any executor spinning it skips it).
    msg_type, topic, qos, raw, qos_overriding_options
        As for ``Node.create_subscription``.
    on_messages : callable(list)
        Called with the messages taken at one wake-up, oldest first: serialized bytes
        if ``raw``, else messages; at most ``max_take`` of them.
    on_error : callable(Exception)
        Called when ``on_messages`` raised; the loop goes on.
    max_take : int
        Most messages handed over at once.
    name : str
        The thread's name.
    gil_free : bool
        Take serialized messages (``raw`` only) with
        :func:`~grasp_fc_ros.interface.rcl_take.take_serialized`, which holds the GIL for
        none of the copying: for topics of messages of many MB, whose take through rclpy
        would hold up every other thread of the process.

    :meth:`stop` lets the messages being handed over finish and ends the thread; the
    subscription stays, for its node to destroy.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, qos: QoSProfile,
                 on_messages: Callable[[list], None], on_error: Callable[[Exception], None],
                 *, raw: bool = False, max_take: int = 2_000, name: str = "subscription",
                 gil_free: bool = False, **subscription_options: Any):
        if gil_free and not raw:
            raise ValueError("gil_free takes serialized messages: it needs raw=True")
        self._msg_type = msg_type
        self._on_messages = on_messages
        self._on_error = on_error
        self._max_take = max_take
        self._raw = raw
        self._gil_free = gil_free
        self.subscription: Subscription = node.create_subscription(
            msg_type, topic, on_messages, qos, raw=raw, callback_group=OwnThreadGroup(),
            **subscription_options)
        # Its QoS events (message lost, incompatible QoS) are handled here too: in the
        # node's executor, their wait set woke the executor at every message (measured:
        # docs/performance.md#single-topic). rclpy annotates event_handlers as one
        # EventHandler; it is a list.
        self._events: list[Any] = list(cast("list[Any]", self.subscription.event_handlers))
        self._start(node.context, (1, 1, 0, 0, 0, len(self._events)), name)

    def _add_entities(self, wait_set: Any) -> None:
        wait_set.add_subscription(self.subscription.handle)
        for event in self._events:
            event.add_to_wait_set(wait_set)

    def _on_ready(self, wait_set: Any) -> None:
        for event in self._events:
            if event.is_ready(wait_set):
                taken = event.take_data()
                if taken:
                    try:
                        event.callback(taken)
                    except Exception as exc:  # noqa: BLE001 - one event must not end the loop
                        self._on_error(exc)
        handle = self.subscription.handle
        if handle.pointer not in wait_set.get_ready_entities("subscription"):
            return
        taken = self._take(handle)
        if not taken:
            return  # the wait set saw a message that another reader took
        try:
            self._on_messages(taken)
        except Exception as exc:  # noqa: BLE001 - one pass must not end the loop
            self._on_error(exc)

    def _take(self, handle: Any) -> list:
        taken: list = []
        with handle:
            while len(taken) < self._max_take:
                if self._gil_free:
                    message = take_serialized(handle)
                else:
                    info = handle.take_message(self._msg_type, self._raw)
                    message = None if info is None else info[0]
                if message is None:
                    break
                taken.append(message)
        return taken
