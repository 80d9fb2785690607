"""The client's side of the ``label_grasps`` action: a long job with a progress bar,
Ctrl-C cancelling it.

A job goes to the node as goals of at most
:data:`~grasp_fc_ros.interface.names.MAX_MESSAGE_CONTACTS` contacts
(:class:`~grasp_fc_ros.client.label_job.LabelJob`), presented to the caller as one.
A job whose node was killed goes on when a node is back (its unfinished goals are sent
again); one whose node stays away for :data:`NODE_RETURN_WAIT_S` ends with
:class:`NodeGoneError`, which carries the verdicts decided before.
"""

from __future__ import annotations

import time

import numpy as np
from action_msgs.msg import GoalStatus
from grasp_fc_msgs.action import LabelGrasps
from rclpy.action import ActionClient
from rclpy.node import Node
from tqdm import tqdm

from grasp_fc_ros.client.batches import split_batch
from grasp_fc_ros.client.connection import ActionServerWatch
from grasp_fc_ros.client.label_job import JobProgress, LabelJob
from grasp_fc_ros.interface.conversions import BatchArrays, batch_msg
from grasp_fc_ros.interface.names import LABEL_ACTION, MAX_MESSAGE_CONTACTS, resolve
from grasp_fc_ros.packed import Verdicts

# How long label_grasps looks for the action server when it has no timeout (s).
DEFAULT_SERVER_WAIT_S = 60.0
# How long a label_grasps job waits for its node to come back once no action server is
# left in the ROS graph (s): a SIGKILLed node leaves it when its DDS lease ends (Fast
# DDS: 20 s), so a job whose node never returns ends about 80 s after the kill, with
# NodeGoneError. A node restarted within this time gets the unfinished goals again.
NODE_RETURN_WAIT_S = 60.0
# How often label_grasps redraws its progress bar and looks at its deadline (s).
PROGRESS_POLL_S = 0.1
# How long label_grasps waits for the decided prefix after it cancelled its goal (s):
# the node ends a canceled goal within ~0.1 s.
CANCEL_WAIT_S = 10.0


class NodeGoneError(ConnectionError):
    """A label_grasps job's node went away and did not come back within
    :data:`NODE_RETURN_WAIT_S`.

    Attributes
    ----------
    verdicts : Verdicts
        The job's verdicts decided before, in order: a prefix of its grasps (the parts
        that ended before the first unfinished one).
    total : int
        Grasps in the job.
    """

    def __init__(self, verdicts: Verdicts, total: int, gone_s: float):
        super().__init__(
            f"the node went away: no {LABEL_ACTION} action server in the ROS graph for "
            f"{gone_s:.0f} s; {len(verdicts)} of {total} grasps were decided (this "
            "error's verdicts)")
        self.verdicts = verdicts
        self.total = total


class LabelActionClient:
    """Send label_grasps goals and follow them to their end.

    Parameters
    ----------
    node : Node
        The client's node, spun by an executor on another thread.
    node_name : str
        The force_closure node's full name.

    Attributes
    ----------
    action_client : rclpy.action.ActionClient
    last_goal_status : int
        ``action_msgs/GoalStatus`` code of the last goal (STATUS_UNKNOWN before any).
    """

    def __init__(self, node: Node, node_name: str):
        self._node = node
        self.action_name = resolve(node_name, LABEL_ACTION)
        self.action_client = ActionClient(node, LabelGrasps, self.action_name)
        self.last_goal_status = GoalStatus.STATUS_UNKNOWN
        self._last_job: LabelJob | None = None

    @property
    def last_job_resent(self) -> int:
        """Goals of the last job sent again (its node restarted, or a goal request went
        unanswered)."""
        return 0 if self._last_job is None else self._last_job.resent

    @property
    def last_job_progress(self) -> JobProgress | None:
        """How far the last job is (None before any); another thread may read it."""
        return None if self._last_job is None else self._last_job.progress()

    def label(self, fields: BatchArrays, progress: bool, timeout: float | None,
              client_id: int = 0) -> Verdicts:
        """Send the grasps ``fields`` as one job, in goals of whole grasps of at most
        MAX_MESSAGE_CONTACTS contacts, and wait for its verdicts (see
        :meth:`grasp_fc_ros.client.GraspClient.label_grasps`)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        wait_s = (DEFAULT_SERVER_WAIT_S if deadline is None
                  else max(deadline - time.monotonic(), 0))
        if not self.action_client.wait_for_server(timeout_sec=wait_s):
            raise TimeoutError(f"no label_grasps action server within {wait_s:.1f} s "
                               f"({self.action_name}): is the node up?")
        stamp = self._node.get_clock().now().to_msg()
        parts = []
        for part in split_batch(fields, MAX_MESSAGE_CONTACTS):
            parts.append(batch_msg(part, client_id=client_id))
            parts[-1].header.stamp = stamp
        job = self._last_job = LabelJob(self._node, self.action_client, parts,
                                        ActionServerWatch(self._node, self.action_name))
        started = time.monotonic()
        with tqdm(total=job.total, unit="grasp", disable=not progress,
                  dynamic_ncols=True, desc=LABEL_ACTION) as bar:
            try:
                follow_job(job, bar, started, deadline)
            except NodeGoneError:
                self.last_goal_status = GoalStatus.STATUS_ABORTED
                raise
            except KeyboardInterrupt:
                job.cancel()
                if not finish(job, time.monotonic() + CANCEL_WAIT_S):
                    raise
            if job.rejected_part == 0:
                raise RuntimeError("the node rejected the label_grasps goal (shutting down?)")
            verdicts = job.verdicts()
            # The last feedback may predate the end (a short goal may have none after its
            # first), and a cancelled job drops what its later parts decided: the bar
            # ends on the verdicts themselves.
            show_progress(bar, JobProgress(len(verdicts), job.total, int(
                np.count_nonzero(verdicts.force_closure))), started)
        self.last_goal_status = job.status()
        return verdicts


def follow_job(job: LabelJob, bar: tqdm, started: float, deadline: float | None) -> None:
    """Run ``job`` to its end, showing its progress; cancel it at ``deadline``; end it
    with :class:`NodeGoneError` once no server was there for NODE_RETURN_WAIT_S."""
    while not job.ended():
        job.step(PROGRESS_POLL_S)
        show_progress(bar, job.progress(), started)
        if deadline is not None and time.monotonic() > deadline:
            job.cancel()
            raise TimeoutError("label_grasps goal not done within its timeout (cancelled)")
        if (gone_s := job.gone_for()) > NODE_RETURN_WAIT_S:
            job.cancel()
            raise NodeGoneError(job.verdicts(), job.total, gone_s)


def finish(job: LabelJob, deadline: float) -> bool:
    """Follow a cancelled ``job`` until its parts in flight ended; whether they did
    before ``deadline``."""
    while not job.ended():
        if time.monotonic() > deadline:
            return False
        job.step(PROGRESS_POLL_S)
    return True


def show_progress(bar: tqdm, progress: JobProgress, started: float) -> None:
    """Move a tqdm ``bar`` to a job's ``progress``, with its rate since ``started``."""
    rate = progress.done / max(time.monotonic() - started, 1e-9)
    bar.set_postfix(force_closure=progress.force_closure, rate=f"{rate:.0f}/s",
                    refresh=False)
    bar.update(progress.done - bar.n)
