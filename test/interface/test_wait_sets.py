"""ServiceLoop: services served from a wait set, without an executor (tiny services)."""

from __future__ import annotations

import threading
import time

import pytest

SERVE_TIMEOUT_S = 20.0
# The callback's call number that is slow, and by how much (s): longer than a caller's
# short time-out below.
SLOW_CALL = 3
SLOW_CALL_S = 0.5
SHORT_TIMEOUT_S = 0.1


@pytest.fixture
def served(ros):
    """(client, callback calls, errors, loop) for a SetBool service ``/loop_test_<pid>``
    served by a ServiceLoop; its callback answers "call <k>" and raises for False."""
    import os

    from rclpy.node import Node
    from std_srvs.srv import SetBool

    from grasp_fc_ros.interface.wait_sets import ServiceLoop
    from ros_fixtures import SpinThread

    name = f"/loop_test_{os.getpid()}"
    calls, errors = [], []

    def callback(request, response):
        calls.append(request.data)
        if not request.data:
            raise RuntimeError("False refused")
        if len(calls) == SLOW_CALL:
            time.sleep(SLOW_CALL_S)
        response.success = request.data
        response.message = f"call {len(calls)}"
        return response

    server = Node("loop_server", start_parameter_services=False)
    service = server.create_service(SetBool, name, callback)
    loop = ServiceLoop([service], server.context,
                       lambda s, exc: errors.append((s.srv_name, str(exc))))
    client_node = Node("loop_client", start_parameter_services=False)
    client = client_node.create_client(SetBool, name)
    spinner = SpinThread(client_node)
    assert client.wait_for_service(timeout_sec=SERVE_TIMEOUT_S)
    yield client, calls, errors, loop
    loop.stop()
    spinner.stop()
    server.destroy_node()


def call(client, data: bool):
    from std_srvs.srv import SetBool

    done = threading.Event()
    future = client.call_async(SetBool.Request(data=data))
    future.add_done_callback(lambda _: done.set())
    return future.result() if done.wait(SERVE_TIMEOUT_S) else None


def test_every_request_gets_its_own_response_in_order(served):
    client, calls, errors, _ = served
    answers = [call(client, True) for _ in range(50)]
    assert [a.message for a in answers] == [f"call {k}" for k in range(1, 51)]
    assert len(calls) == 50 and not errors


def test_a_failing_callback_is_reported_and_the_loop_goes_on(served):
    from std_srvs.srv import SetBool

    client, calls, errors, _ = served
    refused = client.call_async(SetBool.Request(data=False))
    assert call(client, True).message == "call 2"
    assert errors == [(client.srv_name, "False refused")]
    assert not refused.done()  # no response for the failed request


def test_stop_ends_the_thread_and_later_requests_are_not_taken(served):
    client, calls, _, loop = served
    assert call(client, True).success
    loop.stop()
    assert not loop.running
    from std_srvs.srv import SetBool

    client.call_async(SetBool.Request(data=True))
    threading.Event().wait(0.3)
    assert len(calls) == 1


@pytest.fixture
def caller(served):
    """A ServiceCaller on the served service, from a node that no executor spins."""
    from rclpy.node import Node
    from std_srvs.srv import SetBool

    from grasp_fc_ros.interface.wait_sets import ServiceCaller

    client, *_ = served
    node = Node("loop_caller", start_parameter_services=False)
    own = node.create_client(SetBool, client.srv_name)
    assert own.wait_for_service(timeout_sec=SERVE_TIMEOUT_S)
    yield ServiceCaller(own)
    node.destroy_node()


def test_a_caller_gets_each_response_and_drops_one_that_came_too_late(caller, served):
    from std_srvs.srv import SetBool

    _, calls, _, _ = served
    assert caller.call(SetBool.Request(data=True), SERVE_TIMEOUT_S).message == "call 1"
    assert caller.call(SetBool.Request(data=True), SERVE_TIMEOUT_S).message == "call 2"
    with pytest.raises(TimeoutError):
        caller.call(SetBool.Request(data=True), SHORT_TIMEOUT_S)  # call 3 is slow
    # Call 3's response arrives while call 4 waits: call 4 gets its own.
    assert caller.call(SetBool.Request(data=True), SERVE_TIMEOUT_S).message == "call 4"
    assert len(calls) == 4


def test_callers_in_several_threads_take_turns_and_get_their_own_responses(caller):
    from std_srvs.srv import SetBool

    answers: dict[int, list[str]] = {k: [] for k in range(4)}

    def ask(k):
        for _ in range(10):
            answers[k].append(caller.call(SetBool.Request(data=True), SERVE_TIMEOUT_S).message)

    threads = [threading.Thread(target=ask, args=(k,)) for k in answers]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    # Each call number 1..40 reached exactly one caller, each caller's in increasing order.
    got = sorted(int(m.split()[1]) for ms in answers.values() for m in ms)
    assert got == list(range(1, 41))
    assert all(ms == sorted(ms, key=lambda m: int(m.split()[1])) for ms in answers.values())


def test_a_caller_times_out_without_a_server(ros):
    from rclpy.node import Node
    from std_srvs.srv import SetBool

    from grasp_fc_ros.interface.wait_sets import ServiceCaller

    node = Node("lonely_caller", start_parameter_services=False)
    try:
        caller = ServiceCaller(node.create_client(SetBool, "/nobody_serves_this"))
        started = time.monotonic()
        with pytest.raises(TimeoutError):
            caller.call(SetBool.Request(data=True), SHORT_TIMEOUT_S)
        assert time.monotonic() - started >= SHORT_TIMEOUT_S
    finally:
        node.destroy_node()


def test_a_new_callers_request_whose_response_is_lost_is_sent_again_until_one_came(ros):
    """The response a server could not send (rmw_fastrtps drops it when it has not yet
    discovered a new client's response reader) is made up for by a resend; once a
    response came, a lost one is not (the call times out, its request sent once)."""
    import os

    from rclpy.node import Node
    from std_srvs.srv import SetBool

    from grasp_fc_ros.interface.wait_sets import (
        FIRST_RESPONSE_RESEND_S,
        ServiceCaller,
        ServiceLoop,
    )

    calls = []

    def callback(request, response):
        calls.append(request.data)
        if not request.data or len(calls) == 1:
            raise RuntimeError("response lost")  # the loop sends nothing for it
        response.message = f"call {len(calls)}"
        return response

    name = f"/lost_response_{os.getpid()}"
    server = Node("lost_server", start_parameter_services=False)
    loop = ServiceLoop([server.create_service(SetBool, name, callback)], server.context,
                       lambda service, exc: None)
    node = Node("lost_caller", start_parameter_services=False)
    try:
        own = node.create_client(SetBool, name)
        assert own.wait_for_service(timeout_sec=SERVE_TIMEOUT_S)
        caller = ServiceCaller(own)
        started = time.monotonic()
        assert caller.call(SetBool.Request(data=True), SERVE_TIMEOUT_S).message == "call 2"
        assert time.monotonic() - started >= FIRST_RESPONSE_RESEND_S
        with pytest.raises(TimeoutError):
            caller.call(SetBool.Request(data=False), 2.5 * FIRST_RESPONSE_RESEND_S)
        assert calls == [True, True, False]
    finally:
        loop.stop()
        node.destroy_node()
        server.destroy_node()


# SubscriptionLoop: a topic's messages taken from a wait set on a thread of its own.

TAKE_TIMEOUT_S = 10.0
MAX_TAKE = 7
BURST = 500


class Taken:
    """What a SubscriptionLoop handed over: each on_messages call's list and thread, and
    each on_error exception. ``hold_first`` makes the first call wait for ``release``,
    so that the messages published meanwhile pile up in the subscription."""

    def __init__(self, hold_first: bool = False, raise_first: Exception | None = None):
        self.calls: list[list] = []
        self.threads: list[str] = []
        self.errors: list[Exception] = []
        self.release = threading.Event()
        self._hold_first = hold_first
        self._raise_first = raise_first
        self._changed = threading.Condition(threading.RLock())

    def on_messages(self, msgs):
        with self._changed:
            self.calls.append(msgs)  # a list from the loop (one message from an executor)
            self.threads.append(threading.current_thread().name)
            first = len(self.calls) == 1
            self._changed.notify_all()
        if first and self._hold_first:
            self.release.wait(TAKE_TIMEOUT_S)
        if first and self._raise_first is not None:
            raise self._raise_first

    def on_error(self, exc):
        with self._changed:
            self.errors.append(exc)
            self._changed.notify_all()

    def flat(self) -> list:
        with self._changed:  # reentrant: wait_for_count calls it holding the lock
            return [m for call in self.calls
                    for m in (call if isinstance(call, list) else [call])]

    def wait_for(self, condition, what: str, timeout: float = TAKE_TIMEOUT_S):
        with self._changed:
            ok = self._changed.wait_for(condition, timeout)
        assert ok, f"{what} not within {timeout} s: {len(self.calls)} calls, {self.errors}"

    def wait_for_count(self, count: int, timeout: float = TAKE_TIMEOUT_S) -> list:
        self.wait_for(lambda: len(self.flat()) >= count, f"{count} messages", timeout)
        return self.flat()


def wait_matched(publisher, subscriptions: int = 1, timeout: float = SERVE_TIMEOUT_S):
    deadline = time.monotonic() + timeout
    while publisher.get_subscription_count() < subscriptions:
        assert time.monotonic() < deadline, "publisher and subscription(s) not matched"
        time.sleep(0.01)


@pytest.fixture
def subscribed(ros):
    """Factory: subscribe(msg_type, taken, subscriptions=1, before_loop=None,
    **loop_options) -> (loop, publisher, node): a SubscriptionLoop on topic
    ``/sub_loop_<pid>_<k>`` of a node of its own (``before_loop(node, topic)`` may add
    to that node first), and a publisher (QUERY_QOS) from another node, matched with
    ``subscriptions`` subscriptions; the loops stopped and the nodes destroyed after
    the test."""
    import copy
    import os

    from rclpy.node import Node

    from grasp_fc_ros.interface.names import QUERY_QOS
    from grasp_fc_ros.interface.wait_sets import SubscriptionLoop

    made = []

    def subscribe(msg_type, taken, subscriptions=1, before_loop=None, **options):
        k = len(made)
        topic = f"/sub_loop_{os.getpid()}_{k}"
        node = Node(f"sub_loop_{k}", start_parameter_services=False)
        pub_node = Node(f"sub_loop_pub_{k}", start_parameter_services=False)
        made.append((None, node, pub_node))
        if before_loop is not None:
            before_loop(node, topic)
        loop = SubscriptionLoop(node, msg_type, topic, copy.copy(QUERY_QOS),
                                taken.on_messages, taken.on_error, **options)
        made[-1] = (loop, node, pub_node)
        publisher = pub_node.create_publisher(msg_type, topic, copy.copy(QUERY_QOS))
        wait_matched(publisher, subscriptions)
        return loop, publisher, node

    yield subscribe
    for loop, node, pub_node in made:
        if loop is not None:
            loop.stop()
        node.destroy_node()
        pub_node.destroy_node()


def strings(n: int, prefix: str = "m") -> list:
    from std_msgs.msg import String

    return [String(data=f"{prefix}{k}") for k in range(n)]


def test_every_message_arrives_once_in_order_in_lists_of_at_most_max_take(subscribed):
    from std_msgs.msg import String

    taken = Taken(hold_first=True)
    _, publisher, _ = subscribed(String, taken, max_take=MAX_TAKE, name="loop_thread")
    sent = strings(BURST)
    for msg in sent:
        publisher.publish(msg)  # the first call holds the loop: the rest pile up
    taken.release.set()
    got = taken.wait_for_count(BURST)
    assert [m.data for m in got] == [m.data for m in sent]
    sizes = [len(call) for call in taken.calls]
    assert max(sizes) <= MAX_TAKE
    assert any(size > 1 for size in sizes), sizes
    assert set(taken.threads) == {"loop_thread"} and not taken.errors


def test_raw_hands_over_the_serialized_messages(subscribed):
    from geometry_msgs.msg import Point, Vector3
    from grasp_fc_msgs.msg import Contact, ContactArray
    from rclpy.serialization import deserialize_message

    taken = Taken()
    _, publisher, _ = subscribed(ContactArray, taken, raw=True)
    sent = [ContactArray(client_id=7, id=k, contacts=[
        Contact(position=Point(x=0.1 * k, y=-1.0 * j, z=2.5),
                normal=Vector3(x=0.0, y=1.0, z=float(j)),
                friction_coefficient=0.5 + 0.01 * k, torsional_friction=0.001 * j)
        for j in range(k % 5)]) for k in range(40)]
    for msg in sent:
        publisher.publish(msg)
    got = taken.wait_for_count(len(sent))
    assert all(isinstance(item, bytes) for item in got)
    assert [deserialize_message(item, ContactArray) for item in got] == sent


def test_an_executor_spinning_the_node_does_not_take_the_loops_messages(subscribed):
    """The loop's subscription is never offered to an executor spinning its node, even
    while it holds messages; another subscription of that node is (the executor runs)."""
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    from grasp_fc_ros.interface.names import QUERY_QOS

    class Watching(SingleThreadedExecutor):
        """Records every entity whose callback the executor is about to run."""

        def __init__(self):
            super().__init__()
            self.offered = []

        def wait_for_ready_callbacks(self, *args, **kwargs):
            handler, entity, node = super().wait_for_ready_callbacks(*args, **kwargs)
            self.offered.append(entity)
            return handler, entity, node

    n = 200
    taken = Taken(hold_first=True)
    executor_got = []
    all_there = threading.Event()

    def on_control(msg):
        executor_got.append(msg.data)
        if len(executor_got) == n:
            all_there.set()

    def control_subscription(node, topic):
        node.create_subscription(String, topic, on_control, QUERY_QOS)

    loop, publisher, node = subscribed(String, taken, subscriptions=2, name="loop_thread",
                                       before_loop=control_subscription)
    executor = Watching()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        sent = strings(n)
        for msg in sent:
            publisher.publish(msg)
        # The loop holds its first call (with its other messages still in the
        # subscription) until the executor has run the control callback for all of them.
        assert all_there.wait(TAKE_TIMEOUT_S), (
            f"executor ran {len(executor_got)} of {n}; on_messages ran in {taken.threads}")
        taken.release.set()
        got = taken.wait_for_count(n)
    finally:
        taken.release.set()
        executor.shutdown()
        spinner.join(timeout=5.0)
    assert [m.data for m in got] == [m.data for m in sent]
    assert executor_got == [m.data for m in sent]
    assert all(isinstance(call, list) for call in taken.calls)
    assert set(taken.threads) == {"loop_thread"}
    assert loop.subscription not in executor.offered
    assert not spinner.is_alive()


def test_an_error_in_on_messages_is_reported_and_the_loop_goes_on(subscribed):
    from std_msgs.msg import String

    refused = RuntimeError("first call refused")
    taken = Taken(raise_first=refused)
    loop, publisher, _ = subscribed(String, taken)
    publisher.publish(String(data="first"))
    taken.wait_for(lambda: taken.errors, "on_error")
    later = strings(5, prefix="later")
    for msg in later:
        publisher.publish(msg)
    got = taken.wait_for_count(1 + len(later))
    assert [m.data for m in got] == ["first"] + [m.data for m in later]
    assert len(taken.errors) == 1 and taken.errors[0] is refused
    assert loop.running


def test_stop_ends_the_loop_and_a_second_stop_does_nothing(subscribed):
    from std_msgs.msg import String

    taken = Taken()
    loop, publisher, _ = subscribed(String, taken)
    publisher.publish(String(data="before"))
    assert [m.data for m in taken.wait_for_count(1)] == ["before"]
    assert loop.running
    loop.stop()  # joins the thread, woken at once (else within a wait, WAIT_NS)
    assert not loop.running
    loop.stop()  # does nothing: its guard condition is gone, its thread joined
    assert not loop.running
    publisher.publish(String(data="after"))
    threading.Event().wait(0.3)
    assert [m.data for m in taken.flat()] == ["before"]


def test_gil_free_hands_over_the_bytes_rclpy_would(subscribed):
    """gil_free takes through rcl_take.take_serialized: the same bytes as rclpy's take,
    in order, a message of MBs (fragmented by DDS) included."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    taken = Taken()
    _, publisher, _ = subscribed(String, taken, raw=True, gil_free=True, name="gil_free")
    sent = [*strings(40), String(data="x" * 3_000_000), *strings(3, prefix="after")]
    for msg in sent:
        publisher.publish(msg)
    got = taken.wait_for_count(len(sent))
    assert all(type(item) is bytes for item in got)
    assert got == [serialize_message(msg) for msg in sent]
    assert set(taken.threads) == {"gil_free"} and not taken.errors


def test_gil_free_needs_raw(subscribed):
    from std_msgs.msg import String

    with pytest.raises(ValueError, match="gil_free takes serialized messages: it needs raw"):
        subscribed(String, Taken(), gil_free=True)


def test_take_serialized_is_none_without_a_message_then_takes_each_once(subscribed):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    from grasp_fc_ros.interface.rcl_take import take_serialized

    # Its own subscription on the loop's node, which no loop or executor takes from.
    taken = Taken()
    subscriptions = []

    def second_subscription(node, topic):
        subscriptions.append(node.create_subscription(String, topic, lambda _: None, 10,
                                                      raw=True))

    _, publisher, _ = subscribed(String, taken, subscriptions=2,
                                 before_loop=second_subscription)
    [subscription] = subscriptions
    with subscription.handle:
        assert take_serialized(subscription.handle) is None
    sent = strings(3)
    for msg in sent:
        publisher.publish(msg)
    taken.wait_for_count(len(sent))  # delivered to the loop: to the other one too, soon
    got: list = []
    deadline = time.monotonic() + TAKE_TIMEOUT_S
    while len(got) < len(sent) and time.monotonic() < deadline:
        with subscription.handle:
            item = take_serialized(subscription.handle)
        if item is None:
            time.sleep(0.01)
        else:
            got.append(item)
    assert got == [serialize_message(msg) for msg in sent]
    with subscription.handle:
        assert take_serialized(subscription.handle) is None
