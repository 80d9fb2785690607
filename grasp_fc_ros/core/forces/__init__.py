"""Contact forces that hold a given load.

* :mod:`.grasp_forces` -- the least largest normal force that holds a given load;
* :mod:`.force_interior_point` -- its fast stage for hard contacts: a compiled
  interior-point method, every answer checked in numpy.
"""
