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

    from ros_fixtures import SpinThread
    from rclpy.node import Node
    from std_srvs.srv import SetBool

    from grasp_fc_ros.service_loop import ServiceLoop

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

    from grasp_fc_ros.service_loop import ServiceCaller

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

    from grasp_fc_ros.service_loop import ServiceCaller

    node = Node("lonely_caller", start_parameter_services=False)
    try:
        caller = ServiceCaller(node.create_client(SetBool, "/nobody_serves_this"))
        started = time.monotonic()
        with pytest.raises(TimeoutError):
            caller.call(SetBool.Request(data=True), SHORT_TIMEOUT_S)
        assert time.monotonic() - started >= SHORT_TIMEOUT_S
    finally:
        node.destroy_node()
