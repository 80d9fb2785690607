"""grasp_fc_ros.client: talk to a running ``force_closure`` node from Python.

>>> import rclpy
>>> from grasp_fc_ros.client import GraspClient
>>> rclpy.init()
>>> with GraspClient() as client:                      # node "force_closure"
...     client.wait_for_node(timeout=10.0)
...     verdicts = client.check_batch(positions, normals)   # (N, n, 3) arrays
...     future = client.submit(positions[0], normals[0])  # one query, a Future
...     print(verdicts.status, future.result(timeout=5.0).status)

The client uses the QoS the node documents (:data:`grasp_fc_ros.interface.names.QUERY_QOS`:
reliable, KEEP_ALL), keeps at most ``max_in_flight`` single queries unanswered (more
:meth:`submit` calls wait), keeps only verdicts carrying its own random ``client_id``,
and publishes again every unanswered query when a node (re)appears on the query topics,
e.g. after the node was killed and restarted. A verdict answering an id twice (the old
and the new node both answered) resolves its future once. :meth:`GraspClient.label_grasps`
sends a long job to the node's ``label_grasps`` action, with a progress bar and Ctrl-C
cancelling it.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

import numpy as np
from action_msgs.msg import GoalStatus
from diagnostic_msgs.msg import DiagnosticArray
from grasp_fc_msgs.action import LabelGrasps
from grasp_fc_msgs.msg import (
    ContactArray,
    ContactArrayBatch,
    ForceClosureVerdict,
    ForceClosureVerdictArray,
)
from grasp_fc_msgs.srv import CheckForceClosure, ComputeContactForces
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future as RclpyFuture
from tqdm import tqdm
from rclpy.serialization import deserialize_message

from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import (
    grasp_to_contact_array,
    grasps_to_batch_msg,
    verdict_array_to_numpy,
    verdict_msgs_to_numpy,
)
from grasp_fc_ros.engine.contact_forces import ContactForces
from grasp_fc_ros.engine.packed import Verdicts
from grasp_fc_ros.interface.names import NODE_NAME, QUERY_QOS
from grasp_fc_ros.interface.wait_sets import ServiceCaller, SubscriptionLoop

# Single queries unanswered at most (more submit() calls wait): well inside what the
# node's KEEP_ALL reader takes without pushing back for long.
DEFAULT_IN_FLIGHT = 2_000
DEFAULT_TIMEOUT_S = 60.0
# How often the client looks for a (re)started node on the query topics (s).
WATCH_PERIOD_S = 0.25
# Grace period after matching: DDS matches the two directions at different moments.
MATCH_GRACE_S = 0.3
# How often label_grasps redraws its progress bar and looks at its deadline (s).
PROGRESS_POLL_S = 0.1
# How long label_grasps waits for the decided prefix after it cancelled its goal (s):
# the node ends a canceled goal within ~0.1 s.
CANCEL_WAIT_S = 10.0
# Verdicts taken per wake-up of the verdicts loop at most (one wake-up costs about as
# much as a verdict).
MAX_TAKE = 2_000


class GraspClient:
    """A client of one ``force_closure`` node: batches, single queries, the service.

    Parameters
    ----------
    node_name : str
        The node to talk to: ``force_closure``, or with its namespace
        (``/robot/force_closure``); the topics are looked up next to it.
    max_in_flight : int
        Largest number of single queries sent but not answered.
    name : str, optional
        Name of the client's own ROS node (default: a unique one).

    Requires ``rclpy.init()``; the client spins its own node on a thread of its own
    (service calls wait for their responses in the calling thread).
    """

    def __init__(self, node_name: str = NODE_NAME, max_in_flight: int = DEFAULT_IN_FLIGHT,
                 name: str | None = None):
        namespace, _, base = node_name.rpartition("/")
        prefix = ("/" + namespace.strip("/")).rstrip("/")
        self.client_id = secrets.randbits(63) | 1  # never 0 ("no client id")
        self.node = Node(name or f"grasp_fc_client_{self.client_id:x}")
        self._cond = threading.Condition()
        self._singles: dict[int, tuple[ContactArray, Future]] = {}
        self._batches: dict[int, tuple[ContactArrayBatch, Future]] = {}
        self._next_request = 1
        self._max_in_flight = max_in_flight
        self.resubmitted = 0
        self.diagnostics: dict[str, str] = {}
        self._contacts_pub = self.node.create_publisher(ContactArray, f"{prefix}/contacts",
                                                        QUERY_QOS)
        self._batch_pub = self.node.create_publisher(ContactArrayBatch,
                                                     f"{prefix}/contacts_batch", QUERY_QOS)
        # Queries go out and verdicts come in serialized (grasp_fc_ros.interface.wire), unless this
        # rmw's layout is not the one wire writes: ~20 Python objects less per query.
        self._raw = wire.layout_matches()
        # Single verdicts come in many at a time: taken by a loop of their own, every
        # verdict the subscription holds at each wake-up (see SubscriptionLoop).
        self._verdict_loop = SubscriptionLoop(
            self.node, ForceClosureVerdict, f"{prefix}/verdicts", QUERY_QOS,
            self._on_raw_verdicts if self._raw else self._on_verdicts, self._on_loop_error,
            raw=self._raw, max_take=MAX_TAKE, name="grasp_client_verdicts")
        self.node.create_subscription(ForceClosureVerdictArray, f"{prefix}/verdicts_batch",
                                      self._on_raw_batch if self._raw else self._on_batch,
                                      QUERY_QOS, raw=self._raw)
        self._diag_name = f"{prefix}/{base}:"  # the node's diagnostics status name starts so
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        # The services on a small node of their own that no executor spins: each call
        # waits for its response in the caller's thread (ServiceCaller). An executor
        # thread that also waits on the topics, the timer and the action took ~0.5 ms
        # longer per call (measured).
        self._service_node = Node(f"{self.node.get_name()}_service",
                                  start_parameter_services=False)
        self._service = self._service_node.create_client(CheckForceClosure,
                                                         f"{prefix}/check_force_closure")
        self._forces_service = self._service_node.create_client(
            ComputeContactForces, f"{prefix}/compute_contact_forces")
        self._service_caller = ServiceCaller(self._service)
        self._forces_caller = ServiceCaller(self._forces_service)
        self._label_action = ActionClient(self.node, LabelGrasps, f"{prefix}/label_grasps")
        # GoalStatus code of the last label_grasps goal (STATUS_UNKNOWN before any).
        self.last_goal_status = GoalStatus.STATUS_UNKNOWN
        self._matched = 0
        self._closed = False
        self.node.create_timer(WATCH_PERIOD_S, self._watch_node)
        self._executor = SingleThreadedExecutor(context=self.node.context)
        self._executor.add_node(self.node)
        self._spinner = threading.Thread(target=self._spin, daemon=True, name="grasp_client")
        self._spinner.start()

    # --- connection -------------------------------------------------------------------

    def wait_for_node(self, timeout: float = DEFAULT_TIMEOUT_S) -> bool:
        """Wait until the node's service and both directions of its topics are matched."""
        deadline = time.monotonic() + timeout
        if not self._service.wait_for_service(timeout_sec=timeout):
            return False
        while time.monotonic() < deadline:
            if (self._contacts_pub.get_subscription_count()
                    and self._batch_pub.get_subscription_count()
                    and self.node.count_publishers(self._verdict_topic("verdicts"))
                    and self.node.count_publishers(self._verdict_topic("verdicts_batch"))):
                time.sleep(MATCH_GRACE_S)
                return True
            time.sleep(0.02)
        return False

    def _verdict_topic(self, name: str) -> str:
        return self._contacts_pub.topic_name.rsplit("/", 1)[0] + "/" + name

    def _watch_node(self):
        """Publish unanswered queries again when a node newly subscribes to them.

        A restarted node has not seen what was sent to its predecessor; a duplicate
        answer (both saw it) is ignored by id.
        """
        matched = self._contacts_pub.get_subscription_count()
        grew, self._matched = matched > self._matched, matched
        if not grew:
            return
        with self._cond:
            singles = [msg for msg, _ in self._singles.values()]
            batches = [msg for msg, _ in self._batches.values()]
        if singles or batches:
            time.sleep(MATCH_GRACE_S)
        for msg in singles:
            self._contacts_pub.publish(msg)
        for msg in batches:
            self._batch_pub.publish(msg)
        with self._cond:
            self.resubmitted += len(singles) + sum(len(m.ids) for m in batches)

    # --- single queries -----------------------------------------------------------------

    def submit(self, positions, normals, mu=0.0, query_id: int | None = None,
               frame_id: str = "", timeout: float = DEFAULT_TIMEOUT_S) -> Future:
        """Send one grasp on ``contacts``; return a Future of its ForceClosureVerdict.

        Parameters
        ----------
        positions, normals : (n, 3) float
            Contact positions (m) and inward normals.
        mu : scalar or (n,) float
            Friction per contact; a finite value <= 0 means the node's default.
        query_id : int, optional
            Default: a number counting up from 1 in this client.
        frame_id : str
            Frame of the contacts; the verdict's header carries it back.
        timeout : float
            How long to wait for room when ``max_in_flight`` queries are unanswered.

        Raises
        ------
        TimeoutError
            If no room was made within ``timeout``.
        ValueError
            If ``query_id`` is already in flight.
        """
        with self._cond:
            if query_id is None:
                query_id, self._next_request = self._next_request, self._next_request + 1
            if query_id in self._singles:
                raise ValueError(f"query id {query_id} is already in flight")
            if not self._cond.wait_for(lambda: len(self._singles) < self._max_in_flight,
                                       timeout):
                raise TimeoutError(f"{len(self._singles)} queries unanswered for {timeout} s")
            msg = self._single_query(query_id, positions, normals, mu, frame_id)
            future: Future = Future()
            self._singles[query_id] = (msg, future)
        self._contacts_pub.publish(msg)
        return future

    def _single_query(self, query_id: int, positions, normals, mu, frame_id: str):
        """The ContactArray of one query: serialized bytes, or a message without wire."""
        if not self._raw:
            msg = grasp_to_contact_array(query_id, positions, normals, mu,
                                         client_id=self.client_id)
            msg.header.frame_id = frame_id
            msg.header.stamp = self.node.get_clock().now().to_msg()
            return msg
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        contacts = np.zeros((len(positions), wire.CONTACT_VALUES))
        contacts[:, 0:3] = positions
        contacts[:, 3:6] = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        contacts[:, 6] = mu
        return wire.encode_contact_array(query_id, self.client_id, contacts, frame_id,
                                         self._stamp())

    def _stamp(self) -> tuple[int, int]:
        """The client node's clock now, (sec, nanosec): read from the system clock as
        rcl does unless ROS time is active (use_sim_time), without rclpy's Time objects
        (measured 6.3 vs 2.3 us a query)."""
        clock = self.node.get_clock()
        if clock.ros_time_is_active:
            return clock.now().seconds_nanoseconds()
        return divmod(time.time_ns(), 1_000_000_000)

    def _on_raw_verdicts(self, raws: list[bytes]):
        """Resolve the futures of serialized verdicts of this client."""
        mine = []
        for data in raws:
            if data[:len(wire.CDR_LE)] == wire.CDR_LE:
                client_id, query_id = wire.verdict_ids(data)
                if client_id == self.client_id:  # others' verdicts are not decoded
                    mine.append((query_id, data))
            else:
                msg = deserialize_message(data, ForceClosureVerdict)
                if msg.client_id == self.client_id:
                    mine.append((msg.id, data))
        with self._cond:
            entries = [(self._singles.pop(query_id, None), data) for query_id, data in mine]
            self._cond.notify_all()
        for entry, data in entries:
            if entry is not None:
                entry[1].set_result(wire.decode_verdict(data) if data[:4] == wire.CDR_LE
                                    else deserialize_message(data, ForceClosureVerdict))

    def _on_verdicts(self, msgs: list[ForceClosureVerdict]):
        with self._cond:
            entries = [(self._singles.pop(msg.id, None), msg) for msg in msgs
                       if msg.client_id == self.client_id]  # not another client's
            self._cond.notify_all()
        for entry, msg in entries:
            if entry is not None:
                entry[1].set_result(msg)

    def _on_loop_error(self, exc: Exception):
        self.node.get_logger().error(f"reading verdicts failed: {exc!r}")

    @property
    def in_flight(self) -> int:
        """Single queries and batches sent but not answered yet."""
        with self._cond:
            return len(self._singles) + len(self._batches)

    # --- batches ------------------------------------------------------------------------

    def submit_batch(self, positions, normals, mu=None, counts=None, ids=None,
                     frame_id: str = "", torsional_friction=None) -> Future:
        """Send grasps as one ContactArrayBatch; return a Future of their :class:`Verdicts`.

        ``positions``, ``normals``: (N, n, 3), or stacked (K, 3) with ``counts`` (N,);
        ``mu``: None (node default), a scalar or one value per contact; ``ids``: (N,),
        default 0..N-1; ``torsional_friction``: None (hard contacts), a scalar or one
        value per contact (m).
        """
        msg = self._batch_message(positions, normals, mu, counts, ids, frame_id,
                                  torsional_friction)
        future: Future = Future()
        with self._cond:
            self._batches[msg.request_id] = (msg, future)
        self._batch_pub.publish(msg)
        return future

    def _batch_message(self, positions, normals, mu, counts, ids, frame_id: str = "",
                       torsional_friction=None) -> ContactArrayBatch:
        """One stamped ContactArrayBatch of this client, with the next request id."""
        n_grasps = len(counts) if counts is not None else len(positions)
        ids = np.arange(n_grasps) if ids is None else ids
        with self._cond:
            request_id, self._next_request = self._next_request, self._next_request + 1
        msg = grasps_to_batch_msg(ids, positions, normals, mu, counts,
                                  client_id=self.client_id, request_id=request_id,
                                  torsional_friction=torsional_friction)
        msg.header.frame_id = frame_id
        msg.header.stamp = self.node.get_clock().now().to_msg()
        return msg

    def check_batch(self, positions, normals, mu=None, counts=None, ids=None,
                    timeout: float = DEFAULT_TIMEOUT_S, torsional_friction=None) -> Verdicts:
        """:meth:`submit_batch` and wait for its verdicts (TimeoutError after ``timeout``).

        With the node's ``certificates`` parameter on, the verdicts carry
        ``contact_forces`` (K, 3), grasp after grasp in the order sent (reshape to
        (N, n, 3) for equal sizes; NaN rows unless FORCE_CLOSURE) and
        ``separating_wrench`` (N, 6); with ``compute_min_friction``, ``min_friction``
        (N,); each is None when the node sent none; soft contacts add
        ``contact_torques`` (K,).
        """
        return self.submit_batch(positions, normals, mu, counts, ids,
                                 torsional_friction=torsional_friction).result(timeout)

    def _on_batch(self, msg: ForceClosureVerdictArray):
        if msg.client_id == self.client_id:
            self._batch_answered(msg.request_id, lambda: verdict_array_to_numpy(msg))

    def _on_raw_batch(self, raw: bytes):
        """A serialized verdict array: read with numpy (grasp_fc_ros.interface.wire), ~10x faster
        than rclpy's message for a large batch; other clients' answers are skipped
        unread."""
        client_id, request_id = wire.verdict_ids(raw)
        if client_id == self.client_id:
            self._batch_answered(request_id, lambda: wire.decode_verdict_array(raw)[2])

    def _batch_answered(self, request_id: int, read: Callable[[], Verdicts]):
        with self._cond:
            entry = self._batches.pop(request_id, None)
            self._cond.notify_all()
        if entry is None:
            return
        try:
            entry[1].set_result(read())
        except Exception as exc:  # noqa: BLE001 - the caller learns why, not a timeout
            entry[1].set_exception(exc)

    # --- the service --------------------------------------------------------------------

    def call(self, positions, normals, mu=0.0, ids=None,
             timeout: float = DEFAULT_TIMEOUT_S) -> Verdicts:
        """Decide grasps (N, n, 3) through the service; their :class:`Verdicts` in order.

        The verdicts always carry ``contact_forces`` (N * n, 3), ``separating_wrench``
        (N, 6) and ``min_friction`` (N,): NaN where the node sent none (parameters
        ``certificates``, ``compute_min_friction`` off, or no certificate).

        Raises
        ------
        TimeoutError
            If no response came within ``timeout``.
        """
        positions = np.asarray(positions, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        ids = np.arange(len(positions)) if ids is None else np.asarray(ids)
        mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), positions.shape[:2])
        request = CheckForceClosure.Request(grasps=[
            grasp_to_contact_array(i, p, n, m) for i, p, n, m in zip(ids, positions, normals, mu)])
        return self.call_request(request, timeout)

    def call_request(self, request, timeout: float = DEFAULT_TIMEOUT_S) -> Verdicts:
        """Send a prepared CheckForceClosure request; its :class:`Verdicts` in order."""
        replies = self._service_caller.call(request, timeout).verdicts
        return verdict_msgs_to_numpy(replies, [len(g.contacts) for g in request.grasps])

    def compute_contact_forces(self, positions, normals, wrench, mu=0.0,
                               max_normal_forces=None, frame_id: str = "",
                               timeout: float = DEFAULT_TIMEOUT_S,
                               torsional_friction=0.0) -> ContactForces:
        """The least-largest-normal-force contact forces that hold a load (the node's
        ``compute_contact_forces`` service).

        Parameters
        ----------
        positions, normals : (n, 3) float
            One grasp: contact positions (m) and inward normals.
        wrench : (6,) float
            External load on the object: force (N) then torque (N m) about the frame's
            origin; the contact forces cancel it.
        mu : scalar or (n,) float
            Friction per contact; a finite value <= 0 means the node's default.
        max_normal_forces : None or (n,) float
            Per-contact normal-force limits (N); None: no limits.
        frame_id : str
            Frame of the contacts and the wrench.
        torsional_friction : scalar or (n,) float
            Torsional friction per contact (m; 0: hard contact).

        Returns
        -------
        ContactForces
            ``feasible``, ``max_normal_force`` s* (inf: infeasible, NaN: invalid
            request), ``contact_forces`` (n, 3) and ``contact_torques`` (n,) (empty unless
            feasible) and ``message`` (why the request was refused, naming the contact).

        Raises
        ------
        TimeoutError
            If no response came within ``timeout``.
        """
        request = ComputeContactForces.Request(
            grasp=grasp_to_contact_array(0, positions, normals, mu,
                                         torsional_friction=torsional_friction))
        request.grasp.header.frame_id = frame_id
        w = np.asarray(wrench, dtype=np.float64).reshape(6).tolist()
        force, torque = request.wrench.force, request.wrench.torque
        force.x, force.y, force.z, torque.x, torque.y, torque.z = w
        if max_normal_forces is not None:
            request.max_normal_forces = np.asarray(max_normal_forces,
                                                   dtype=np.float64).reshape(-1).tolist()
        # wait_for_node waits for check_force_closure only; this service may be
        # discovered a moment later, and a request sent before would go unanswered.
        if not self._forces_service.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"service compute_contact_forces not found within {timeout} s")
        response = self._forces_caller.call(request, timeout)
        forces = np.array([(v.x, v.y, v.z) for v in response.contact_forces],
                          dtype=np.float64).reshape(-1, 3)
        return ContactForces(bool(response.feasible), float(response.max_normal_force),
                             forces, np.array(response.contact_torques, dtype=np.float64),
                             response.message)

    # --- the label_grasps action ------------------------------------------------------

    def label_grasps(self, positions, normals, mu=None, counts=None, ids=None,
                     progress: bool = True, timeout: float | None = None) -> Verdicts:
        """Decide grasps through the node's ``label_grasps`` action; their :class:`Verdicts`.

        The grasps go as one goal (packed as for :meth:`submit_batch`); the node's
        feedback (about 4 per second) drives a tqdm progress bar on stderr. Ctrl-C
        (KeyboardInterrupt) while waiting cancels the goal and returns the verdicts
        decided so far; a second Ctrl-C while waiting for them raises.

        Parameters
        ----------
        positions, normals : (N, n, 3) float, or stacked (K, 3) with ``counts`` (N,)
            Contact positions (m) and inward normals.
        mu : None, scalar or one value per contact
            None or values <= 0: the node's default friction.
        counts, ids : (N,) int, optional
            Contacts per grasp for stacked input; query ids (default 0..N-1).
        progress : bool
            Show the progress bar.
        timeout : float, optional
            Seconds for the whole goal (None: as long as it takes; the action server
            is then looked for for at most 60 s). On expiry the goal is cancelled.

        Returns
        -------
        Verdicts
            One per grasp, in order; fewer (a prefix) when the goal was cancelled
            (Ctrl-C) or aborted (the node shut down): :attr:`last_goal_status` says
            which (an ``action_msgs/GoalStatus`` code).

        Raises
        ------
        TimeoutError
            No action server, or the goal did not end within ``timeout``.
        RuntimeError
            The node rejected the goal (it is shutting down).
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        n_grasps = len(counts) if counts is not None else len(positions)
        batch = self._batch_message(positions, normals, mu, counts, ids)
        wait_s = DEFAULT_TIMEOUT_S if deadline is None else max(deadline - time.monotonic(), 0)
        if not self._label_action.wait_for_server(timeout_sec=wait_s):
            raise TimeoutError(f"no label_grasps action server within {wait_s:.1f} s")
        latest: list = [None]  # the newest feedback, written by the spin thread
        goal_handle = _wait_rclpy(
            request_on_spin_thread(self.node, lambda: self._label_action.send_goal_async(
                LabelGrasps.Goal(grasps=batch),
                feedback_callback=lambda msg: latest.__setitem__(0, msg.feedback))),
            deadline, "the label_grasps goal to be accepted")
        if not goal_handle.accepted:
            raise RuntimeError("the node rejected the label_grasps goal (shutting down?)")
        result_future = request_on_spin_thread(self.node, goal_handle.get_result_async)
        started = time.monotonic()
        done = threading.Event()
        result_future.add_done_callback(lambda _: done.set())

        def cancel():
            request_on_spin_thread(self.node, goal_handle.cancel_goal_async)

        with tqdm(total=n_grasps, unit="grasp", disable=not progress, dynamic_ncols=True,
                  desc="label_grasps") as bar:
            try:
                _follow_goal(done, latest, bar, deadline, cancel)
            except KeyboardInterrupt:
                cancel()
                if not done.wait(CANCEL_WAIT_S):
                    raise
            response = result_future.result()
            verdicts = verdict_array_to_numpy(response.result.verdicts)
            # The last feedback may predate the end (a short goal may have none after its
            # first): the bar ends on the verdicts themselves.
            elapsed = max(time.monotonic() - started, 1e-9)
            bar.set_postfix(force_closure=int(np.count_nonzero(verdicts.force_closure)),
                            rate=f"{len(verdicts) / elapsed:.0f}/s", refresh=False)
            bar.update(len(verdicts) - bar.n)
        self.last_goal_status = response.status
        return verdicts

    # --- diagnostics --------------------------------------------------------------------

    def _on_diagnostics(self, msg: DiagnosticArray):
        for status in msg.status:
            if status.name.startswith(self._diag_name):
                with self._cond:
                    self.diagnostics = {kv.key: kv.value for kv in status.values}
                    self._cond.notify_all()

    def next_diagnostics(self, timeout: float = 5.0) -> dict[str, str]:
        """The node's next /diagnostics key values (it publishes about once a second)."""
        with self._cond:
            self.diagnostics = {}
            if not self._cond.wait_for(lambda: self.diagnostics, timeout):
                raise TimeoutError(f"no diagnostics within {timeout} s")
            return dict(self.diagnostics)

    # --- lifetime -----------------------------------------------------------------------

    def _spin(self):
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - rclpy shut down while spinning: end quietly
            pass

    def close(self):
        """Stop spinning and destroy the client's node; unanswered futures are cancelled.

        A second call does nothing.
        """
        if self._closed:
            return
        self._closed = True
        self._verdict_loop.stop()
        self._executor.shutdown()
        self._spinner.join(timeout=5.0)
        self._service_node.destroy_node()
        self.node.destroy_node()
        with self._cond:
            pending = [f for _, f in self._singles.values()] + [
                f for _, f in self._batches.values()]
            self._singles.clear()
            self._batches.clear()
        for future in pending:
            future.cancel()

    def __enter__(self) -> GraspClient:
        return self

    def __exit__(self, *exc_info):
        self.close()



def request_on_spin_thread(node: Node, request: Callable[[], RclpyFuture]) -> RclpyFuture:
    """Make ``request()`` on the thread that spins ``node``; a Future of its response.

    For an rclpy ActionClient's ``send_goal_async``, ``get_result_async`` and
    ``cancel_goal_async``: rclpy 7 registers the request's future only after sending the
    request, so made from another thread, a response that the spin thread took in
    between was dropped ("Ignoring unexpected goal response") and the future never
    completed (a goal the node accepted and the client never learned of: seen once in
    a CI run). On the spin thread nothing is taken between the two. ``node`` must have
    been added to an executor that spins.
    """
    async def make_request():
        return await request()

    return node.executor.create_task(make_request)


def _wait_rclpy(future, deadline: float | None, what: str):
    """The result of an rclpy Future that the client's spin thread resolves."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    wait_s = None if deadline is None else max(deadline - time.monotonic(), 0)
    if not done.wait(wait_s):
        raise TimeoutError(f"timed out waiting for {what}")
    return future.result()


def _follow_goal(done: threading.Event, latest: list, bar, deadline: float | None,
                 cancel: Callable[[], None]):
    """Show a goal's feedback until its result is in; ``cancel()`` it at ``deadline``."""
    while not done.wait(PROGRESS_POLL_S):
        _show_progress(bar, latest[0])
        if deadline is not None and time.monotonic() > deadline:
            cancel()
            raise TimeoutError("label_grasps goal not done within its timeout (cancelled)")


def _show_progress(bar, feedback):
    """Move a tqdm ``bar`` to a LabelGrasps feedback's ``done`` (None: none yet)."""
    if feedback is None:
        return
    bar.set_postfix(force_closure=feedback.force_closure,
                    rate=f"{feedback.grasps_per_second:.0f}/s", refresh=False)
    bar.update(int(feedback.done) - bar.n)
