"""Label many grasps as force closure or not, in chunks on Dask, into Parquet (ROS-free).

* :mod:`.sources` -- inputs (``.npz``, Parquet, grasps drawn on objects), read by chunk;
* :mod:`.npz_members` -- rows of a ``.npz`` member without loading the whole array;
* :mod:`.tasks` -- what a worker runs on one chunk: check it, label it;
* :mod:`.schema` -- the output columns;
* :mod:`.output` -- parts on disk, atomic writes, resumption, the single-file merge;
* :mod:`.runner` -- the Dask side: plan the chunks, run them, stream the parts to disk;
* :mod:`.cli` -- the console script ``grasp-fc-label``.

Example
-------
>>> from grasp_fc_ros.labelling import Plan, dask_client, open_input, run
>>> plan = Plan([open_input("grasps.npz")], chunk_size=50_000)      # doctest: +SKIP
>>> with dask_client(workers=2) as client:                          # doctest: +SKIP
...     summary = run(plan, "labels/", client)
"""

from .output import OutputConflict
from .runner import DEFAULT_CHUNK_SIZE, Plan, Summary, TaskFailed, dask_client, run
from .sources import InputError, object_sources, open_input

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "InputError",
    "OutputConflict",
    "Plan",
    "Summary",
    "TaskFailed",
    "dask_client",
    "object_sources",
    "open_input",
    "run",
]
