"""RViz markers of answered queries, built and published off the verdict path.

The node hands every answered message (a single-grasp query, a service request, a
batch) to :class:`MarkerPublisher` *after* its verdicts are out: :meth:`offer` only
appends a reference to a bounded queue. A thread of its own converts the message,
computes the separating wrench of the sampled rejected grasps with
``check_force_closure(..., certificates=True)``, builds the markers with
:func:`grasp_fc_ros.markers.grasp_markers` and publishes one
``visualization_msgs/MarkerArray`` per message. Building markers costs several times
a one-grasp core call, so when it falls behind the oldest queued marker work is
dropped (and counted), never a verdict.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from grasp_fc_msgs.msg import ContactArray, ContactArrayBatch, ForceClosureVerdictArray
from rclpy.publisher import Publisher
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

from grasp_fc_ros.conversions import MalformedBatch, batch_to_packed, contact_arrays_to_packed
from grasp_fc_ros.core import Status, check_force_closure
from grasp_fc_ros.evaluation import PackedGrasps
from grasp_fc_ros.markers import DEFAULT_LIFETIME_S, delete_all_markers, grasp_markers

# Messages whose markers may wait to be built; beyond, the oldest are dropped. A few
# seconds of work at most (a message holds at most MAX_MARKER_SAMPLE grasps).
MARKER_QUEUE_LENGTH = 64
# Upper bound of the marker_batch_sample parameter: one MarkerArray of 1,000 grasps is
# ~0.5 s of marker work and ~10 MB of message.
MAX_MARKER_SAMPLE = 1000
DEFAULT_MARKER_SAMPLE = 10
# The markers topic: reliable like RViz's MarkerArray display, a KEEP_LAST history so
# that a slow viewer never blocks the node.
MARKER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST, depth=100)
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
    """Friction coefficients as decided: finite values <= 0 replaced by ``default``."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(mu) & (mu <= 0), default, mu)


@dataclass
class _Job:
    """One answered message whose markers are still to be built.

    ``queries`` is either ContactArray messages (a single query or a service request;
    one per verdict) or one ContactArrayBatch; ``status`` and ``margin`` hold one
    verdict per grasp.
    """

    header: Header
    queries: Sequence[ContactArray] | ContactArrayBatch
    status: list[int]
    margin: list[float]
    default_mu: float
    settings: MarkerSettings
    limit: int  # at most this many of its grasps get markers

    def n_drawn(self) -> int:
        """How many grasps of this job get markers."""
        return min(len(self.status), self.limit)

    def grasps(self) -> tuple[PackedGrasps, np.ndarray]:
        """(the message's grasps, the indices of those that get markers)."""
        if isinstance(self.queries, ContactArrayBatch):
            packed = batch_to_packed(self.queries)
        else:
            packed = contact_arrays_to_packed(list(self.queries))
        return packed, sample_indices(len(packed), self.limit)


class MarkerPublisher:
    """A bounded queue of answered messages and the thread that draws them.

    Parameters
    ----------
    publisher : rclpy Publisher of visualization_msgs/MarkerArray
    on_error : callable(what, exception)
        Told about marker work that failed (it never reaches the verdict path).
    """

    def __init__(self, publisher: Publisher,
                 on_error: Callable[[str, Exception], None]) -> None:
        self._publisher = publisher
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
        for query, reply in zip(queries, replies):
            self._queue(_Job(header=query.header, queries=[query], status=[reply.status],
                             margin=[reply.margin], default_mu=default_mu,
                             settings=settings, limit=1))

    def offer_service(self, grasps: Sequence[ContactArray], replies: Sequence,
                      settings: MarkerSettings, default_mu: float) -> None:
        """Queue markers of at most ``batch_sample`` grasps of an answered service request.

        One MarkerArray for the request, in the frame of its first grasp's header.
        """
        if not grasps or settings.batch_sample == 0:
            return
        self._queue(_Job(header=grasps[0].header, queries=grasps,
                         status=[r.status for r in replies], margin=[r.margin for r in replies],
                         default_mu=default_mu, settings=settings,
                         limit=settings.batch_sample))

    def offer_batch(self, query: ContactArrayBatch, reply: ForceClosureVerdictArray,
                    settings: MarkerSettings, default_mu: float) -> None:
        """Queue markers of at most ``batch_sample`` grasps of an answered batch."""
        if not len(query.ids) or settings.batch_sample == 0:
            return
        self._queue(_Job(header=query.header, queries=query, status=list(reply.status),
                         margin=list(reply.margin), default_mu=default_mu,
                         settings=settings, limit=settings.batch_sample))

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
        """Stop the thread (queued marker work is discarded)."""
        with self._lock:
            self._closing = True
            self._lock.notify_all()
        self._thread.join()

    def _queue(self, job: _Job) -> None:
        with self._lock:
            if len(self._jobs) >= MARKER_QUEUE_LENGTH:
                # The oldest marker work goes (a requested DELETEALL stays).
                oldest = next(j for j in self._jobs if j is not None)
                self._jobs.remove(oldest)
                self.dropped += oldest.n_drawn()
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
                    self._publisher.publish(delete_all_markers())
                    continue
                markers = self._draw(job)
                if markers.markers:
                    self._publisher.publish(markers)
                    with self._lock:
                        self.published += job.n_drawn()
            except MalformedBatch:
                pass  # every grasp of it is INVALID_INPUT and none can be placed
            except Exception as exc:  # noqa: BLE001 - markers must never stop the node
                if self._closing:
                    return
                self._on_error("markers", exc)

    def _draw(self, job: _Job) -> MarkerArray:
        """All markers of one job's sampled grasps, in one MarkerArray."""
        packed, drawn = job.grasps()
        starts, counts = packed.starts, packed.counts
        mu = decided_mu(packed.mu, job.default_mu)
        wrenches = self._separating_wrenches(packed, mu, drawn, job.status)
        out = MarkerArray()
        for index in drawn.tolist():
            if self._closing:
                break
            lo, hi = int(starts[index]), int(starts[index] + counts[index])
            out.markers.extend(grasp_markers(
                packed.positions[lo:hi], packed.normals[lo:hi], mu[lo:hi],
                job.status[index], query_id=int(packed.ids[index]),
                frame_id=job.header.frame_id, stamp=job.header.stamp,
                margin=job.margin[index], separating_wrench=wrenches.get(index),
                lifetime_s=job.settings.lifetime_s).markers)
            # Hand the GIL over between grasps: the verdict path may be waiting for it.
            time.sleep(0)
        return out

    @staticmethod
    def _separating_wrenches(packed: PackedGrasps, mu: np.ndarray, drawn: np.ndarray,
                             status: list[int]) -> dict[int, np.ndarray]:
        """Separating wrench (6,) of each drawn rejected grasp that has one, by index.

        One certificate core call per contact count; the verdict is not recomputed (the
        published one colours the markers), only its wrench.
        """
        rejected = [i for i in drawn.tolist() if status[i] in _REJECTED]
        by_count: dict[int, list[int]] = {}
        for i in rejected:
            by_count.setdefault(int(packed.counts[i]), []).append(i)
        wrenches: dict[int, np.ndarray] = {}
        starts = packed.starts
        for count, indices in by_count.items():
            rows = (starts[indices][:, None] + np.arange(count)).reshape(-1)
            shape = (len(indices), count)
            result = check_force_closure(
                packed.positions[rows].reshape(*shape, 3), packed.normals[rows].reshape(*shape, 3),
                mu[rows].reshape(shape), margin="bound", certificates=True)
            for i, wrench, fc in zip(indices, result.separating_wrench, result.force_closure):
                if not fc and np.isfinite(wrench).all():
                    wrenches[i] = wrench
        return wrenches

