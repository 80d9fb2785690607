"""The node's names and QoS profiles: what a client needs to talk to it, without it.

Topic, service and action names are relative: they resolve in the node's namespace
(``/robot/contacts`` for a node ``/robot/force_closure``). :func:`resolve` does that for
a client that knows the node's full name.
"""

from __future__ import annotations

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

NODE_NAME = "force_closure"

# Topics the node subscribes to.
CONTACTS_TOPIC = "contacts"
CONTACTS_BATCH_TOPIC = "contacts_batch"
# Topics the node publishes on: answers to queries without a client id (client_id 0)
# on these shared topics, answers to a client's queries on its reply topics
# (reply_topic()).
VERDICTS_TOPIC = "verdicts"
VERDICTS_BATCH_TOPIC = "verdicts_batch"
MARKERS_TOPIC = "markers"
DIAGNOSTICS_TOPIC = "/diagnostics"
# Services and the action.
CHECK_SERVICE = "check_force_closure"
CONTACT_FORCES_SERVICE = "compute_contact_forces"
CLEAR_MARKERS_SERVICE = "clear_markers"
ASSESS_SERVICE = "assess_robustness"
LABEL_ACTION = "label_grasps"

# The QoS clients use on all four grasp topics, and the node's query subscriptions.
# Reliable + KEEP_ALL: a reader never overwrites a sample it has not handed over, so a
# busy node makes the publisher wait instead of losing queries.
QUERY_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                       history=HistoryPolicy.KEEP_ALL, depth=1)
# The node's verdict publishers: reliable, and a deep KEEP_LAST history rather than
# KEEP_ALL, so that a client that stops reading (or was killed and is not yet known to
# be gone) can never make publish() block the node for everyone. A live client keeps
# at most its window (2,000) unanswered, far below this depth.
VERDICT_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST, depth=10_000)


def reply_topic(answers_topic: str, client_id: int) -> str:
    """The topic on which the node answers the queries carrying ``client_id``.

    ``answers_topic`` is :data:`VERDICTS_TOPIC` or :data:`VERDICTS_BATCH_TOPIC`; the
    reply topic is below it, named by the id in 16 hex digits
    (``verdicts/c00000000000000ff``; a name token may not start with a digit). Each
    client reads only its own answers, so other clients cost it nothing
    (docs/performance.md#reply-topics). Client id 0 ("no client id") is answered on
    ``answers_topic`` itself.
    """
    if client_id == 0:
        return answers_topic
    return f"{answers_topic}/c{client_id:016x}"


def resolve(node_name: str, name: str) -> str:
    """The absolute name of the node's topic, service or action ``name``.

    ``node_name`` is the node's name, with its namespace if it has one
    (``force_closure``, ``/robot/force_closure``); absolute names stay as they are.
    """
    if name.startswith("/"):
        return name
    namespace = node_name.rpartition("/")[0].strip("/")
    return f"/{namespace}/{name}" if namespace else f"/{name}"


# Most contacts a client puts in one ContactArrayBatch: GraspClient sends a larger batch
# as several messages (parts) of whole grasps, one after the other, and joins their
# answers. A part with every per-contact field (64 bytes a contact) stays under Fast
# DDS's default 512 KiB shared-memory segment: larger messages, or many sent at once,
# overflowed it, and a service request sent meanwhile from the same process was lost
# and repaired seconds later (tuned: docs/performance.md#big-batches).
MAX_MESSAGE_CONTACTS = 6_144

# Most contacts GraspClient puts in one check_force_closure request: a larger call goes
# as several requests of whole grasps, one after the other, so that other clients' calls
# are served between them. Half of MAX_MESSAGE_CONTACTS: the node's service thread
# takes a request as rclpy messages, which costs about 15 us a contact, and a call
# arriving meanwhile waits for the request being served; parts of MAX_MESSAGE_CONTACTS
# held such calls up twice as long, smaller ones slowed the big call down and held
# them up no less on a busy machine (tuned: docs/performance.md#big-service-calls).
MAX_REQUEST_CONTACTS = 3_072

# Most samples (grasps x samples per grasp) GraspClient asks for in one assess_robustness
# request: a larger call goes as several requests of whole grasps, one after the other,
# each well under the node's default max_assessment_samples (1,000,000) and a fraction of
# a second of the workers' time, so that other clients' requests are served between them.
MAX_REQUEST_SAMPLES = 250_000
