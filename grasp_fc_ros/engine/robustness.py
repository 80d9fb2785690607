"""The robustness of packed grasps, for the assess_robustness service (no ROS).

:func:`assess_group` runs the core's three robustness answers on validated same-size
grasps: the certified radii (:func:`~grasp_fc_ros.core.robustness`), whether the grasp
holds under the query's errors (:func:`~grasp_fc_ros.core.holds_under`, with its
witness) and the probability of force closure under its random errors
(:func:`~grasp_fc_ros.core.probability_of_force_closure`). :func:`.evaluation.evaluate`
calls it for each contact-count group of a request whose settings carry a
:class:`~grasp_fc_ros.packed.RobustnessQuery`, in the pool's worker processes like
epsilon and mu*.
"""

from __future__ import annotations

import numpy as np

from grasp_fc_ros.core import holds_under, probability_of_force_closure, robustness
from grasp_fc_ros.packed import Assessments, RobustnessQuery


def assess_group(positions: np.ndarray, normals: np.ndarray, mu: np.ndarray,
                 torsional: np.ndarray | None, query: RobustnessQuery,
                 stream_ids: np.ndarray) -> tuple[Assessments, list[str]]:
    """The robustness of validated same-size grasps.

    Parameters
    ----------
    positions, normals : (G, n, 3) float64
    mu : (G, n) float64
        Effective friction per contact (> 0).
    torsional : (G, n) float64 or None
        Torsional friction per contact (m); None: hard contacts.
    query : RobustnessQuery
    stream_ids : (G,) uint64
        The grasps' sample streams (their query ids: a grasp's probability does not
        depend on the request it came in, nor on its place there).

    Returns
    -------
    assessments : Assessments
        G rows (n contacts each); NaN (holds 0) for what could not be computed.
    problems : list of str
        What could not be computed and why, for the whole group ('' items omitted).
        Soft fingers have no radii and no holds answer (the core refuses them: the tilt
        lemma does not cover a torsional moment's turning axis); their probability is
        computed.
    """
    n_grasps, n_contacts = mu.shape
    rows = Assessments.not_computed(n_grasps, n_grasps * n_contacts)
    problems = []
    if torsional is None:
        radii = robustness(positions, normals, mu)
        rows.normal_angle[:] = radii.normal_angle
        rows.position_radius[:] = radii.position_radius
        rows.friction_drop[:] = radii.friction_drop
        held = holds_under(positions, normals, mu, position_error=query.position_error,
                           normal_error=query.normal_error,
                           friction_error=query.friction_error)
        rows.holds[:] = held.status
        rows.holds_bound[:] = held.bound
        rows.witness_positions[:] = held.witness_positions.reshape(-1, 3)
        rows.witness_normals[:] = held.witness_normals.reshape(-1, 3)
        rows.witness_friction[:] = held.witness_mu.reshape(-1)
        rows.separating_wrench[:] = held.separating_wrench
    else:
        problems.append("no radii and no holds answer for soft fingers (torsional "
                        "friction): the core's bounds cover hard contacts only")
    if query.samples:
        chance = probability_of_force_closure(
            positions, normals, mu, position_sigma=query.position_sigma,
            normal_sigma=query.normal_sigma, friction_sigma=query.friction_sigma,
            samples=query.samples, confidence=query.confidence, seed=query.seed,
            torsional_friction=0.0 if torsional is None else torsional,
            grasp_ids=stream_ids)
        rows.probability[:] = chance.estimate
        rows.probability_lower[:] = chance.lower
        rows.probability_upper[:] = chance.upper
        rows.probability_normal_bound[:] = chance.normal_lower_bound
    return rows, problems
