"""assess_robustness requests from numpy arrays, with their shapes checked (client side).

:meth:`grasp_fc_ros.client.GraspClient.assess_robustness` asks the node how well grasps
hold when their contacts are off (docs/robustness.md)::

    from grasp_fc_ros.client import RobustnessQuery
    answer = client.assess_robustness(positions, normals, 0.5, RobustnessQuery(
        position_error=0.003, normal_error=np.radians(5), position_sigma=0.002,
        normal_sigma=np.radians(3), samples=1000))

Its arguments: ``positions``, ``normals`` (N, n, 3), or (n, 3) for one grasp; ``mu``
None (the node's ``friction_coefficient``), a scalar, (N, 1) or (N, n); the question, a
:class:`~grasp_fc_ros.packed.RobustnessQuery` (default :data:`ASK`: no errors, no
noise, 1,000 samples): ``position_error``, ``normal_error``, ``friction_error`` (m, rad,
unitless) for the holds answer, ``position_sigma``, ``normal_sigma``,
``friction_sigma`` for the probability, ``samples`` per grasp (0: no probability),
``confidence``, ``seed``; ``ids`` (N,) (default 0..N-1): grasp ``ids[k]`` draws its
samples from stream (``seed``, ``ids[k]``), so the answers do not depend on how the call
is split or ordered; ``torsional_friction`` (m): soft fingers get a probability but no
radii and no holds answer; ``frame_id``; ``timeout`` for the whole call (many grasps go
as several requests).

It returns the nominal :class:`~grasp_fc_ros.packed.Verdicts` (``margin`` NaN) with
``robustness``, an :class:`~grasp_fc_ros.packed.Assessments` of numpy arrays, one row
per grasp (the witness one per contact). Bad grasps are INVALID_INPUT alone, a refused
request INVALID_INPUT for every grasp, the message saying why. It raises ValueError on
mis-shaped input (naming the argument) before anything is sent, and TimeoutError if not
every response came within ``timeout``.

:func:`assessment_requests` turns grasps (N, n, 3) and the question's errors, sigmas and
samples into AssessRobustness requests of whole grasps: several where the grasps are
many (at most :data:`~grasp_fc_ros.interface.names.MAX_REQUEST_CONTACTS` contacts and
:data:`~grasp_fc_ros.interface.names.MAX_REQUEST_SAMPLES` samples each), so that each
stays under the node's limits and other clients' calls are served between them. A
grasp's samples come from the stream of its id, so the answers do not depend on how the
grasps were split.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
from grasp_fc_msgs.srv import AssessRobustness
from numpy.typing import ArrayLike

from grasp_fc_ros.client import shapes
from grasp_fc_ros.client.batches import grasp_ranges
from grasp_fc_ros.interface.conversions import friction_or_default, grasp_to_contact_array
from grasp_fc_ros.interface.names import MAX_REQUEST_CONTACTS, MAX_REQUEST_SAMPLES
from grasp_fc_ros.packed import RobustnessQuery

#: The default question: the request's defaults (no errors, no noise, 1,000 samples).
ASK = RobustnessQuery()
#: Largest ``samples`` the request's field holds (uint32).
MAX_SAMPLES = 2 ** 32 - 1


def assessment_requests(positions: ArrayLike, normals: ArrayLike, mu: ArrayLike | None,
                        torsional_friction: ArrayLike | None, ids: ArrayLike | None,
                        question: RobustnessQuery, frame_id: str) -> list[AssessRobustness.Request]:
    """The requests asking ``question`` of grasps (N, n, 3) (or one grasp (n, 3)).

    Raises
    ------
    ValueError
        On mis-shaped input, naming the argument and the shapes, or ``samples`` or
        ``seed`` outside their fields' ranges; before anything is sent.
    """
    if np.ndim(positions) == 2:                 # one grasp: a batch of one
        one = shapes.one_grasp(positions, normals)
        points, directions = one[0][None], one[1][None]
        mu, torsional_friction = _batch_of_one(mu), _batch_of_one(torsional_friction)
    else:
        points, directions, _ = shapes.grasp_batch(positions, normals, stacked=False)
    n_grasps, n_contacts = points.shape[:2]
    shapes.per_contact(mu, "mu", points)
    shapes.per_contact(torsional_friction, "torsional_friction", points)
    shapes.per_grasp(ids, "ids", n_grasps)
    grasp_ids = np.arange(n_grasps) if ids is None else np.asarray(ids)
    if n_grasps and not np.issubdtype(grasp_ids.dtype, np.integer):
        raise ValueError(f"ids must be integers, got {grasp_ids.dtype}")
    mus = np.broadcast_to(np.asarray(friction_or_default(mu), dtype=np.float64),
                          (n_grasps, n_contacts))
    gammas = np.broadcast_to(np.asarray(0.0 if torsional_friction is None
                                        else torsional_friction, dtype=np.float64),
                             (n_grasps, n_contacts))
    if not 0 <= question.samples <= MAX_SAMPLES:
        raise ValueError(f"samples must be in 0..{MAX_SAMPLES}, got {question.samples}")
    if not 0 <= question.seed < 2 ** 64:
        raise ValueError(f"seed must be in 0..2**64 - 1, got {question.seed}")
    grasps = [grasp_to_contact_array(int(i), p, n, m, torsional_friction=g)
              for i, p, n, m, g in zip(grasp_ids, points, directions, mus, gammas,
                                       strict=True)]
    for grasp in grasps:
        grasp.header.frame_id = frame_id
    per_part = max(1, min(MAX_REQUEST_CONTACTS // max(n_contacts, 1),
                          MAX_REQUEST_SAMPLES // max(question.samples, 1)))
    return [AssessRobustness.Request(grasps=grasps[first:last], **asdict(question))
            for first, last in grasp_ranges([1] * n_grasps, per_part)] or [
        AssessRobustness.Request(grasps=[], **asdict(question))]


def _batch_of_one(values: ArrayLike | None) -> ArrayLike | None:
    """A per-contact value of one grasp (None, a scalar or (n,)) as its batch of one's."""
    if values is None or np.ndim(values) == 0:
        return values
    return np.asarray(values, dtype=np.float64)[None]
