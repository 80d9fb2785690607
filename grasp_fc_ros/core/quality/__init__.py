"""How good a grasp is, each measure with certified bounds.

* :mod:`.epsilon` -- the Ferrari-Canny epsilon (Q1) with circular cones; its compiled
  search in :mod:`.epsilon_kernels`;
* :mod:`.minimum_friction` -- the least friction coefficient that makes a grasp force
  closure.
"""
