"""The node's RViz markers (publish_markers) and its QoS overrides, through real DDS.

Each test runs a ForceClosureNode of its own in a namespace of its own (no worker
processes), a raw-protocol client and a subscriber on the node's ``markers`` topic.
The marker queue itself (bounds, dropping, DELETEALL order) is tested without DDS, on a
MarkerPublisher with a recording publisher.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
from std_srvs.srv import Empty
from visualization_msgs.msg import Marker, MarkerArray

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.engine.child_process import FramingError
from grasp_fc_ros.interface.conversions import grasp_to_contact_array, grasps_to_batch_msg
from grasp_fc_ros.interface.names import QUERY_QOS, VERDICT_QOS
from grasp_fc_ros.markers import publisher as marker_publisher_module
from grasp_fc_ros.markers.build import (
    CONTACTS_ID,
    FORCE_ARROW_ID,
    STATUS_COLORS,
    TEXT_ID,
    delete_all_markers,
    marker_namespace,
)
from grasp_fc_ros.markers.publisher import (
    MARKER_QOS,
    MARKER_QUEUE_LENGTH,
    MarkerPayload,
    MarkerProcess,
    MarkerPublisher,
    MarkerSettings,
    draw,
    sample_indices,
)
from grasp_fc_ros.objects import make_object, sample_grasps
from ros_fixtures import REPLY_TIMEOUT_S

pytestmark = pytest.mark.timeout(120)

# Time to make sure that nothing (more) arrives on the markers topic.
QUIET_S = 1.0
# Four fingers on a sphere of radius 3 cm: force closure at mu 0.5; the same fingers on
# the upper cap: rejected (by the filter, at four contacts).
AROUND = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float) * 0.03
CAP = np.array([[0.6, 0, 0.8], [-0.6, 0, 0.8], [0, 0.6, 0.8], [0, -0.6, 0.8]]) * 0.03


class MarkerListener:
    """Collects the MarkerArrays of one node's ``markers`` topic."""

    def __init__(self, client, publishing: bool = True):
        self._lock = threading.Condition()
        self.arrays: list[MarkerArray] = []
        self._sub = client.node.create_subscription(MarkerArray, "markers", self._on_markers,
                                                    MARKER_QOS)
        self._clear = client.node.create_client(Empty, "clear_markers")
        if publishing:
            self.wait_matched()

    def wait_matched(self):
        """Wait for the marker process's publisher (MARKER_QOS is transient local, so
        what it sent before it matched this subscription arrives too)."""
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while self._sub.get_publisher_count() == 0:
            assert time.monotonic() < deadline, "markers publisher not matched"
            time.sleep(0.05)
        time.sleep(0.5)  # matching is not symmetric in time: let the publisher match too

    def _on_markers(self, msg):
        with self._lock:
            self.arrays.append(msg)
            self._lock.notify_all()

    def wait_for(self, count: int, timeout=REPLY_TIMEOUT_S) -> list[MarkerArray]:
        with self._lock:
            ok = self._lock.wait_for(lambda: len(self.arrays) >= count, timeout)
            arrays = list(self.arrays)
        assert ok, f"received {len(arrays)} of {count} marker arrays"
        return arrays

    def quiet(self) -> list[MarkerArray]:
        """Every array received once nothing arrived for QUIET_S."""
        time.sleep(QUIET_S)
        with self._lock:
            return list(self.arrays)

    def clear_markers(self):
        assert self._clear.wait_for_service(timeout_sec=REPLY_TIMEOUT_S)
        done = threading.Event()
        self._clear.call_async(Empty.Request()).add_done_callback(lambda _: done.set())
        assert done.wait(REPLY_TIMEOUT_S), "clear_markers did not answer"


def by_namespace(array: MarkerArray) -> dict[str, dict[int, Marker]]:
    out: dict[str, dict[int, Marker]] = {}
    for marker in array.markers:
        out.setdefault(marker.ns, {})[marker.id] = marker
    return out


def rgba(marker: Marker) -> tuple[float, ...]:
    return tuple(round(v, 5) for v in (marker.color.r, marker.color.g, marker.color.b,
                                       marker.color.a))


def expected_rgba(status: Status) -> tuple[float, ...]:
    return tuple(round(v, 5) for v in STATUS_COLORS[status])


def query(grasp_id: int, positions, frame_id: str):
    msg = grasp_to_contact_array(grasp_id, positions, -positions)
    msg.header.frame_id = frame_id
    msg.header.stamp.sec = 1234
    return msg


@pytest.fixture
def marker_node(own_node):
    """make(namespace, **parameters) -> (node, client, listener)."""
    def make(namespace, **parameters):
        node, _, client = own_node(namespace, workers=0, **parameters)
        return node, client, MarkerListener(client, parameters.get("publish_markers", False))
    return make


def test_single_queries_get_markers_in_their_frame_coloured_by_verdict(marker_node):
    _, client, listener = marker_node("/markers_single", publish_markers=True,
                                      marker_lifetime=2.5)
    client.contacts_pub.publish(query(11, AROUND, "object"))
    client.contacts_pub.publish(query(12, CAP, "palm"))
    verdicts = {v.id: v for v in client.wait_for("verdicts", 2)}
    assert verdicts[11].status == Status.FORCE_CLOSURE
    assert verdicts[12].status == Status.FILTERED_OUT
    arrays = listener.wait_for(2)
    assert len(arrays) == 2  # one MarkerArray per query
    drawn = {}
    for array in arrays:
        (ns, markers), = by_namespace(array).items()
        drawn[ns] = markers
    assert set(drawn) == {marker_namespace(11), marker_namespace(12)}
    for grasp_id, frame in ((11, "object"), (12, "palm")):
        markers = drawn[marker_namespace(grasp_id)]
        status = Status(verdicts[grasp_id].status)
        assert {m.header.frame_id for m in markers.values()} == {frame}
        assert {m.header.stamp.sec for m in markers.values()} == {1234}
        assert {(m.lifetime.sec, m.lifetime.nanosec) for m in markers.values()} == {
            (2, 500_000_000)}
        assert rgba(markers[CONTACTS_ID]) == expected_rgba(status)
        assert len(markers[CONTACTS_ID].points) == 4
        assert f"grasp {grasp_id}" in markers[TEXT_ID].text
    # The rejected grasp's separating wrench is drawn, computed on the marker thread.
    assert FORCE_ARROW_ID in drawn[marker_namespace(12)]
    assert FORCE_ARROW_ID not in drawn[marker_namespace(11)]


def test_service_request_gets_markers(marker_node):
    _, client, listener = marker_node("/markers_service", publish_markers=True)
    verdicts = client.call([query(21, AROUND, "hand"), query(22, CAP, "hand")])
    assert [v.status for v in verdicts] == [Status.FORCE_CLOSURE, Status.FILTERED_OUT]
    array, = listener.wait_for(1)
    drawn = by_namespace(array)
    assert set(drawn) == {marker_namespace(21), marker_namespace(22)}
    assert {m.header.frame_id for m in array.markers} == {"hand"}
    assert rgba(drawn[marker_namespace(21)][CONTACTS_ID]) == expected_rgba(
        Status.FORCE_CLOSURE)
    assert rgba(drawn[marker_namespace(22)][CONTACTS_ID]) == expected_rgba(
        Status.FILTERED_OUT)
    assert listener.quiet() == [array]


def test_a_batch_gets_markers_for_at_most_its_sample(marker_node):
    _, client, listener = marker_node("/markers_batch", publish_markers=True,
                                      marker_batch_sample=3)
    positions, normals = sample_grasps(make_object("box"), 40, 4, np.random.default_rng(5))
    msg = grasps_to_batch_msg(np.arange(40) + 500, positions, normals)
    msg.header.frame_id = "box"
    reply = client.request_batch(msg)
    listener.wait_for(1)  # the marker process may lag under load: wait for the first,
    arrays = listener.quiet()  # then make sure no second one follows
    assert len(arrays) == 1
    drawn = by_namespace(arrays[0])
    expected_ids = 500 + sample_indices(40, 3)
    assert set(drawn) == {marker_namespace(i) for i in expected_ids.tolist()}
    assert {m.header.frame_id for m in arrays[0].markers} == {"box"}
    for i in expected_ids.tolist():
        assert rgba(drawn[marker_namespace(i)][CONTACTS_ID]) == expected_rgba(
            Status(reply.status[i - 500]))


def test_markers_use_the_node_default_friction_for_contacts_without_one(marker_node):
    # The cones' half-angle is atan(mu) of the node's friction_coefficient.
    _, client, listener = marker_node("/markers_mu", publish_markers=True,
                                      friction_coefficient=0.25)
    client.contacts_pub.publish(query(31, AROUND, "object"))
    array, = listener.wait_for(1)
    cones = by_namespace(array)[marker_namespace(31)][1]
    apex = AROUND[0]
    rim = np.array([[p.x, p.y, p.z] for p in cones.points[1:3]])
    axis = AROUND[0] / np.linalg.norm(AROUND[0])  # -normal: away from the object
    cosines = (rim - apex) @ axis / np.linalg.norm(rim - apex, axis=1)
    np.testing.assert_allclose(np.arccos(cosines), np.arctan(0.25), atol=1e-9)


def test_off_means_no_marker_traffic_and_on_at_run_time_starts_it(marker_node):
    node, client, listener = marker_node("/markers_off")
    assert node.get_parameter("publish_markers").value is False
    client.contacts_pub.publish(query(41, AROUND, "object"))
    client.call([query(42, CAP, "object")])
    positions, normals = sample_grasps(make_object("box"), 5, 4, np.random.default_rng(6))
    client.request_batch(grasps_to_batch_msg(np.arange(5), positions, normals))
    client.wait_for("verdicts", 1)
    assert listener.quiet() == []
    assert node.markers.counts() == {"markers_published": 0, "markers_dropped": 0}
    from rclpy.parameter import Parameter
    assert listener._sub.get_publisher_count() == 0  # no marker process while off
    assert node.set_parameters([Parameter("publish_markers", value=True)])[0].successful
    listener.wait_matched()
    client.contacts_pub.publish(query(43, AROUND, "object"))
    array, = listener.wait_for(1)
    assert set(by_namespace(array)) == {marker_namespace(43)}


def test_a_failing_offer_costs_no_verdict(marker_node, monkeypatch):
    node, client, listener = marker_node("/markers_fail", publish_markers=True)

    def broken(*args):
        raise RuntimeError("marker queue broken")

    monkeypatch.setattr(node.markers.publisher, "offer_singles", broken)
    monkeypatch.setattr(node.markers.publisher, "offer_serialized_singles", broken)
    client.contacts_pub.publish(query(71, AROUND, "object"))
    verdict, = client.wait_for("verdicts", 1)
    assert verdict.id == 71 and verdict.status == Status.FORCE_CLOSURE
    values = client.diagnostics_after(time.time(), node_name="/markers_fail/force_closure")
    assert values["callback_errors"] == "1" and values["answered"] == "1"
    assert listener.quiet() == []


def test_clear_markers_publishes_a_delete_all(marker_node):
    node, client, listener = marker_node("/markers_clear", publish_markers=True)
    client.contacts_pub.publish(query(51, AROUND, "object"))
    listener.wait_for(1)
    listener.clear_markers()
    arrays = listener.wait_for(2)
    assert [m.action for m in arrays[1].markers] == [Marker.DELETEALL]


def test_marker_counts_are_in_the_diagnostics(marker_node):
    node, client, listener = marker_node("/markers_diag", publish_markers=True)
    client.contacts_pub.publish(query(61, AROUND, "object"))
    listener.wait_for(1)
    values = client.diagnostics_after(time.time(), node_name="/markers_diag/force_closure")
    assert values["markers_published"] == "1"
    assert values["markers_dropped"] == "0"


@pytest.mark.parametrize("name, value, match", [
    ("marker_lifetime", -1.0, "marker_lifetime"),
    ("marker_lifetime", float("nan"), "marker_lifetime"),
    ("marker_batch_sample", 1001, "marker_batch_sample"),
])
def test_bad_marker_parameters_are_refused(marker_node, name, value, match):
    from rclpy.parameter import Parameter
    node, _, _ = marker_node("/markers_params")
    result = node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert node.get_parameter(name).value != value


# --- QoS overrides ---------------------------------------------------------------------


def test_qos_overrides_take_effect(own_node):
    from rclpy.qos import HistoryPolicy, ReliabilityPolicy
    ns = "/qos_test"
    node, _, _ = own_node(ns, workers=0, **{
        f"qos_overrides.{ns}/contacts.subscription.history": "keep_last",
        f"qos_overrides.{ns}/contacts.subscription.depth": 7,
        f"qos_overrides.{ns}/contacts_batch.subscription.history": "keep_last",
        f"qos_overrides.{ns}/contacts_batch.subscription.depth": 3,
        f"qos_overrides.{ns}/verdicts.publisher.depth": 50,
    })
    subs = {s.topic_name: s.qos_profile
            for s in (*node.subscriptions, *node.batch_participant.node.subscriptions)}
    pubs = {p.topic_name: p.qos_profile for p in node.publishers}
    assert subs[f"{ns}/contacts"].history == HistoryPolicy.KEEP_LAST
    assert subs[f"{ns}/contacts"].depth == 7
    # Declared on the node, applied on the helper node of the batch topic's participant.
    assert subs[f"{ns}/contacts_batch"].history == HistoryPolicy.KEEP_LAST
    assert subs[f"{ns}/contacts_batch"].depth == 3
    assert node.get_parameter(f"qos_overrides.{ns}/contacts_batch.subscription.depth").value == 3
    assert pubs[f"{ns}/verdicts"].depth == 50
    assert pubs[f"{ns}/verdicts"].reliability == ReliabilityPolicy.RELIABLE  # not overridden
    assert pubs[f"{ns}/verdicts_batch"].depth == 10_000  # the default VERDICT_QOS
    # The module's profiles, which clients use too, stay as they were.
    assert (QUERY_QOS.history, QUERY_QOS.depth) == (HistoryPolicy.KEEP_ALL, 1)
    assert VERDICT_QOS.depth == 10_000 and MARKER_QOS.reliability == ReliabilityPolicy.RELIABLE


def test_qos_overrides_from_a_params_file_as_documented(tmp_path):
    """The nested YAML of docs/params.md, read by rclpy in a context of its own."""
    import rclpy
    from rclpy.qos import HistoryPolicy

    from grasp_fc_ros.node import ForceClosureNode

    params = tmp_path / "qos.yaml"
    params.write_text(
        "/qos_file/force_closure:\n  ros__parameters:\n    workers: 0\n"
        "    qos_overrides:\n      /qos_file/contacts:\n        subscription:\n"
        "          history: keep_last\n          depth: 100\n"
        "      /qos_file/verdicts:\n        publisher:\n          depth: 1000\n")
    context = rclpy.Context()
    rclpy.init(args=["test", "--ros-args", "--params-file", str(params)], context=context)
    try:
        node = ForceClosureNode(namespace="/qos_file", context=context)
        try:
            subs = {s.topic_name: s.qos_profile for s in (
                *node.subscriptions, *node.batch_participant.node.subscriptions)}
            pubs = {p.topic_name: p.qos_profile for p in node.publishers}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert (subs["/qos_file/contacts"].history, subs["/qos_file/contacts"].depth) == (
        HistoryPolicy.KEEP_LAST, 100)
    assert subs["/qos_file/contacts_batch"].history == HistoryPolicy.KEEP_ALL
    assert pubs["/qos_file/verdicts"].depth == 1000


def test_qos_overrides_are_not_reported_as_unknown_parameters(own_node, capfd):
    own_node("/qos_warn", workers=0,
             **{"qos_overrides./qos_warn/contacts.subscription.depth": 5,
                "frction_coefficient": 0.3})
    err = capfd.readouterr().err
    assert "frction_coefficient" in err
    assert "qos_overrides" not in err


# --- the marker queue, without DDS -------------------------------------------------


class RecordingSink:
    """Draws in this process (as the marker process would) and records the arrays."""

    def __init__(self):
        self.published: list[MarkerArray] = []
        self.event = threading.Event()

    def start(self):
        pass

    def wait_ready(self, timeout_s):
        return True

    def draw(self, payload):
        markers = draw(payload)
        self.published.append(markers)
        self.event.set()
        return len(payload)

    def clear(self):
        self.published.append(delete_all_markers())
        self.event.set()

    def close(self):
        pass


def test_sample_indices_are_bounded_spread_and_unique():
    assert sample_indices(3, 10).tolist() == [0, 1, 2]
    assert sample_indices(100, 0).tolist() == []
    for n, k in ((10, 3), (1000, 7), (11, 10), (5, 1)):
        got = sample_indices(n, k)
        assert len(got) == k == len(set(got.tolist()))
        assert got[0] == 0 and (k == 1 or got[-1] == n - 1)
        assert (np.diff(got) > 0).all()


def test_queue_drops_the_oldest_marker_work_when_full_and_keeps_a_clear(monkeypatch):
    started, release = threading.Event(), threading.Event()
    publisher = RecordingSink()
    real_draw = publisher.draw

    def blocked_draw(payload):
        started.set()
        release.wait(REPLY_TIMEOUT_S)
        return real_draw(payload)

    publisher.draw = blocked_draw
    errors = []
    markers = MarkerPublisher(publisher, lambda what, exc: errors.append(exc))
    settings = MarkerSettings(enabled=True)
    result = check_force_closure(AROUND, -AROUND, 0.5)

    class Reply:
        status = int(result.status)
        margin = float(result.margin)

    try:
        markers.offer_singles([query(0, AROUND, "f")], [Reply()], settings, 0.5)
        assert started.wait(REPLY_TIMEOUT_S)  # job 0 is being drawn, the queue is empty
        markers.clear()  # a DELETEALL waits first in the queue
        extra = 5
        for i in range(1, MARKER_QUEUE_LENGTH + extra):
            markers.offer_singles([query(i, AROUND, "f")], [Reply()], settings, 0.5)
        # The queue holds the DELETEALL and the newest jobs; the oldest were dropped.
        assert markers.counts()["markers_dropped"] == extra
        release.set()
        deadline = time.monotonic() + REPLY_TIMEOUT_S
        while markers.counts()["markers_published"] < MARKER_QUEUE_LENGTH:
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        release.set()
        markers.close()
    assert not errors
    kinds = [a.markers[0].action == Marker.DELETEALL for a in publisher.published]
    assert kinds == [False, True] + [False] * (MARKER_QUEUE_LENGTH - 1)
    namespaces = [a.markers[0].ns for a in publisher.published[2:]]
    assert namespaces == [marker_namespace(i) for i in range(
        1 + extra, MARKER_QUEUE_LENGTH + extra)]


def test_marker_failures_are_reported_not_raised(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("no markers today")

    monkeypatch.setattr(marker_publisher_module, "grasp_markers", broken)
    publisher = RecordingSink()
    errors = threading.Event()
    markers = MarkerPublisher(publisher, lambda what, exc: errors.set())

    class Reply:
        status, margin = int(Status.FORCE_CLOSURE), 0.1

    try:
        markers.offer_singles([query(0, AROUND, "f")], [Reply()], MarkerSettings(True), 0.5)
        assert errors.wait(REPLY_TIMEOUT_S)
        markers.clear()  # the thread lives on
        assert publisher.event.wait(REPLY_TIMEOUT_S)
    finally:
        markers.close()
    assert [m.action for m in publisher.published[0].markers] == [Marker.DELETEALL]


def test_the_marker_process_starts_with_publish_markers_and_ends_with_the_node(ros):
    from rclpy.parameter import Parameter

    from grasp_fc_ros.node import ForceClosureNode

    node = ForceClosureNode(namespace="/markers_process", parameter_overrides=[
        Parameter("workers", value=0), Parameter("publish_markers", value=True)])
    try:
        process = node.markers.publisher.sink.process
        assert process is not None and process.poll() is None
        # Once it has answered (it is up), it ends cleanly when its stdin closes; one
        # still starting would be killed after PROCESS_EXIT_TIMEOUT_S.
        node.markers.publisher.sink.clear()
    finally:
        node.destroy_node()
    assert process.wait(timeout=REPLY_TIMEOUT_S) == 0


def test_a_marker_process_that_dies_or_breaks_its_channel_is_replaced(ros, monkeypatch):
    """A marker process that died while idle is replaced before the next payload; one
    whose channel breaks during an exchange fails that exchange with the reason and is
    replaced at once, and the next payload is drawn."""
    payload = MarkerPayload(
        frame_id="f", stamp=(0, 0), ids=np.array([5], np.uint64), counts=np.array([4]),
        positions=AROUND, normals=-AROUND, mu=np.full(4, 0.5),
        status=np.array([Status.FORCE_CLOSURE], np.uint8), margin=np.array([0.1]),
        lifetime_s=1.0)
    sink = MarkerProcess("/markers_replaced", "force_closure_markers")
    try:
        assert sink.draw(payload) == 1
        first = sink.process
        assert first is not None
        os.kill(first.pid, signal.SIGKILL)
        first.wait()
        assert sink.draw(payload) == 1
        second = sink.process
        assert second is not None and second.pid != first.pid
        read = marker_publisher_module.read_message

        def broken_once(stream):
            monkeypatch.setattr(marker_publisher_module, "read_message", read)
            read(stream)
            raise FramingError("no message header where one should start: b'[XMLPARSER'")

        monkeypatch.setattr(marker_publisher_module, "read_message", broken_once)
        with pytest.raises(RuntimeError, match=f"marker process {second.pid} failed "
                                               r"\(FramingError.*XMLPARSER.*started another"):
            sink.draw(payload)
        assert second.poll() is not None  # killed and reaped
        assert sink.process is not None and sink.process.pid != second.pid
        assert sink.draw(payload) == 1
    finally:
        sink.close()
