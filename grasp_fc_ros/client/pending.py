"""What the client has sent and not had answered yet, and when to send it again.

Every query a client registers stays until its answer comes, and is published again
when it has had none for :func:`resend_after` seconds, when its first publish failed
(no node, or one that has gone and not yet been noticed: rclpy raises ``RCLError``
"cannot publish data"), or when a node (re)appears (:mod:`.connection`). The node
answers a repeated query again, and the client resolves each future once, so a
re-send costs at most a duplicate answer, never a wrong one.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.publisher import Publisher

# A query unanswered for this long is sent again (s): far beyond the node's answer time
# under load (a single query waits behind at most every client's window), so that a
# re-send means its query or answer was lost, not that the node is slow.
# Tuned: docs/performance.md#reply-topics.
RESEND_AFTER_S = 10.0
# Added per grasp of a batch (s): a batch is answered once all of its grasps are
# decided, and may wait behind other batches; this allows for a node deciding 10,000
# grasps a second, well below this machine's rate.
RESEND_PER_GRASP_S = 1e-4


def resend_after(grasps: int, base_s: float = RESEND_AFTER_S) -> float:
    """Seconds without an answer after which a query of ``grasps`` grasps is resent."""
    return base_s + grasps * RESEND_PER_GRASP_S


@dataclass
class Pending:
    """A query sent (or to be sent) and not answered yet.

    Attributes
    ----------
    msg : Any
        The query: a message, or its serialized bytes.
    future : Future
        Resolved by its answer.
    due : float
        When to send it (again), ``time.monotonic()`` seconds: now when its publish
        failed.
    patience_s : float
        Seconds between sending it and sending it again (:func:`resend_after`).
    """

    msg: Any
    future: Future
    due: float
    patience_s: float

    @classmethod
    def new(cls, msg: Any, patience_s: float) -> Pending:
        """A query about to be published: due ``patience_s`` from now, so that a resend
        cannot overtake its first publish."""
        return cls(msg, Future(), time.monotonic() + patience_s, patience_s)


def publish(publisher: Publisher, pending: Pending) -> bool:
    """Publish a query and set when to resend it; False (and due at once) if rclpy could
    not publish it (``RCLError``: no node, or one that died)."""
    try:
        publisher.publish(pending.msg)
    except _rclpy.RCLError:
        pending.due = time.monotonic()
        return False
    pending.due = time.monotonic() + pending.patience_s
    return True


def publish_again(publisher: Publisher, pendings: list[Pending], everything: bool,
                  closed: Callable[[], bool]) -> list[Pending]:
    """Publish ``pendings`` again, all of them or those due now, until ``closed()`` (the
    client is closing and waits for the thread doing this); those published."""
    if not everything:
        now = time.monotonic()
        pendings = [p for p in pendings if p.due <= now]
    sent = []
    for pending in pendings:
        if closed():
            break
        publish(publisher, pending)
        sent.append(pending)
    return sent
