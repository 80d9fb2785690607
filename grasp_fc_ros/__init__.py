"""grasp_fc_ros: fast, exact force-closure tests for multi-finger frictional grasps.

The mathematics lives in :mod:`grasp_fc_ros.core`, which needs only numpy and
clarabel. Importing this package does not import rclpy; the ROS node lives in
:mod:`grasp_fc_ros.node`.
"""

__version__ = "0.1.0"
