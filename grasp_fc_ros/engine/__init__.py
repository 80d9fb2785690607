"""Deciding packed grasps, in worker processes and in chunks (ROS-free).

* :mod:`.evaluation` -- packed grasps in, verdicts out (the core on the node's layout);
* :mod:`.workers` -- the pool of worker processes that decide chunks of a request;
* :mod:`.long_jobs` -- a long job chunk by chunk, with progress and a prompt stop.

Importing this package imports none of them: a client that needs only the data types
of :mod:`.evaluation` does not start or load the pool.
"""
