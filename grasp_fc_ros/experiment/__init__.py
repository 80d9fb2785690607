"""Reproduction of the seed paper's experiment (section V, Tables I and II).

Run it with the console script ``grasp-fc-experiment`` (see :mod:`.cli`). This
package imports scipy, matplotlib and trimesh; grasp_fc_ros.core never does.
"""
