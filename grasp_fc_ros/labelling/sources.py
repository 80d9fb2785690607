"""Where grasps come from: ``.npz`` files, Parquet files, or sampling on objects.

Every source is small and picklable: it holds where to read, not the data. The client
opens each input once to check its keys and shapes (:func:`open_input`); workers then read
one chunk at a time with :meth:`read`, so memory stays bounded by the chunk size.

Layouts
-------
``.npz``: ``positions`` (N, n, 3), ``normals`` (N, n, 3), ``mu`` scalar, (N,) or (N, n),
optional ``ids`` (N,) non-negative integers, optional ``torsional_friction`` (scalar, (N,)
or (N, n): gamma of soft-finger contacts, a length in the positions' unit; 0: hard).

Parquet: one row per grasp; ``positions`` and ``normals`` are list columns of 3n floats
(x, y, z per contact, contact after contact) or lists of n lists of 3; ``mu`` a float
column or a list column of n floats; optional ``ids`` (or ``id``, as written by
``grasp-fc-label --objects/--mesh``) an integer column; optional ``torsional_friction``.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from .npz_members import NpyMember, read_members

if TYPE_CHECKING:
    import pyarrow as pa

    from grasp_fc_ros.objects import ContactSurface

REQUIRED_KEYS = ("positions", "normals", "mu")
TORSIONAL_KEY = "torsional_friction"
# Rows a Parquet reader decodes at a time; bounds memory for row groups of any size.
PARQUET_BATCH_ROWS = 65_536


class InputError(ValueError):
    """Bad input: the message names the file and, where it can, the grasp and contact."""


@dataclass(frozen=True)
class GraspChunk:
    """The grasps of rows ``start:stop`` of a source, read on a worker.

    Attributes
    ----------
    ids : ndarray of uint64, shape (k,)
    positions, normals : ndarray of float64, shape (k, n, 3)
        Contact positions (the input's length unit) and inward normals.
    mu : ndarray of float64, shape () or (k, n)
        Friction coefficients.
    torsional : ndarray of float64 or None
        Torsional friction as given (broadcastable to (k, n)), None when absent.
    rows : ndarray of int64, shape (k,)
        Row of each grasp in its source, for error messages.
    """

    ids: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    torsional: np.ndarray | None
    rows: np.ndarray


def _file_stamp(path: str) -> dict[str, Any]:
    """What identifies a file's content for resumption: path, size, modification time."""
    stat = os.stat(path)
    return {"path": path, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def _default_ids(id_offset: int, start: int, stop: int) -> np.ndarray:
    return np.arange(id_offset + start, id_offset + stop, dtype=np.uint64)


def _checked_ids(ids: np.ndarray, path: str, key: str, start: int) -> np.ndarray:
    """Integer ids as uint64; a negative one is an error naming its grasp."""
    if ids.dtype.kind == "i" and ids.size and ids.min() < 0:
        row = int(np.argmax(ids < 0))
        raise InputError(f"{path}: grasp {start + row}: {key} is negative ({ids[row]})")
    return ids.astype(np.uint64)


def _per_grasp_slice(array_or_member: NpyMember, shape: tuple[int, ...], start: int,
                     stop: int) -> np.ndarray:
    """Rows start:stop of an array that is scalar, (N,) or (N, n), as () or (k, n) or (k, 1)."""
    if not shape:
        return np.asarray(array_or_member.read(), dtype=np.float64)
    values = np.asarray(array_or_member.read(start, stop), dtype=np.float64)
    return values[:, None] if len(shape) == 1 else values


@dataclass(frozen=True)
class NpzSource:
    """A ``.npz`` input. Build it with :func:`open_input`."""

    path: str
    n_grasps: int
    n_contacts: int
    id_offset: int
    members: dict[str, NpyMember] = field(repr=False)
    object_name = None  # grasps read from a file: no object, no grasp columns

    def describe(self) -> dict[str, Any]:
        return {"kind": "npz", **_file_stamp(self.path), "n_grasps": self.n_grasps}

    def read(self, start: int, stop: int) -> GraspChunk:
        m = self.members
        ids = (_checked_ids(m["ids"].read(start, stop), self.path, "ids", start) if "ids" in m
               else _default_ids(self.id_offset, start, stop))
        torsional = (_per_grasp_slice(m[TORSIONAL_KEY], m[TORSIONAL_KEY].shape, start, stop)
                     if TORSIONAL_KEY in m else None)
        return GraspChunk(
            ids=ids,
            positions=np.asarray(m["positions"].read(start, stop), dtype=np.float64),
            normals=np.asarray(m["normals"].read(start, stop), dtype=np.float64),
            mu=_per_grasp_slice(m["mu"], m["mu"].shape, start, stop),
            torsional=torsional,
            rows=np.arange(start, stop))


def _open_npz(path: str, id_offset: int) -> NpzSource:
    members = read_members(path)
    missing = [key for key in REQUIRED_KEYS if key not in members]
    if missing:
        raise InputError(f"{path}: missing array(s) {', '.join(missing)} "
                         f"(needs {', '.join(REQUIRED_KEYS)})")
    positions, normals = members["positions"], members["normals"]
    if len(positions.shape) != 3 or positions.shape[2] != 3:
        raise InputError(f"{path}: positions must have shape (N, n, 3), got {positions.shape}")
    if normals.shape != positions.shape:
        raise InputError(f"{path}: normals must have the shape of positions "
                         f"{positions.shape}, got {normals.shape}")
    n_grasps, n_contacts = positions.shape[:2]
    for key in ("positions", "normals", "mu", TORSIONAL_KEY):
        if key in members and members[key].dtype.kind not in "fiu":
            raise InputError(f"{path}: {key} must hold numbers, got dtype {members[key].dtype}")
    for key in ("mu", TORSIONAL_KEY):
        if key in members and members[key].shape not in ((), (n_grasps,),
                                                         (n_grasps, n_contacts)):
            raise InputError(f"{path}: {key} must be a scalar or have shape ({n_grasps},) or "
                             f"({n_grasps}, {n_contacts}), got {members[key].shape}")
    if "ids" in members:
        ids = members["ids"]
        if ids.shape != (n_grasps,) or ids.dtype.kind not in "iu":
            raise InputError(f"{path}: ids must be integers of shape ({n_grasps},), got "
                             f"{ids.dtype} {ids.shape}")
    return NpzSource(path, n_grasps, n_contacts, id_offset, members)


@dataclass(frozen=True)
class ParquetSource:
    """A Parquet input. Build it with :func:`open_input`."""

    path: str
    n_grasps: int
    n_contacts: int
    id_offset: int
    id_column: str | None
    has_torsional: bool
    object_name = None

    def describe(self) -> dict[str, Any]:
        return {"kind": "parquet", **_file_stamp(self.path), "n_grasps": self.n_grasps}

    def read(self, start: int, stop: int) -> GraspChunk:
        table = _read_parquet_rows(self.path, start, stop, self._columns())
        k = stop - start
        rows = np.arange(start, stop)
        n = self.n_contacts
        ids = (_integer_column(table[self.id_column], self.path, self.id_column, start)
               if self.id_column else _default_ids(self.id_offset, start, stop))
        mu = _per_grasp_column(table["mu"], k, n, self.path, "mu", start)
        torsional = (_per_grasp_column(table[TORSIONAL_KEY], k, n, self.path, TORSIONAL_KEY,
                                       start) if self.has_torsional else None)
        return GraspChunk(
            ids=ids,
            positions=_vector_column(table["positions"], k, n, self.path, "positions", start),
            normals=_vector_column(table["normals"], k, n, self.path, "normals", start),
            mu=mu, torsional=torsional, rows=rows)

    def _columns(self) -> list[str]:
        columns = list(REQUIRED_KEYS)
        if self.id_column:
            columns.append(self.id_column)
        if self.has_torsional:
            columns.append(TORSIONAL_KEY)
        return columns


def _read_parquet_rows(path: str, start: int, stop: int, columns: list[str]) -> pa.Table:
    """Rows start:stop of some columns, decoding one batch of a row group at a time."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    parquet = pq.ParquetFile(path)
    groups: list[int] = []
    offset, first = 0, 0
    for g in range(parquet.metadata.num_row_groups):
        rows = parquet.metadata.row_group(g).num_rows
        if offset + rows > start and offset < stop:
            first = offset if not groups else first
            groups.append(g)
        offset += rows
    batches, position = [], first
    for batch in parquet.iter_batches(batch_size=PARQUET_BATCH_ROWS, row_groups=groups,
                                      columns=columns):
        lo, hi = max(start - position, 0), min(stop - position, batch.num_rows)
        if hi > lo:
            batches.append(batch.slice(lo, hi - lo))
        position += batch.num_rows
        if position >= stop:
            break
    schema = pa.schema([parquet.schema_arrow.field(name) for name in columns])
    return pa.Table.from_batches(batches, schema=schema)


def _is_list(arrow_type: pa.DataType) -> bool:
    import pyarrow as pa

    return (pa.types.is_list(arrow_type) or pa.types.is_large_list(arrow_type)
            or pa.types.is_fixed_size_list(arrow_type))


def _combined(column: pa.ChunkedArray | pa.Array) -> pa.Array:
    import pyarrow as pa

    return column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column


def _check_lengths(lists: pa.Array, want: int, path: str, key: str, start: int,
                   rows_per_grasp: int = 1) -> None:
    """Raise naming the first grasp whose list is null or does not hold ``want`` items."""
    import pyarrow.compute as pc

    lengths = pc.list_value_length(lists).to_numpy(zero_copy_only=False)
    lengths = np.where(np.isnan(lengths.astype(np.float64)), -1, lengths).astype(np.int64)
    bad = np.flatnonzero(lengths != want)
    if bad.size:
        got = "no value" if lengths[bad[0]] < 0 else f"{lengths[bad[0]]} entries"
        raise InputError(f"{path}: grasp {start + int(bad[0]) // rows_per_grasp}: {key} has "
                         f"{got}, expected lists of {want}")


def _numbers(values: pa.Array, path: str, key: str) -> np.ndarray:
    import pyarrow as pa

    if not (pa.types.is_floating(values.type) or pa.types.is_integer(values.type)):
        raise InputError(f"{path}: {key} must hold numbers, got {values.type}")
    # Nulls become NaN here and are then reported by the grasp validation.
    return values.to_numpy(zero_copy_only=False).astype(np.float64)


def _vector_column(column: pa.ChunkedArray, k: int, n: int, path: str, key: str,
                   start: int) -> np.ndarray:
    """A positions/normals column -> (k, n, 3): 3n numbers per row, or n lists of 3."""
    lists = _combined(column)
    if not _is_list(lists.type):
        raise InputError(f"{path}: {key} must be a list column, got {lists.type}")
    inner_type = lists.type.value_type
    if _is_list(inner_type):
        _check_lengths(lists, n, path, key, start)
        inner = lists.flatten()
        _check_lengths(inner, 3, path, key, start, rows_per_grasp=n)
        flat = _numbers(inner.flatten(), path, key)
    else:
        _check_lengths(lists, 3 * n, path, key, start)
        flat = _numbers(lists.flatten(), path, key)
    return flat.reshape(k, n, 3)


def _per_grasp_column(column: pa.ChunkedArray, k: int, n: int, path: str, key: str,
                      start: int) -> np.ndarray:
    """A mu-like column -> (k, 1) for one number per grasp, (k, n) for a list of n."""
    values = _combined(column)
    if _is_list(values.type):
        _check_lengths(values, n, path, key, start)
        return _numbers(values.flatten(), path, key).reshape(k, n)
    return _numbers(values, path, key).reshape(k, 1)


def _integer_column(column: pa.ChunkedArray, path: str, key: str, start: int) -> np.ndarray:
    import pyarrow as pa

    values = _combined(column)
    if not pa.types.is_integer(values.type):
        raise InputError(f"{path}: {key} must be an integer column, got {values.type}")
    if values.null_count:
        row = int(np.flatnonzero(values.is_null().to_numpy(zero_copy_only=False))[0])
        raise InputError(f"{path}: grasp {start + row}: {key} has no value")
    return _checked_ids(values.to_numpy(), path, key, start)


def _open_parquet(path: str, id_offset: int) -> ParquetSource:
    import pyarrow.parquet as pq

    try:
        parquet = pq.ParquetFile(path)
    except Exception as error:  # pyarrow raises several types for a non-Parquet file
        raise InputError(f"{path}: not a readable Parquet file: {error}") from None
    names = parquet.schema_arrow.names
    missing = [key for key in REQUIRED_KEYS if key not in names]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)} "
                         f"(needs {', '.join(REQUIRED_KEYS)})")
    id_columns = [key for key in ("ids", "id") if key in names]
    if len(id_columns) > 1:
        raise InputError(f"{path}: has both an ids and an id column; keep one")
    n_grasps = parquet.metadata.num_rows
    n_contacts = 0
    if n_grasps:
        first = next(parquet.iter_batches(batch_size=1, columns=["positions"]))
        lists = first.column(0)
        if not _is_list(lists.type):
            raise InputError(f"{path}: positions must be a list column, got {lists.type}")
        length = len(lists[0].values) if lists[0].is_valid else 0
        n_contacts = length if _is_list(lists.type.value_type) else length // 3
        if n_contacts == 0 or (not _is_list(lists.type.value_type) and length % 3):
            raise InputError(f"{path}: grasp 0: positions must hold 3 numbers per contact, "
                             f"got {length}")
    return ParquetSource(path, n_grasps, n_contacts, id_offset,
                         id_columns[0] if id_columns else None, TORSIONAL_KEY in names)


@dataclass(frozen=True)
class SurfaceSource:
    """Random grasps on one object, drawn on the worker (as the experiment draws them).

    Block ``b`` (rows ``b * draw_block`` up to the next block) of object ``index`` is
    drawn from ``default_rng([seed, index, b])``: the grasps depend on the seed and the
    block size, never on the number of workers or on the chunks that read them.
    """

    surface: ContactSurface = field(repr=False)
    description: dict[str, Any] = field(default_factory=dict)
    index: int = 0
    n_grasps: int = 0
    n_contacts: int = 0
    mu: float = 0.0
    seed: int = 0
    id_offset: int = 0
    draw_block: int = 1

    @property
    def object_name(self) -> str:
        """The object's name: the output then holds the grasps too."""
        return self.surface.name

    @property
    def path(self) -> str:
        return str(self.description.get("path", self.surface.name))

    def describe(self) -> dict[str, Any]:
        return {**self.description, "n_grasps": self.n_grasps, "fingers": self.n_contacts,
                "mu": self.mu, "seed": self.seed}

    def read(self, start: int, stop: int) -> GraspChunk:
        """Rows ``start:stop``: the blocks they overlap are drawn whole, then cut."""
        from grasp_fc_ros.objects import sample_grasps

        first = start // self.draw_block
        blocks = range(first, max(first + 1, -(-stop // self.draw_block)))
        drawn = [sample_grasps(self.surface,
                               min(self.draw_block, self.n_grasps - b * self.draw_block),
                               self.n_contacts,
                               np.random.default_rng([self.seed, self.index, b]))
                 for b in blocks]
        rows = slice(start - first * self.draw_block, stop - first * self.draw_block)
        return GraspChunk(ids=_default_ids(self.id_offset, start, stop),
                          positions=np.concatenate([p for p, _ in drawn])[rows],
                          normals=np.concatenate([n for _, n in drawn])[rows],
                          mu=np.asarray(self.mu, dtype=np.float64),
                          torsional=None, rows=np.arange(start, stop))


def open_input(path: str | os.PathLike[str], id_offset: int = 0) -> Source:
    """Check an input file's keys and shapes and return its source.

    Parameters
    ----------
    path : str or pathlib.Path
        A ``.npz`` or ``.parquet`` file.
    id_offset : int
        Default id of its first grasp (used when it has no ids).

    Raises
    ------
    InputError
        Unknown suffix, unreadable file, missing keys or wrong shapes, naming the file.
    """
    resolved = str(Path(path).resolve())
    if not os.path.isfile(resolved):
        raise InputError(f"{resolved}: no such file")
    suffix = Path(resolved).suffix.lower()
    try:
        if suffix == ".npz":
            return _open_npz(resolved, id_offset)
        if suffix in (".parquet", ".pq"):
            return _open_parquet(resolved, id_offset)
    except InputError:
        raise
    except (OSError, ValueError) as error:
        raise InputError(str(error) if resolved in str(error)
                         else f"{resolved}: {error}") from None
    raise InputError(f"{resolved}: unsupported input (expected .npz or .parquet)")


#: Any source of grasps: each reads its chunks with ``read(start, stop)``.
Source: TypeAlias = NpzSource | ParquetSource | SurfaceSource


@functools.cache
def _builtin(name: str, points: int, seed: int) -> ContactSurface:
    from grasp_fc_ros.objects import make_object

    return make_object(name, n_points=points, seed=seed)


def object_sources(builtin_names: Sequence[str], mesh_paths: Sequence[str],
                   grasps_per_object: int, fingers: int, mu: float, seed: int, points: int,
                   draw_block: int, id_offset: int = 0) -> list[SurfaceSource]:
    """Sources of random grasps on built-in objects and on meshes/point clouds, drawn
    ``draw_block`` grasps per random stream (see :class:`SurfaceSource`).

    Raises
    ------
    InputError
        A mesh that cannot be loaded, or an object with fewer points than fingers.
    """
    from grasp_fc_ros.objects import load_surface

    surfaces = [(_builtin(name, points, seed), {"kind": "object", "name": name,
                                               "points": points})
                for name in builtin_names]
    for mesh in mesh_paths:
        path = str(Path(mesh).resolve())
        try:
            surface = load_surface(path, n_points=points, seed=seed)
        except (OSError, ValueError) as error:
            raise InputError(f"{path}: {error}") from None
        surfaces.append((surface, {"kind": "mesh", **_file_stamp(path), "points": points}))
    sources = []
    for index, (surface, description) in enumerate(surfaces):
        if len(surface) < fingers:
            raise InputError(f"{description.get('path', surface.name)}: {len(surface)} "
                             f"points, fewer than {fingers} fingers")
        sources.append(SurfaceSource(surface, description, index, grasps_per_object, fingers,
                                     mu, seed, id_offset, draw_block))
        id_offset += grasps_per_object
    return sources
