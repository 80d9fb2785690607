"""A chunk's arrays in memory shared between the pool's owner and one worker (no ROS)."""

from __future__ import annotations

import mmap
import os
import tempfile

import numpy as np

from grasp_fc_ros.packed import PackedGrasps

# Bytes of the memory each worker shares with its owner for the chunks' arrays: a chunk
# of CHUNK_CONTACTS hard contacts takes 16 * grasps + 56 * contacts bytes, at most
# 1,048,576 (two-contact grasps); 2 MiB leave room, and pages never written cost nothing.
# Shared, a chunk costs the pool's owner and the workers less CPU than pickled through
# the pipes (tuned: docs/performance.md#worker-pool). A chunk that does not fit (huge
# grasps, thousands of empty ones) still goes through the pipe.
SHARED_BYTES = 2 << 20


class SharedChunk:
    """A chunk's arrays in memory shared between the node and one worker process.

    The owner :meth:`put` s a chunk's arrays into it and sends the worker only their
    sizes; the worker :meth:`get` s a :class:`PackedGrasps` of views into the same
    memory. One message at a time: the owner writes the next one only once the worker
    answered the last; a message of several chunks puts each after the one before
    (``at``).
    """

    def __init__(self, fd: int):
        self.fd = fd
        self.memory = mmap.mmap(fd, 0)  # the whole file

    @classmethod
    def create(cls, size: int | None = None) -> SharedChunk:
        """A new block of ``size`` bytes (default :data:`SHARED_BYTES`), backed by an
        anonymous memory file (Linux; elsewhere a temporary file)."""
        if hasattr(os, "memfd_create"):
            fd = os.memfd_create("grasp_fc_chunk")
        else:
            with tempfile.TemporaryFile() as backing:
                fd = os.dup(backing.fileno())
        os.ftruncate(fd, SHARED_BYTES if size is None else size)
        return cls(fd)

    def close(self) -> None:
        self.memory.close()
        os.close(self.fd)

    def put(self, chunk: PackedGrasps, at: int = 0) -> tuple | None:
        """Copy ``chunk``'s arrays in from byte ``at`` on; what :meth:`get` needs to read
        them back, or None if they do not fit (the chunk then goes through the pipe).
        The chunk ends at byte ``at + shared_bytes(chunk)``."""
        layout = (len(chunk), len(chunk.mu), chunk.torsional is not None, chunk.name_by_id,
                  chunk.first_index, at)
        if at + shared_bytes(chunk) > len(self.memory):
            return None
        for name, dtype, count in _shared_fields(*layout[:3]):
            target = np.frombuffer(self.memory, dtype, count, at)
            target[:] = np.reshape(getattr(chunk, name), -1)
            at += target.nbytes
        return layout

    def get(self, layout: tuple) -> PackedGrasps:
        """The chunk that :meth:`put` returned ``layout`` for, as views of the memory."""
        n_grasps, n_contacts, soft, name_by_id, first_index, at = layout
        arrays = {}
        for name, dtype, count in _shared_fields(n_grasps, n_contacts, soft):
            arrays[name] = np.frombuffer(self.memory, dtype, count, at)
            at += arrays[name].nbytes
        return PackedGrasps(ids=arrays["ids"], counts=arrays["counts"],
                            positions=arrays["positions"].reshape(-1, 3),
                            normals=arrays["normals"].reshape(-1, 3), mu=arrays["mu"],
                            name_by_id=name_by_id, first_index=first_index,
                            torsional=arrays.get("torsional"))


def shared_bytes(chunk: PackedGrasps) -> int:
    """Bytes ``chunk``'s arrays take in the shared memory."""
    return sum(np.dtype(dtype).itemsize * count for _, dtype, count in
               _shared_fields(len(chunk), len(chunk.mu), chunk.torsional is not None))


def _shared_fields(n_grasps: int, n_contacts: int, soft: bool) -> list[tuple]:
    """(PackedGrasps field, dtype, values) of a chunk's arrays, in their order in the
    shared memory: 16 bytes per grasp, 56 per contact (64 with torsional friction)."""
    fields = [("ids", np.uint64, n_grasps), ("counts", np.int64, n_grasps),
              ("positions", np.float64, 3 * n_contacts),
              ("normals", np.float64, 3 * n_contacts), ("mu", np.float64, n_contacts)]
    return fields + [("torsional", np.float64, n_contacts)] if soft else fields


# How a chunk reaches a worker: its arrays in the shared memory, or pickled whole.
SHARED = "shared"
PICKLED = "pickled"
