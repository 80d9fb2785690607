"""The paper's torque-space filter: a necessary condition for force closure.

* :mod:`.torque_sets` -- the torque set of one friction cone: a fan, a plane or {0}
  (paper section IV-A);
* :mod:`.positive_span` -- do fans and planes positively span R^3? (section IV-B);
* :mod:`.torque_space_filter` -- the filter on a batch of grasps (section III);
* :mod:`.one_grasp_filter` -- the same filter on one grasp, compiled, for the one-grasp
  fast path.
"""
