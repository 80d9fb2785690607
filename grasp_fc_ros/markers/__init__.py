"""RViz markers of answered queries.

* :mod:`.build` -- the MarkerArray of one answered grasp (geometry in numpy);
* :mod:`.publisher` -- built and published off the verdict path, by a process of its own;
* :mod:`.render` -- MarkerArrays drawn to a PNG with matplotlib (no RViz needed).
"""
