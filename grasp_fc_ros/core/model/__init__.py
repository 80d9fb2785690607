"""The grasp as the core takes it: what a contact transmits, and checked input.

* :mod:`.contact_model` -- hard contacts and soft fingers (torsional friction): cones,
  wrench columns, depths and work, in one place;
* :mod:`.grasp_input` -- shapes, broadcasting and per-grasp validation.
"""
