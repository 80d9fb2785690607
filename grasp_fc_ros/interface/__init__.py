"""What the node and its clients share: names, QoS and message conversions (rclpy).

* :mod:`.names` -- the node's name, every topic, service and action name, the QoS;
* :mod:`.conversions` -- grasp_fc_msgs messages to and from numpy arrays;
* :mod:`.wire` -- single queries, verdicts and batches straight from and to their CDR bytes;
* :mod:`.message_slots` -- the hot message types built without their constructors;
* :mod:`.wait_sets` -- services, service calls and busy subscriptions on bare rclpy
  wait sets instead of an executor.
"""
