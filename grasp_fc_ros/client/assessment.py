"""assess_robustness requests from numpy arrays, with their shapes checked (client side).

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

from grasp_fc_ros.client.batches import grasp_ranges
from grasp_fc_ros.interface.conversions import friction_or_default, grasp_to_contact_array
from grasp_fc_ros.interface.names import MAX_REQUEST_CONTACTS, MAX_REQUEST_SAMPLES
from grasp_fc_ros.packed import RobustnessQuery

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
    points = _grasps(positions, "positions")
    directions = _grasps(normals, "normals")
    if directions.shape != points.shape:
        raise ValueError(f"normals must have the shape of positions {points.shape}, got "
                         f"{directions.shape}")
    n_grasps, n_contacts = points.shape[:2]
    mus = _per_contact(friction_or_default(mu), "mu", (n_grasps, n_contacts))
    gammas = _per_contact(0.0 if torsional_friction is None else torsional_friction,
                          "torsional_friction", (n_grasps, n_contacts))
    grasp_ids = np.arange(n_grasps) if ids is None else np.asarray(ids)
    if grasp_ids.shape != (n_grasps,) or (n_grasps and not np.issubdtype(grasp_ids.dtype,
                                                                          np.integer)):
        raise ValueError(f"ids must be {n_grasps} integers (one per grasp), got shape "
                         f"{grasp_ids.shape} of {grasp_ids.dtype}")
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


def _grasps(values: ArrayLike, name: str) -> np.ndarray:
    """``values`` as float64 (N, n, 3); one grasp (n, 3) becomes a batch of one."""
    array = np.asarray(values, dtype=np.float64)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"{name} must have shape (N, n, 3) or (n, 3), got "
                         f"{np.shape(values)}")
    return array


def _per_contact(values: ArrayLike, name: str, shape: tuple[int, int]) -> np.ndarray:
    """A per-contact value (scalar, (N, 1), (N, n), or (n,) for one grasp) as (N, n)."""
    array = np.asarray(values, dtype=np.float64)
    try:
        return np.broadcast_to(array, shape)
    except ValueError:
        raise ValueError(f"{name} of shape {array.shape} does not broadcast to (grasps, "
                         f"contacts) = {shape} (one per grasp: shape (N, 1))") from None
