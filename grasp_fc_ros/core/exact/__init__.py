"""The exact force-closure test, a second-order cone program, and its certificates.

* :mod:`.exact_test` -- the SOCP: the fast stage, then Clarabel for what it cannot
  certify;
* :mod:`.interior_point` -- the fast stage: a compiled interior-point method in the
  6-vector wrench, deciding each grasp from certificates;
* :mod:`.certificates` -- internal forces and bounding wrenches, checked in numpy;
* :mod:`.stacked_socp` -- many same-shape SOCPs in one Clarabel solve (also for grasp
  forces and minimum friction).
"""
