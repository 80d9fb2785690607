"""Child processes that speak pickled messages on their stdin and stdout (no ROS).

The worker processes of :mod:`.pool` and the marker process of
:mod:`grasp_fc_ros.markers.publisher` are fresh interpreters (``python -m ...``), not
multiprocessing: its spawn and forkserver methods re-run the parent's ``__main__`` script
in every child (which breaks any unguarded script embedding the node), and fork would
copy the ROS process's DDS threads. Each message is a length prefix and a pickle.
"""

from __future__ import annotations

import pickle
import struct
from typing import IO, Any

# Environment of a child process: the processes are the parallelism, and a BLAS thread
# pool per process would oversubscribe the cores (OpenBLAS threads spin while waiting).
ONE_THREAD_ENV = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                      "MKL_NUM_THREADS")}


_HEADER = struct.Struct("<Q")  # length prefix of each pickled message


def write_message(stream: IO[bytes], obj: Any) -> None:
    """Send ``obj`` pickled, with its length first, and flush."""
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def read_message(stream: IO[bytes]) -> Any:
    """The next object :func:`write_message` sent on ``stream``.

    Raises
    ------
    EOFError
        If the stream ended (the other process closed it or died).
    """
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        raise EOFError("child process stream closed")
    (size,) = _HEADER.unpack(header)
    return pickle.loads(stream.read(size))
