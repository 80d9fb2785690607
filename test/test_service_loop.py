"""ServiceLoop: services served from a wait set, without an executor (tiny services)."""

from __future__ import annotations

import threading

import pytest

SERVE_TIMEOUT_S = 20.0


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
