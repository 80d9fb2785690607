"""RViz markers of answered queries, built and published off the verdict path.

The node hands every answered message (a single-grasp query, a service request, a
batch) to :class:`MarkerPublisher` *after* its verdicts are out: ``offer_*`` only append
a reference to a bounded queue. A thread of the node's takes the oldest, converts its
sampled grasps to numpy (:class:`MarkerPayload`) and passes them to a marker process
(:class:`MarkerProcess`, ``python -m grasp_fc_ros.markers.publisher``), one at a time,
which computes the separating wrench of the rejected grasps with
``check_force_closure(..., certificates=True)``, builds the markers with
:func:`grasp_fc_ros.markers.build.grasp_markers` (:func:`draw`) and publishes one
``visualization_msgs/MarkerArray`` per message on ``markers`` from a node of its own,
``<node name>_markers`` in the node's namespace.

Why a process: building one grasp's markers costs several times a one-grasp core call
(benchmarks/bench_markers.py), and on a thread of the node that work held the GIL
while the next query waited for it (docs/performance.md#markers). When the marker process
falls behind, the oldest queued marker work is dropped (and counted), never a verdict.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from builtin_interfaces.msg import Time
from grasp_fc_msgs.msg import ContactArray, ContactArrayBatch
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.engine.child_process import (
    ONE_THREAD_ENV,
    ChildProcess,
    FramingError,
    open_channel,
    read_message,
    write_message,
)
from grasp_fc_ros.interface.conversions import (
    MalformedBatch,
    batch_to_packed,
    contact_arrays_to_packed,
)
from grasp_fc_ros.markers.build import DEFAULT_LIFETIME_S, delete_all_markers, grasp_markers
from grasp_fc_ros.packed import Verdicts

# Messages whose markers may wait to be built; beyond, the oldest are dropped. A few
# seconds of work at most (a message holds at most MAX_MARKER_SAMPLE grasps).
MARKER_QUEUE_LENGTH = 64
# Upper bound of the marker_batch_sample parameter: it bounds one MarkerArray's build
# time and size (measured: docs/performance.md#markers).
MAX_MARKER_SAMPLE = 1000
DEFAULT_MARKER_SAMPLE = 10
# The markers topic: reliable like RViz's MarkerArray display, a KEEP_LAST history so
# that a slow viewer never blocks the marker process, and transient local: a viewer that
# subscribes so (RViz: Durability Policy "Transient Local") gets the last 100 arrays
# when it joins, including those sent before discovery had matched it (a volatile
# publisher drops them: seen with a busy participant); volatile viewers match as well.
MARKER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST, depth=100,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Niceness added to the marker process where the SCHED_IDLE policy is not available:
# markers are best effort, so on a busy machine the CPU goes to the node first.
MARKER_PROCESS_NICENESS = 10
# How long close() waits for the marker process to exit after its stdin closed (s).
PROCESS_EXIT_TIMEOUT_S = 2.0
# Verdicts whose grasps have a separating wrench to draw.
_REJECTED = (Status.FILTERED_OUT, Status.NOT_FORCE_CLOSURE)


@dataclass(frozen=True)
class MarkerSettings:
    """The marker parameters of the node; one snapshot serves a whole message.

    Attributes
    ----------
    enabled : bool
        ``publish_markers``: the node offers nothing when False.
    lifetime_s : float
        ``marker_lifetime``: seconds until RViz drops a query's markers (0: never).
    batch_sample : int
        ``marker_batch_sample``: at most this many grasps of one batch or service
        request get markers (evenly spread over it); 0: none.
    """

    enabled: bool = False
    lifetime_s: float = DEFAULT_LIFETIME_S
    batch_sample: int = DEFAULT_MARKER_SAMPLE


def sample_indices(n_grasps: int, sample: int) -> np.ndarray:
    """Indices of at most ``sample`` of ``n_grasps`` grasps, evenly spread, ascending.

    Returns
    -------
    (min(n_grasps, sample),) int64 array; all grasps when ``n_grasps <= sample``.
    """
    if n_grasps <= sample:
        return np.arange(n_grasps, dtype=np.int64)
    if sample <= 0:
        return np.empty(0, np.int64)
    return np.round(np.linspace(0, n_grasps - 1, sample)).astype(np.int64)


def decided_mu(mu: np.ndarray, default: float) -> np.ndarray:
    """Friction coefficients as decided: values exactly 0 replaced by ``default``."""
    return np.where(mu == 0, default, mu)


@dataclass
class MarkerPayload:
    """The grasps of one answered message that get markers, as numpy arrays (picklable).

    Attributes
    ----------
    frame_id : str
    stamp : (sec, nanosec) of the query's header
    ids, counts : (G,) uint64 and int64: query id and contact count per drawn grasp
    positions, normals : (K, 3) float64: their contacts, grasp after grasp (m)
    mu : (K,) float64: friction coefficient per contact as decided (default substituted)
    status : (G,) uint8 and margin : (G,) float64: the published verdicts
    lifetime_s : float
    """

    frame_id: str
    stamp: tuple[int, int]
    ids: np.ndarray
    counts: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    status: np.ndarray
    margin: np.ndarray
    lifetime_s: float

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class _Job:
    """One answered message whose markers are still to be built.

    ``queries`` is either ContactArray messages (single queries or a service request;
    one per verdict), serialized ContactArrays (single queries the node took as bytes,
    or messages serialized by :meth:`portable`) or one ContactArrayBatch; ``status`` and
    ``margin`` hold one verdict per grasp. A job of single queries is drawn in the frame
    of its first one.
    """

    queries: Sequence[ContactArray] | Sequence[bytes] | ContactArrayBatch
    status: list[int]
    margin: list[float]
    default_mu: float
    settings: MarkerSettings
    limit: int  # at most this many of its grasps get markers

    def __len__(self) -> int:
        """How many grasps of this job get markers."""
        return min(len(self.status), self.limit)

    def portable(self) -> _Job | MarkerPayload:
        """What the marker process is sent: the sampled queries serialized, as a job
        (converted there), or for a batch its payload (its packing is vectorized; a whole
        batch serialized would be large)."""
        if isinstance(self.queries, ContactArrayBatch):
            return self.payload()
        drawn = sample_indices(len(self.queries), self.limit).tolist()
        return replace(
            self, queries=[q if isinstance(q, bytes) else serialize_message(q)
                           for q in (self.queries[i] for i in drawn)],
            status=[self.status[i] for i in drawn], margin=[self.margin[i] for i in drawn],
            limit=len(drawn))

    def payload(self) -> MarkerPayload:
        """The sampled grasps, converted (raises MalformedBatch for a mis-packed batch)."""
        if isinstance(self.queries, ContactArrayBatch):
            packed = batch_to_packed(self.queries)
            header: Header = self.queries.header
        else:
            queries = [deserialize_message(q, ContactArray) if isinstance(q, bytes) else q
                       for q in self.queries]
            header = queries[0].header
            packed = contact_arrays_to_packed(queries)
        drawn = sample_indices(len(packed), self.limit)
        starts = packed.starts[drawn]
        counts = packed.counts[drawn]
        rows = np.concatenate([np.arange(lo, lo + c) for lo, c in
                               zip(starts.tolist(), counts.tolist(), strict=True)]
                              or [np.empty(0, int)])
        return MarkerPayload(
            frame_id=header.frame_id,
            stamp=(header.stamp.sec, header.stamp.nanosec),
            ids=packed.ids[drawn], counts=counts, positions=packed.positions[rows],
            normals=packed.normals[rows], mu=decided_mu(packed.mu[rows], self.default_mu),
            status=np.asarray(self.status, np.uint8)[drawn],
            margin=np.asarray(self.margin, np.float64)[drawn],
            lifetime_s=self.settings.lifetime_s)


class MarkerSink(Protocol):
    """Where the marker thread sends its work (:class:`MarkerProcess`, or a test's)."""

    def start(self) -> None:
        """Get ready to draw (idempotent)."""

    def wait_ready(self, timeout_s: float) -> bool:
        """Start if need be and wait, at most ``timeout_s``, until drawing can begin at
        once; whether it can."""

    def draw(self, work: _Job | MarkerPayload) -> int:
        """Build and publish the markers of ``work`` (a job is converted first, see
        :func:`draw`); return how many grasps were drawn."""

    def clear(self) -> None:
        """Publish a DELETEALL."""

    def close(self) -> None:
        """Release the sink's resources."""


class MarkerPublisher:
    """A bounded queue of answered messages and the thread that hands them to a sink.

    Parameters
    ----------
    sink : MarkerSink
        Builds and publishes; called from the thread only, one payload at a time.
    on_error : callable(what, exception)
        Told about marker work that failed (it never reaches the verdict path).

    Attributes
    ----------
    sink : MarkerSink
    """

    def __init__(self, sink: MarkerSink, on_error: Callable[[str, Exception], None]) -> None:
        self.sink = sink
        self._on_error = on_error
        self._lock = threading.Condition()
        self._jobs: deque[_Job | None] = deque()  # None: publish a DELETEALL
        self._closing = False
        self.published = 0  # grasps whose markers were published
        self.dropped = 0    # grasps whose markers were dropped (queue full)
        self._thread = threading.Thread(target=self._run, daemon=True, name="markers")
        self._thread.start()

    # --- called by the node (cheap: no conversion, no maths) ---------------------------

    def offer_singles(self, queries: Sequence[ContactArray], replies: Sequence,
                      settings: MarkerSettings, default_mu: float) -> None:
        """Queue markers of answered single-grasp topic queries: one MarkerArray each.

        ``replies`` are their ForceClosureVerdict messages; ``default_mu`` the node's
        ``friction_coefficient``. The node calls the ``offer_*`` methods only when
        ``settings.enabled``.
        """
        for query, reply in zip(queries, replies, strict=True):
            self._queue(_Job(queries=[query], status=[reply.status],
                             margin=[reply.margin], default_mu=default_mu,
                             settings=settings, limit=1))

    def offer_serialized_singles(self, raws: Sequence[bytes], verdicts: Verdicts,
                                 settings: MarkerSettings, default_mu: float) -> None:
        """:meth:`offer_singles` for queries the node took serialized (``raws``, one per
        verdict of ``verdicts``); they are deserialized on the marker thread."""
        for raw, status, margin in zip(raws, verdicts.status.tolist(),
                                       verdicts.margin.tolist(), strict=True):
            self._queue(_Job(queries=[raw], status=[status], margin=[margin],
                             default_mu=default_mu, settings=settings, limit=1))

    def offer_service(self, grasps: Sequence[ContactArray], replies: Sequence,
                      settings: MarkerSettings, default_mu: float) -> None:
        """Queue markers of at most ``batch_sample`` grasps of an answered service request.

        One MarkerArray for the request, in the frame of its first grasp's header.
        """
        if not grasps or settings.batch_sample == 0:
            return
        self._queue(_Job(queries=grasps,
                         status=[r.status for r in replies], margin=[r.margin for r in replies],
                         default_mu=default_mu, settings=settings,
                         limit=settings.batch_sample))

    def offer_batch(self, query: ContactArrayBatch, verdicts: Verdicts,
                    settings: MarkerSettings, default_mu: float) -> None:
        """Queue markers of at most ``batch_sample`` grasps of an answered batch (its
        published ``verdicts``)."""
        if not len(query.ids) or settings.batch_sample == 0:
            return
        self._queue(_Job(queries=query, status=verdicts.status.tolist(),
                         margin=verdicts.margin.tolist(), default_mu=default_mu,
                         settings=settings, limit=settings.batch_sample))

    def start(self) -> None:
        """Start the sink now (the node does when publish_markers turns on), so that
        viewers have discovered the marker topic before the first markers go out."""
        self.sink.start()

    def wait_ready(self, timeout_s: float) -> bool:
        """Start the sink and wait, at most ``timeout_s``, until it can draw at once (the
        node does before it says it is ready, so that its first answers' markers do not
        wait for the marker process to start); whether it can."""
        return self.sink.wait_ready(timeout_s)

    def clear(self) -> None:
        """Discard queued marker work and publish a DELETEALL (in that order)."""
        with self._lock:
            self._jobs.clear()
            self._jobs.append(None)
            self._lock.notify_all()

    def counts(self) -> dict[str, int]:
        """Diagnostics: grasps whose markers were published and dropped."""
        with self._lock:
            return {"markers_published": self.published, "markers_dropped": self.dropped}

    def close(self) -> None:
        """Stop the thread and the sink (queued marker work is discarded)."""
        with self._lock:
            self._closing = True
            self._lock.notify_all()
        self.sink.close()
        self._thread.join()

    def _queue(self, job: _Job) -> None:
        with self._lock:
            if len(self._jobs) >= MARKER_QUEUE_LENGTH:
                # The oldest marker work goes (a requested DELETEALL stays).
                oldest = next(j for j in self._jobs if j is not None)
                self._jobs.remove(oldest)
                self.dropped += len(oldest)
            self._jobs.append(job)
            self._lock.notify_all()

    # --- the marker thread ------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._lock:
                self._lock.wait_for(lambda: self._jobs or self._closing)
                if self._closing:
                    return
                job = self._jobs.popleft()
            try:
                if job is None:
                    self.sink.clear()
                    continue
                drawn = self.sink.draw(job.portable())
                with self._lock:
                    self.published += drawn
            except MalformedBatch:
                pass  # every grasp of it is INVALID_INPUT and none can be placed
            except Exception as exc:  # noqa: BLE001 - markers must never stop the node
                if self._closing:
                    return
                self._on_error("markers", exc)


# --- building the markers (in the marker process) ---------------------------------


def draw(work: _Job | MarkerPayload) -> MarkerArray:
    """All markers of one payload's grasps in one MarkerArray, with separating wrenches.

    A job is converted to its payload here, in the marker process: deserializing and
    packing would cost the node's process time on a thread that shares the GIL with the
    verdict path (docs/performance.md#markers).
    """
    payload = work.payload() if isinstance(work, _Job) else work
    starts = np.concatenate(([0], np.cumsum(payload.counts)[:-1])).astype(np.int64)
    wrenches = separating_wrenches(payload, starts)
    stamp = Time(sec=payload.stamp[0], nanosec=payload.stamp[1])
    out = MarkerArray()
    for i, (lo, count) in enumerate(zip(starts.tolist(), payload.counts.tolist(), strict=True)):
        rows = slice(lo, lo + count)
        out.markers.extend(grasp_markers(
            payload.positions[rows], payload.normals[rows], payload.mu[rows],
            int(payload.status[i]), query_id=int(payload.ids[i]), frame_id=payload.frame_id,
            stamp=stamp, margin=float(payload.margin[i]),
            separating_wrench=wrenches.get(i), lifetime_s=payload.lifetime_s).markers)
    return out


def separating_wrenches(payload: MarkerPayload, starts: np.ndarray) -> dict[int, np.ndarray]:
    """Separating wrench (6,) of each rejected grasp of ``payload`` that has one, by index.

    One certificate core call per contact count; the published verdict colours the
    markers, only its wrench is computed here.
    """
    by_count: dict[int, list[int]] = {}
    for i, status in enumerate(payload.status.tolist()):
        if status in _REJECTED:
            by_count.setdefault(int(payload.counts[i]), []).append(i)
    wrenches: dict[int, np.ndarray] = {}
    for count, indices in by_count.items():
        rows = (starts[indices][:, None] + np.arange(count)).reshape(-1)
        shape = (len(indices), count)
        result = check_force_closure(
            payload.positions[rows].reshape(*shape, 3), payload.normals[rows].reshape(*shape, 3),
            payload.mu[rows].reshape(shape), margin="bound", certificates=True)
        assert result.separating_wrench is not None  # certificates=True
        for i, wrench, fc in zip(indices, result.separating_wrench, result.force_closure,
                                 strict=True):
            if not fc and np.isfinite(wrench).all():
                wrenches[i] = wrench
    return wrenches


class MarkerProcess:
    """The marker process: started by :meth:`start` or the first payload, started again
    when it died or broke its channel.

    ``python -m grasp_fc_ros.markers.publisher NAMESPACE NODE_NAME`` runs a node
    ``NODE_NAME`` in ``NAMESPACE`` publishing on ``markers``; it reads pickled payloads
    (None: DELETEALL) on its channel (:class:`~grasp_fc_ros.engine.child_process.ChildProcess`:
    pipes of its own, so that nothing its middleware prints can corrupt them) and
    answers each with the number of grasps drawn. It ignores SIGINT (its owner decides)
    and ends when its channel closes, so a killed node leaves no marker process. ``draw``
    and ``clear`` are called from one thread (the marker thread) at a time, and
    :meth:`wait_ready` may be called from another; an exchange that fails (the process
    died, or a message was broken) raises, and the process is replaced at once, so that
    the next payload finds a fresh one.

    Parameters
    ----------
    namespace : str
        The node's namespace (the topic is ``<namespace>/markers``).
    node_name : str
        Name of the marker process's node.
    """

    def __init__(self, namespace: str, node_name: str) -> None:
        self._args = [namespace, node_name]
        self._child: ChildProcess | None = None
        self._ready = False  # the running process said it is ready
        self._closed = False
        self._lock = threading.Lock()  # the process
        self._exchange = threading.Lock()  # the channel: one exchange at a time

    @property
    def process(self) -> subprocess.Popen | None:
        """The marker process, once started (None before, and after :meth:`close`)."""
        child = self._child
        return None if child is None else child.process

    def start(self) -> None:
        self._running()

    def wait_ready(self, timeout_s: float) -> bool:
        with self._exchange:
            child = self._running()
            if self._ready:
                return True
            if not select.select([child.from_child], [], [], timeout_s)[0]:
                return False
            try:
                self._await_ready(child)
            except Exception as exc:
                raise self._failed(child, exc) from exc
            return True

    def draw(self, work: _Job | MarkerPayload) -> int:
        drawn = self._call(work)
        assert isinstance(drawn, int)
        return drawn

    def clear(self) -> None:
        self._call(None)

    def _running(self) -> ChildProcess:
        with self._lock:
            if self._closed:
                raise RuntimeError("marker process closed")
            if self._child is None or self._child.poll() is not None:
                if self._child is not None:
                    _reap(self._child)
                self._child = ChildProcess.start(
                    [sys.executable, "-m", "grasp_fc_ros.markers.publisher", *self._args],
                    {**os.environ, **ONE_THREAD_ENV})
                self._ready = False
            return self._child

    def _call(self, request: _Job | MarkerPayload | None) -> object:
        """Send one request and wait for its answer (and first for the process's
        "ready", so that a request never waits in a pipe of a process still starting).

        Raises
        ------
        RuntimeError
            If the process could not draw it (its exception, worded), or the exchange
            failed: the process died or broke its channel (it is then replaced).
        """
        with self._exchange:
            child = self._running()
            try:
                self._await_ready(child)
                write_message(child.to_child, request)
                ok, answer = read_message(child.from_child)
            except Exception as exc:
                raise self._failed(child, exc) from exc
        if not ok:
            raise RuntimeError(f"marker process: {answer}")
        return answer

    def _await_ready(self, child: ChildProcess) -> None:
        """Read the process's "ready", unless it was read already."""
        if not self._ready:
            hello = read_message(child.from_child)
            if hello != (True, "ready"):
                raise RuntimeError(f"said {hello!r} instead of ready")
            self._ready = True

    def _failed(self, child: ChildProcess, exc: Exception) -> RuntimeError:
        """Replace ``child``, whose exchange failed with ``exc``: kill and reap it and
        start its successor (unless closed meanwhile); the error to raise."""
        with self._lock:
            if self._child is child:
                self._child = None
        _reap(child)
        try:
            self._running()
        except RuntimeError:
            pass  # closed meanwhile
        return RuntimeError(f"marker process {child.pid} failed ({exc!r}); started another")

    def close(self) -> None:
        with self._lock:
            child, self._child, self._closed = self._child, None, True
        if child is None:
            return
        child.close_channel()  # the process ends at EOF
        try:
            child.process.wait(timeout=PROCESS_EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            _reap(child)


def _reap(child: ChildProcess) -> None:
    """Kill ``child`` (if it still runs), wait for it and close its channel."""
    child.process.kill()
    child.process.wait()
    child.close_channel()


def _run_when_idle() -> None:
    """Put this process under Linux's SCHED_IDLE policy: it runs only on CPU time no
    other process wants, and yields at once when the node or its clients wake up
    (niceness +10 alone still slowed the single queries: docs/performance.md#markers).
    Elsewhere, niceness +10."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        os.nice(MARKER_PROCESS_NICENESS)


def _serve(namespace: str, node_name: str) -> None:
    """Marker process main loop: payloads in, (ok, grasps drawn) out, on its channel."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from grasp_fc_ros.core import warm_up

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _run_when_idle()
    requests, answers = open_channel()
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(node_name, namespace=namespace, use_global_arguments=False,
                             start_parameter_services=False)
    publisher = node.create_publisher(MarkerArray, "markers", MARKER_QOS)
    warm_up()  # the compiled exact stage, for the separating wrenches
    write_message(answers, (True, "ready"))
    try:
        while True:
            try:
                work = read_message(requests)
            except EOFError:
                return  # the owner closed the channel or died
            except FramingError as exc:
                sys.exit(f"marker process {os.getpid()}: {exc}")  # the owner replaces it
            try:
                if work is None:
                    publisher.publish(delete_all_markers())
                    answer: tuple[bool, object] = True, 0
                else:
                    markers = draw(work)
                    if markers.markers:
                        publisher.publish(markers)
                    answer = True, len(work) if markers.markers else 0
            except MalformedBatch:
                answer = True, 0  # every grasp of it is INVALID_INPUT: none can be placed
            except Exception as exc:  # noqa: BLE001 - reported to the owner, process goes on
                answer = False, f"{type(exc).__name__}: {exc}"
            write_message(answers, answer)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    # Through the package's module, not __main__: the jobs the node pickles are
    # grasp_fc_ros.markers.publisher._Job, and draw() must recognise them.
    from grasp_fc_ros.markers.publisher import _serve as serve

    serve(*sys.argv[1:3])
    # The channel closed, the node and rclpy are shut down: skip the interpreter's
    # teardown (numba's and Fast DDS's objects), which took 0.5-1.5 s, beyond the
    # PROCESS_EXIT_TIMEOUT_S the node waits on a loaded machine (this process runs at
    # idle priority), after which it is killed.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
