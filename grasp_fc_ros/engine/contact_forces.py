"""Contact forces that hold a load, for one packed grasp (the compute_contact_forces
service), without ROS."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from grasp_fc_ros.core import optimal_contact_forces
from grasp_fc_ros.engine.evaluation import effective_friction, find_invalid
from grasp_fc_ros.packed import ContactForces, PackedGrasps, Settings

#: Names of the wrench's six components, for messages.
WRENCH_COMPONENTS = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")


def contact_forces_for_load(packed: PackedGrasps, wrench: ArrayLike,
                            max_normal_forces: ArrayLike, settings: Settings) -> ContactForces:
    """Least-largest-normal-force contact forces of one grasp holding a load.

    Parameters
    ----------
    packed : PackedGrasps
        Exactly one grasp of n contacts (friction 0: the default of ``settings``).
    wrench : (6,) float
        External load: force (N) then torque (N m) about the frame's origin.
    max_normal_forces : (0,) or (n,) float
        Per-contact normal-force limits (N, >= 0, inf: none); empty for no limits.
    settings : Settings

    Returns
    -------
    ContactForces
        From :func:`grasp_fc_ros.core.optimal_contact_forces`; an invalid request is
        refused with a message naming the query, and the contact where one is at fault.
    """
    if len(packed) != 1:
        raise ValueError(f"one grasp expected, got {len(packed)}")
    mu = effective_friction(packed.mu, settings.friction_coefficient)
    problems = find_invalid(packed, mu, settings)
    if problems:
        return ContactForces.refused(problems[0].describe(packed))
    label = packed.label(0)
    wrench = np.asarray(wrench, dtype=np.float64).reshape(6)
    bad = np.flatnonzero(~np.isfinite(wrench))
    if bad.size:
        return ContactForces.refused(
            f"{label}: wrench {WRENCH_COMPONENTS[bad[0]]} is not finite ({wrench[bad[0]]})")
    limits = np.asarray(max_normal_forces, dtype=np.float64).reshape(-1)
    n_contacts = int(packed.counts[0])
    if len(limits) not in (0, n_contacts):
        return ContactForces.refused(f"{label}: {len(limits)} max_normal_forces for "
                                     f"{n_contacts} contacts (need one per contact or none)")
    bad = np.flatnonzero(np.isnan(limits) | (limits < 0))
    if bad.size:
        return ContactForces.refused(
            f"{label}, contact {bad[0]}: max_normal_force must be >= 0 (inf: no limit), "
            f"got {limits[bad[0]]}")
    torsional = np.zeros(n_contacts) if packed.torsional is None else packed.torsional
    solution = optimal_contact_forces(
        packed.positions, packed.normals, mu, wrench, limits if len(limits) else None,
        torsional_friction=torsional)
    s_star = float(solution.max_normal_force)
    if math.isnan(s_star):
        return ContactForces.refused(f"{label}: the solver could not decide")
    if math.isinf(s_star):
        return ContactForces.infeasible(s_star)
    return ContactForces(True, s_star, solution.forces, solution.torques)
