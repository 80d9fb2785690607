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
:meth:`submit` calls wait), and reads only its own answers: every query carries its
random ``client_id``, and the node answers it on the client's reply topics
(``verdicts/c<id>``, ``verdicts_batch/c<id>``: :func:`~grasp_fc_ros.interface.names.reply_topic`),
so other clients cost it nothing. It publishes again every unanswered query when a node
(re)appears on the query topics (e.g. after the node was killed and restarted), a query
with no answer within its bound (``resend_after``), and one whose publish failed (no
node up: it is kept, and sent when a node is there). A verdict answering an id twice
resolves its future once. :meth:`GraspClient.label_grasps`
sends a long job to the node's ``label_grasps`` action, with a progress bar and Ctrl-C
cancelling it.

Each concern has a module of its own: :mod:`.single_queries`, :mod:`.batches`,
:mod:`.service_calls`, :mod:`.label_action` and :mod:`.connection` (the watch on the
node and its diagnostics); this class puts them together.
"""

from __future__ import annotations

import secrets
import threading
from concurrent.futures import Future
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from grasp_fc_ros.client import shapes
from grasp_fc_ros.client.batches import BatchQueries
from grasp_fc_ros.client.connection import DiagnosticsReader, NodeWatch
from grasp_fc_ros.client.label_action import LabelActionClient
from grasp_fc_ros.client.pending import RESEND_AFTER_S
from grasp_fc_ros.client.service_calls import ServiceCalls
from grasp_fc_ros.client.single_queries import (
    DEFAULT_IN_FLIGHT,
    DEFAULT_TIMEOUT_S,
    SingleQueries,
)
from grasp_fc_ros.interface import wire
from grasp_fc_ros.interface.conversions import batch_arrays, friction_or_default
from grasp_fc_ros.interface.names import (
    NODE_NAME,
    VERDICTS_BATCH_TOPIC,
    VERDICTS_TOPIC,
    resolve,
)
from grasp_fc_ros.packed import ContactForces, RobustnessQuery, Verdicts


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
    resend_after : float
        Seconds without an answer after which a query is sent again (batches: plus
        :data:`~grasp_fc_ros.client.pending.RESEND_PER_GRASP_S` per grasp); default
        :data:`~grasp_fc_ros.client.pending.RESEND_AFTER_S`.

    Requires ``rclpy.init()``; the client spins its own node on a thread of its own
    (service calls wait for their responses in the calling thread).

    Attributes
    ----------
    client_id : int
        Carried by every query of this client (random, never 0).
    node : rclpy.node.Node
        The client's own node.
    label_action : LabelActionClient
        The label_grasps action client (:meth:`label_grasps`).
    """

    def __init__(self, node_name: str = NODE_NAME, max_in_flight: int = DEFAULT_IN_FLIGHT,
                 name: str | None = None, resend_after: float = RESEND_AFTER_S):
        self.client_id = secrets.randbits(63) | 1  # never 0 ("no client id")
        self.node = Node(name or f"grasp_fc_client_{self.client_id:x}")
        # Queries go out and verdicts come in serialized (grasp_fc_ros.interface.wire),
        # unless this rmw's layout is not the one wire writes.
        serialized = wire.layout_matches()
        self._singles = SingleQueries(self.node, node_name, self.client_id, max_in_flight,
                                      serialized, resend_after)
        self._batches = BatchQueries(self.node, node_name, self.client_id, serialized,
                                     resend_after)
        self._services = ServiceCalls(self.node.get_name(), node_name)
        self.label_action = LabelActionClient(self.node, node_name)
        self._diagnostics = DiagnosticsReader(self.node, node_name)
        self._watch = NodeWatch(
            self.node, [self._singles.publisher, self._batches.publisher],
            [resolve(node_name, VERDICTS_TOPIC), resolve(node_name, VERDICTS_BATCH_TOPIC)],
            self._services.check_client, self._resend)
        self._closed = False
        self._executor = SingleThreadedExecutor(context=self.node.context)
        self._executor.add_node(self.node)
        self._spinner = threading.Thread(target=self._spin, daemon=True, name="grasp_client")
        self._spinner.start()

    # --- connection -------------------------------------------------------------------

    def wait_for_node(self, timeout: float = DEFAULT_TIMEOUT_S) -> bool:
        """Wait until the node's service and both directions of its topics are matched."""
        return self._watch.wait(timeout)

    @property
    def resubmitted(self) -> int:
        """Grasps published again: a node (re)appeared, or they had no answer within
        their bound (:mod:`grasp_fc_ros.client.pending`), or their publish failed."""
        return self._watch.resubmitted

    def _resend(self, everything: bool) -> int:
        return self._singles.resend(everything) + self._batches.resend(everything)

    @property
    def in_flight(self) -> int:
        """Single queries and batches sent but not answered yet."""
        return self._singles.in_flight + self._batches.in_flight

    # --- single queries -----------------------------------------------------------------

    def submit(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None,
               query_id: int | None = None, frame_id: str = "",
               timeout: float = DEFAULT_TIMEOUT_S) -> Future:
        """Send one grasp on ``contacts``; return a Future of its ForceClosureVerdict.

        Parameters
        ----------
        positions, normals : (n, 3) float
            Contact positions (m) and inward normals.
        mu : None, scalar or (n,) float
            Friction per contact; None or 0: the node's ``friction_coefficient``
            (negative: INVALID_INPUT).
        query_id : int, optional
            Default: a number counting up from 1 in this client.
        frame_id : str
            Frame of the contacts; the verdict's header carries it back.
        timeout : float
            How long to wait for room when ``max_in_flight`` queries are unanswered.

        The query is kept until answered: while no node is up (publishing fails) it is
        sent when one appears, and it is sent again if no answer came within
        ``resend_after``. Nothing else is raised.

        Raises
        ------
        TimeoutError
            If no room was made within ``timeout`` (nothing was registered).
        ValueError
            If the arrays' shapes do not match (naming them), or ``query_id`` is already
            in flight (nothing was registered).
        """
        positions, normals = shapes.one_grasp(positions, normals)
        shapes.per_contact(mu, "mu", positions)
        return self._singles.submit(positions, normals, friction_or_default(mu), query_id,
                                    frame_id, timeout)

    # --- batches ------------------------------------------------------------------------

    def submit_batch(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None,
                     counts: ArrayLike | None = None, ids: ArrayLike | None = None,
                     frame_id: str = "", torsional_friction: ArrayLike | None = None
                     ) -> Future:
        """Send grasps as ContactArrayBatch messages (one, or parts of whole grasps beyond
        MAX_MESSAGE_CONTACTS contacts); return a Future of all their :class:`Verdicts`.

        ``positions``, ``normals``: (N, n, 3), or stacked (K, 3) with ``counts`` (N,);
        ``mu``: None or 0 (the node's ``friction_coefficient``), a scalar or one value per
        contact; ``ids``: (N,),
        default 0..N-1; ``torsional_friction``: None (hard contacts), a scalar or one
        value per contact (m).

        The batch is kept until answered, as for :meth:`submit` (its bound grows with
        its size). Raises only the ValueError of a mis-shaped input, naming the arrays
        and their shapes, before anything is registered or sent.
        """
        positions, normals, _ = _checked_batch(positions, normals, mu, counts, ids,
                                               torsional_friction)
        return self._batches.submit(positions, normals, mu, counts, ids, frame_id,
                                    torsional_friction)

    def check_batch(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None,
                    counts: ArrayLike | None = None, ids: ArrayLike | None = None,
                    timeout: float = DEFAULT_TIMEOUT_S,
                    torsional_friction: ArrayLike | None = None) -> Verdicts:
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

    # --- the services -------------------------------------------------------------------

    def call(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None,
             ids: ArrayLike | None = None, timeout: float = DEFAULT_TIMEOUT_S) -> Verdicts:
        """Decide grasps (N, n, 3) through the service; their :class:`Verdicts` in order.

        ``mu``: None or 0 (the node's ``friction_coefficient``), a scalar or (N, n).
        The verdicts always carry ``contact_forces`` (N * n, 3), ``separating_wrench``
        (N, 6) and ``min_friction`` (N,): NaN where the node sent none (parameters
        ``certificates``, ``compute_min_friction`` off, or no certificate).

        A call of more than MAX_REQUEST_CONTACTS contacts goes as several requests of
        whole grasps, each sent once the one before was answered (the node serves other
        calls between them), and its verdicts are joined in order; ``timeout`` is for
        the whole call.

        Raises
        ------
        TimeoutError
            If not every response came within ``timeout``; it names the service.
        ValueError
            If the arrays' shapes do not match, naming them (nothing was sent).
        """
        positions, normals, n_grasps = shapes.grasp_batch(positions, normals,
                                                          stacked=False)
        shapes.per_grasp(ids, "ids", n_grasps)
        shapes.per_contact(mu, "mu", positions)
        return self._services.call(positions, normals, friction_or_default(mu), ids, timeout)

    def call_request(self, request: Any, timeout: float = DEFAULT_TIMEOUT_S) -> Verdicts:
        """Send a prepared CheckForceClosure request; its :class:`Verdicts` in order
        (several requests beyond MAX_REQUEST_CONTACTS contacts, as :meth:`call`)."""
        return self._services.call_request(request, timeout)

    def compute_contact_forces(self, positions: ArrayLike, normals: ArrayLike,
                               wrench: ArrayLike, mu: ArrayLike | None = None,
                               max_normal_forces: ArrayLike | None = None, frame_id: str = "",
                               timeout: float = DEFAULT_TIMEOUT_S,
                               torsional_friction: ArrayLike = 0.0) -> ContactForces:
        """The least-largest-normal-force contact forces that hold a load (the node's
        ``compute_contact_forces`` service).

        Parameters
        ----------
        positions, normals : (n, 3) float
            One grasp: contact positions (m) and inward normals.
        wrench : (6,) float
            External load on the object: force (N) then torque (N m) about the frame's
            origin; the contact forces cancel it.
        mu : None, scalar or (n,) float
            Friction per contact; None or 0: the node's ``friction_coefficient``
            (negative: INVALID_INPUT).
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
        ValueError
            If the arrays' shapes do not match, naming them (nothing was sent).
        """
        positions, normals = shapes.one_grasp(positions, normals)
        wrench = shapes.wrench(wrench)
        for values, name in ((mu, "mu"), (max_normal_forces, "max_normal_forces"),
                             (torsional_friction, "torsional_friction")):
            shapes.per_contact(values, name, positions)
        return self._services.compute_contact_forces(positions, normals, wrench,
                                                     friction_or_default(mu),
                                                     max_normal_forces, frame_id, timeout,
                                                     torsional_friction)

    def assess_robustness(
            self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None, *,
            position_error: float = 0.0, normal_error: float = 0.0, friction_error: float = 0.0,
            position_sigma: float = 0.0, normal_sigma: float = 0.0, friction_sigma: float = 0.0,
            samples: int = 1000, confidence: float = 0.95, seed: int = 0,
            ids: ArrayLike | None = None, torsional_friction: ArrayLike | None = None,
            frame_id: str = "", timeout: float = DEFAULT_TIMEOUT_S) -> Verdicts:
        """How well grasps hold when their contacts are off: the node's
        ``assess_robustness`` service (docs/robustness.md, docs/client.md).

        ``positions``, ``normals``: (N, n, 3), or (n, 3) for one grasp; ``mu``: None (the
        node's ``friction_coefficient``), a scalar, (N, 1) or (N, n); the errors of the
        holds answer (m, rad, unitless) and the sigmas of the probability; ``samples``
        per grasp (0: no probability); grasp ``ids[k]`` (default k) draws its samples
        from stream (``seed``, ``ids[k]``), so the answers do not depend on how the call
        is split or ordered; ``torsional_friction`` (m): soft fingers get a probability
        but no radii and no holds answer. ``timeout`` bounds the whole call (many
        grasps go as several requests).

        Returns
        -------
        Verdicts
            The nominal verdicts (``margin`` NaN) and ``robustness``, an
            :class:`~grasp_fc_ros.packed.Assessments` of numpy arrays, one row per grasp
            (the witness one per contact). Bad grasps are INVALID_INPUT alone, a refused
            request INVALID_INPUT for every grasp, the message saying why.

        Raises
        ------
        ValueError
            On mis-shaped input (naming the argument), before anything is sent.
        TimeoutError
            If not every response came within ``timeout``; it names the service.
        """
        question = RobustnessQuery(position_error, normal_error, friction_error, position_sigma,
                            normal_sigma, friction_sigma, samples, confidence, seed)
        return self._services.assess_robustness(positions, normals, mu, torsional_friction,
                                                ids, question, frame_id, timeout)

    # --- the label_grasps action ------------------------------------------------------

    def label_grasps(self, positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None = None,
                     counts: ArrayLike | None = None, ids: ArrayLike | None = None,
                     progress: bool = True, timeout: float | None = None) -> Verdicts:
        """Decide grasps through the node's ``label_grasps`` action; their :class:`Verdicts`.

        The grasps go as one job (packed as for :meth:`submit_batch`): one goal, or,
        beyond MAX_MESSAGE_CONTACTS contacts, several goals of whole grasps, sent one
        after the other (at most two unfinished at once) so that no large message holds
        up the node's service calls (docs/client.md). The goals' feedback (about 4 per
        second), added up over the job, drives a tqdm progress bar on stderr. Ctrl-C
        (KeyboardInterrupt) while waiting cancels the job (the goals in flight; no more
        are sent) and returns the verdicts decided so far, a prefix; a second Ctrl-C
        while waiting for them raises.

        Parameters
        ----------
        positions, normals : (N, n, 3) float, or stacked (K, 3) with ``counts`` (N,)
            Contact positions (m) and inward normals.
        mu : None, scalar or one value per contact
            None or 0: the node's ``friction_coefficient`` (negative: INVALID_INPUT).
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
            One per grasp, in order; fewer (a prefix) when the job was cancelled
            (Ctrl-C) or aborted (the node shut down, or rejected a later goal of the
            job): :attr:`last_goal_status` says which (an ``action_msgs/GoalStatus``
            code).

        Raises
        ------
        TimeoutError
            No action server, or the goal did not end within ``timeout``.
        RuntimeError
            The node rejected the job's first goal (it is shutting down).
        ValueError
            If the arrays' shapes do not match, naming them (nothing was sent).
        """
        positions, normals, n_grasps = _checked_batch(positions, normals, mu, counts, ids)
        ids = np.arange(n_grasps) if ids is None else ids
        return self.label_action.label(batch_arrays(ids, positions, normals, mu, counts),
                                       progress, timeout, self.client_id)

    @property
    def last_goal_status(self) -> int:
        """``action_msgs/GoalStatus`` code of the last label_grasps job."""
        return self.label_action.last_goal_status

    # --- diagnostics --------------------------------------------------------------------

    @property
    def diagnostics(self) -> dict[str, str]:
        """The node's latest /diagnostics key values ({} before the first)."""
        return self._diagnostics.latest

    def next_diagnostics(self, timeout: float = 5.0) -> dict[str, str]:
        """The node's next /diagnostics key values (it publishes about once a second)."""
        return self._diagnostics.next(timeout)

    # --- lifetime -----------------------------------------------------------------------

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # noqa: BLE001 - rclpy shut down while spinning: end quietly
            pass

    def close(self) -> None:
        """Stop spinning and destroy the client's node; unanswered futures are cancelled.

        A second call does nothing.
        """
        if self._closed:
            return
        self._closed = True
        pending = self._singles.close() + self._batches.close()
        self._executor.shutdown()
        self._spinner.join(timeout=5.0)
        self._services.close()
        self.node.destroy_node()
        for future in pending:
            future.cancel()

    def __enter__(self) -> GraspClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _checked_batch(positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None,
                   counts: ArrayLike | None, ids: ArrayLike | None,
                   torsional_friction: ArrayLike | None = None
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """A batch's positions and normals as float64 arrays and its number of grasps, once
    every shape was checked (:mod:`.shapes`; ValueError naming the arrays and their
    shapes)."""
    positions, normals, n_grasps = shapes.grasp_batch(positions, normals, counts)
    shapes.per_grasp(ids, "ids", n_grasps)
    shapes.per_contact(mu, "mu", positions, flat=True)
    shapes.per_contact(torsional_friction, "torsional_friction", positions, flat=True)
    return positions, normals, n_grasps
