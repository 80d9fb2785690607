"""grasp_fc_ros: fast, exact force-closure tests for multi-finger frictional grasps.

Importing this package does not import rclpy. Its subpackages:

* :mod:`grasp_fc_ros.core` -- the mathematics (numpy, clarabel, numba; no ROS);
* :mod:`grasp_fc_ros.engine` -- packed grasps decided in worker processes, in chunks
  (no ROS);
* :mod:`grasp_fc_ros.interface` -- names, QoS and message conversions that the node and
  its clients share;
* :mod:`grasp_fc_ros.node` -- the ``force_closure`` node;
* :mod:`grasp_fc_ros.client` -- :class:`~grasp_fc_ros.client.GraspClient`, to talk to it;
* :mod:`grasp_fc_ros.markers` -- RViz markers: built, published, rendered;
* :mod:`grasp_fc_ros.labelling` -- datasets labelled on Dask;
* :mod:`grasp_fc_ros.experiment` -- the seed paper's experiment.
"""

__version__ = "1.1.0"
