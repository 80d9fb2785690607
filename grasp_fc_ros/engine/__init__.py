"""Deciding packed grasps, in worker processes and in chunks (ROS-free).

* :mod:`.evaluation` -- packed grasps in, verdicts out (the core on the node's layout);
* :mod:`.contact_forces` -- the forces that hold a load, for one packed grasp;
* :mod:`.chunking` -- how requests and long jobs are cut into chunks;
* :mod:`.pool` -- the pool of worker processes that decides the chunks of a request;
* :mod:`.worker_crew` -- the pool's worker processes, replaced when they die or hang;
* :mod:`.worker`, :mod:`.shared_chunk`, :mod:`.child_process` -- a worker process, the
  memory it shares with the pool, and the framing of their messages;
* :mod:`.long_jobs` -- a long job chunk by chunk, with progress and a prompt stop.

The data these modules pass (packed grasps, verdicts, settings) is in
:mod:`grasp_fc_ros.packed`, which clients import without this package.
"""
