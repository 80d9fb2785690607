"""Lazy access to the arrays of a ``.npz`` file: shapes from the headers, rows on demand.

A ``.npz`` is a zip archive of ``.npy`` members. ``np.load`` reads a whole member at a
time; labelling reads a few rows at a time, so that memory stays bounded whatever the
file's size:

* a member stored uncompressed (``np.savez``) is memory-mapped at its offset in the archive;
* a deflated member (``np.savez_compressed``) is decompressed as a stream up to the rows
  asked for: memory stays bounded, but each read decompresses the member from its start,
  so reading a big compressed file chunk by chunk costs time quadratic in its size.
"""

from __future__ import annotations

import os
import struct
import zipfile
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

# Fixed part of a zip local file header: signature, versions, flags, method, times, CRC,
# sizes, then the lengths of the file name and the extra field (the data follows them).
_LOCAL_HEADER = struct.Struct("<4s5H3I2H")
_LOCAL_SIGNATURE = b"PK\x03\x04"


@dataclass(frozen=True)
class NpyMember:
    """One array of a ``.npz`` archive, described by its header; picklable and small.

    Attributes
    ----------
    path : str
        The archive.
    entry : str
        The zip entry, e.g. ``"positions.npy"``.
    shape : tuple of int
    dtype : numpy.dtype
    compressed : bool
        Deflated (``np.savez_compressed``) rather than stored.
    header_length : int
        Bytes of the ``.npy`` header inside the member (the array data follows it).
    data_offset : int
        For a stored member, the offset of the array data in the archive; else -1.
    """

    path: str
    entry: str
    shape: tuple[int, ...]
    dtype: np.dtype
    compressed: bool
    header_length: int
    data_offset: int

    @property
    def row_bytes(self) -> int:
        """Bytes of one row (one grasp) of the array."""
        return int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize

    def read(self, start: int | None = None, stop: int | None = None) -> np.ndarray:
        """Rows ``start:stop`` of the array (the whole of a 0-d array), as a new array."""
        if not self.shape:
            with zipfile.ZipFile(self.path) as archive, archive.open(self.entry) as member:
                member.seek(self.header_length)
                return np.frombuffer(member.read(self.dtype.itemsize), self.dtype)[0]
        start, stop, _ = slice(start, stop).indices(self.shape[0])
        stop = max(start, stop)
        if not self.compressed:
            mapped = np.memmap(self.path, dtype=self.dtype, mode="r",
                               offset=self.data_offset, shape=self.shape)
            return np.array(mapped[start:stop])
        with zipfile.ZipFile(self.path) as archive, archive.open(self.entry) as member:
            member.seek(self.header_length + start * self.row_bytes)
            data = member.read((stop - start) * self.row_bytes)
        return np.frombuffer(data, self.dtype).reshape((stop - start,) + self.shape[1:]).copy()


def read_members(path: str | os.PathLike[str]) -> dict[str, NpyMember]:
    """Describe every ``.npy`` member of a ``.npz`` archive, without reading its data.

    Returns
    -------
    dict
        Array name (the entry without ``.npy``) to :class:`NpyMember`.

    Raises
    ------
    ValueError
        Not a zip archive, a member that is not a valid ``.npy``, an object array, or an
        array stored in Fortran order.
    """
    path = str(path)
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise ValueError(f"{path}: not a .npz file (not a zip archive)") from None
    members = {}
    with archive, open(path, "rb") as raw:
        for info in archive.infolist():
            if not info.filename.endswith(".npy"):
                continue
            name = info.filename[:-len(".npy")]
            members[name] = _describe(path, archive, raw, info, name)
    return members


def _describe(path: str, archive: zipfile.ZipFile, raw: BinaryIO, info: zipfile.ZipInfo,
              name: str) -> NpyMember:
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise ValueError(f"{path}: array {name!r} uses an unsupported zip compression")
    with archive.open(info) as member:
        try:
            version = np.lib.format.read_magic(member)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran_order, dtype = read_header(member)
        except ValueError as error:
            raise ValueError(f"{path}: array {name!r} is not a valid .npy: {error}") from None
        header_length = member.tell()
    if dtype.hasobject:
        raise ValueError(f"{path}: array {name!r} holds Python objects; numbers expected")
    if fortran_order and len(shape) > 1:
        raise ValueError(f"{path}: array {name!r} is stored in Fortran order; save it "
                         "C-ordered (np.ascontiguousarray) to label it chunk by chunk")
    data_offset = -1
    if info.compress_type == zipfile.ZIP_STORED:
        raw.seek(info.header_offset)
        fields = _LOCAL_HEADER.unpack(raw.read(_LOCAL_HEADER.size))
        if fields[0] != _LOCAL_SIGNATURE:
            raise ValueError(f"{path}: corrupt zip header of array {name!r}")
        name_length, extra_length = fields[-2:]
        data_offset = (info.header_offset + _LOCAL_HEADER.size + name_length + extra_length
                       + header_length)
    return NpyMember(path, info.filename, tuple(shape), dtype,
                     info.compress_type == zipfile.ZIP_DEFLATED, header_length, data_offset)
