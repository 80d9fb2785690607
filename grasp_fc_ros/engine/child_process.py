"""Child processes that speak framed, pickled messages on a channel of their own (no ROS).

The worker processes of :mod:`.pool` and the marker process of
:mod:`grasp_fc_ros.markers.publisher` are fresh interpreters (``python -m ...``), not
multiprocessing: its spawn and forkserver methods re-run the parent's ``__main__`` script
in every child (which breaks any unguarded script embedding the node), and fork would
copy the ROS process's DDS threads.

Their messages travel on two pipes of their own (:class:`ChildProcess`), not on the
child's stdin and stdout: a library in the child that prints (Fast DDS writes its XML
parser errors on file descriptor 1) cannot corrupt them, and what it prints goes to the
owner's own stdout, where a user sees it (issue 28: a Fast DDS error on the marker
process's stdout was read as a message length). The child's stdin is ``/dev/null``.

Each message is a header (:data:`MAGIC`, then the length of the pickle) and the pickle.
A stream that breaks this (wrong magic, a length above :data:`MAX_MESSAGE_BYTES`, a
pickle that does not load, a stream that ends inside a message) raises
:class:`FramingError` showing the bytes seen; the owner then replaces the child.
"""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
from collections.abc import Mapping, Sequence
from typing import IO, Any

# Environment of a child process: the processes are the parallelism, and a BLAS thread
# pool per process would oversubscribe the cores (OpenBLAS threads spin while waiting).
ONE_THREAD_ENV = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                      "MKL_NUM_THREADS")}
#: Names the child's ends of its channel, "READ_FD,WRITE_FD"; :func:`open_channel`
#: removes it, so that nothing the child starts inherits it.
CHANNEL_VARIABLE = "GRASP_FC_CHANNEL"

#: First bytes of every message's header: text a library printed is never taken for one.
MAGIC = b"GFC\x01"
_HEADER = struct.Struct("<4sQ")  # MAGIC, length of the pickle that follows
# A length above this is a broken stream, never an allocation. The largest message sent
# is a marker payload at the parameters' limits (1,000 grasps of 10,000 contacts, about
# 0.6 GB); the worker messages are a few MB (chunks of CHUNK_CONTACTS contacts).
MAX_MESSAGE_BYTES = 1 << 30
# How many bytes of a broken stream a FramingError shows, and how long it waits for
# those that follow the broken header (s): enough to read a line a library printed.
SHOWN_BYTES = 64
SHOWN_WAIT_S = 0.1


class FramingError(Exception):
    """The stream does not hold a message where one should be: wrong header, absurd
    length, a pickle that does not load, or an end inside a message."""


class MessageTooLarge(ValueError):
    """A message to send pickles to more than :data:`MAX_MESSAGE_BYTES`."""


def write_message(stream: IO[bytes], obj: Any) -> None:
    """Send ``obj`` pickled, after its header, and flush.

    Raises
    ------
    MessageTooLarge
        If the pickle is longer than :data:`MAX_MESSAGE_BYTES` (nothing is sent).
    """
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) > MAX_MESSAGE_BYTES:
        raise MessageTooLarge(f"a message of {len(data):,} bytes is more than the "
                              f"{MAX_MESSAGE_BYTES:,} a child process's channel takes")
    stream.write(_HEADER.pack(MAGIC, len(data)))
    stream.write(data)
    stream.flush()


def read_message(stream: IO[bytes]) -> Any:
    """The next object :func:`write_message` sent on ``stream``.

    Raises
    ------
    EOFError
        If the stream ended between messages (the other process closed it or died).
    FramingError
        If the stream holds something else than a message, or ends inside one.
    """
    header = _read_exactly(stream, _HEADER.size)
    if not header:
        raise EOFError("child process stream closed")
    if len(header) < _HEADER.size:
        raise FramingError(f"stream ended inside a message header: {bytes(header)!r}")
    magic, size = _HEADER.unpack(header)
    if magic != MAGIC:
        seen = bytes(header) + _following(stream, SHOWN_BYTES - len(header))
        raise FramingError(f"no message header where one should start: {seen!r}")
    if size > MAX_MESSAGE_BYTES:
        raise FramingError(f"message length {size:,} is above MAX_MESSAGE_BYTES "
                           f"({MAX_MESSAGE_BYTES:,}): header {bytes(header)!r}")
    data = _read_exactly(stream, size)
    if len(data) < size:
        raise FramingError(f"stream ended after {len(data):,} of a message's {size:,} bytes: "
                           f"{bytes(data[:SHOWN_BYTES])!r}")
    try:
        return pickle.loads(data)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a broken message
        raise FramingError(f"message of {size:,} bytes does not unpickle ({exc!r}): "
                           f"{bytes(data[:SHOWN_BYTES])!r}") from exc


def _read_exactly(stream: IO[bytes], size: int) -> bytes:
    """``size`` bytes of ``stream``, fewer only if it ends first (read into one buffer:
    a message of many MB is not copied piece by piece)."""
    buffer = bytearray(size)
    got = 0
    with memoryview(buffer) as view:
        while got < size:
            n = stream.readinto(view[got:])  # type: ignore[attr-defined]
            if not n:
                break
            got += n
    del buffer[got:]
    return buffer  # type: ignore[return-value]  # bytes-like: pickle.loads takes it


def _following(stream: IO[bytes], limit: int) -> bytes:
    """Up to ``limit`` more bytes of a broken stream, those that arrive within
    :data:`SHOWN_WAIT_S` (for the error message only)."""
    try:
        if limit <= 0 or not select.select([stream], [], [], SHOWN_WAIT_S)[0]:
            return b""
        return stream.read1(limit) if hasattr(stream, "read1") else stream.read(limit)
    except (OSError, ValueError):
        return b""


class ChildProcess:
    """A child process and the owner's ends of its channel.

    :meth:`start` runs ``command`` with two new pipes passed to it (their descriptors
    named in :data:`CHANNEL_VARIABLE`); the child opens them with :func:`open_channel`.
    Its stdin is ``/dev/null``; its stdout and stderr are the owner's.

    Attributes
    ----------
    process : subprocess.Popen
    to_child : binary stream
        Where the owner writes messages (:func:`write_message`).
    from_child : binary stream
        Where the owner reads the child's messages (:func:`read_message`).
    """

    def __init__(self, process: subprocess.Popen[bytes], to_child: IO[bytes],
                 from_child: IO[bytes]):
        self.process = process
        self.to_child = to_child
        self.from_child = from_child

    @classmethod
    def start(cls, command: Sequence[str], env: Mapping[str, str],
              pass_fds: Sequence[int] = ()) -> ChildProcess:
        """Run ``command`` with ``env`` (plus :data:`CHANNEL_VARIABLE`) and the channel.

        Raises
        ------
        OSError
            If the command cannot be run.
        """
        # os.pipe's descriptors are not inheritable: a child gets only those it is
        # passed, so another child started meanwhile cannot hold this one's pipes open.
        child_reads, owner_writes = os.pipe()
        owner_reads, child_writes = os.pipe()
        try:
            process = subprocess.Popen(
                list(command), stdin=subprocess.DEVNULL,
                pass_fds=(*pass_fds, child_reads, child_writes),
                env={**env, CHANNEL_VARIABLE: f"{child_reads},{child_writes}"})
        except BaseException:
            for fd in (owner_reads, owner_writes):
                os.close(fd)
            raise
        finally:
            for fd in (child_reads, child_writes):
                os.close(fd)
        return cls(process, os.fdopen(owner_writes, "wb"),
                   os.fdopen(owner_reads, "rb", buffering=0))

    @property
    def pid(self) -> int:
        return self.process.pid

    def poll(self) -> int | None:
        return self.process.poll()

    def close_channel(self) -> None:
        """Close the owner's ends: the child reads the end of its messages."""
        for stream in (self.to_child, self.from_child):
            try:
                stream.close()
            except OSError:
                pass  # a broken pipe's unflushed bytes: the child is gone anyway


def open_channel() -> tuple[IO[bytes], IO[bytes]]:
    """In a child process: the (requests, answers) streams of its channel, from
    :data:`CHANNEL_VARIABLE` (removed from the environment).

    Raises
    ------
    RuntimeError
        If the process was not started by :meth:`ChildProcess.start`.
    """
    spec = os.environ.pop(CHANNEL_VARIABLE, None)
    if spec is None:
        raise RuntimeError(f"no {CHANNEL_VARIABLE} in the environment: this process is "
                           "started by its owner (grasp_fc_ros.engine.child_process)")
    reads, writes = (int(fd) for fd in spec.split(","))
    return os.fdopen(reads, "rb", buffering=0), os.fdopen(writes, "wb")
