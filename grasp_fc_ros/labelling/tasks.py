"""What a Dask worker runs on one chunk: check it, or label it.

Both are pure functions of (source, start, stop): a chunk re-run after a worker died gives
the same rows, which is what makes retries and resumption lose and duplicate nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from .sources import GraspChunk, InputError, Source

if TYPE_CHECKING:
    import pyarrow as pa


def validate_chunk(source: Source, start: int, stop: int) -> str | None:
    """The first problem of rows ``start:stop`` of ``source``, or None if all can be labelled.

    Returns
    -------
    str or None
        ``"FILE: grasp ROW (id ID), contact C: what"``, with ROW the grasp's row in its file.
    """
    from grasp_fc_ros.core import validate_grasps

    try:
        chunk = source.read(start, stop)
    except InputError as error:
        return str(error)
    where = _grasp_names(source.path, chunk)
    validation = validate_grasps(chunk.positions, chunk.normals, chunk.mu,
                                 _torsional(chunk))
    if validation.valid.all():
        return None
    g = int(np.argmin(validation.valid))
    # The core names the grasp by its index in this chunk; name it by its file row and id.
    detail = validation.reasons[g].removeprefix(f"grasp {g}")
    return f"{where(g)}{detail}"


def _grasp_names(path: str, chunk: GraspChunk) -> Callable[[int], str]:
    return lambda g: f"{path}: grasp {int(chunk.rows[g])} (id {int(chunk.ids[g])})"


def _torsional(chunk: GraspChunk) -> np.ndarray | float:
    """The chunk's torsional friction gamma as the core takes it: 0.0 (every contact
    hard) where the input has none."""
    return 0.0 if chunk.torsional is None else chunk.torsional


def label_chunk(source: Source, start: int, stop: int, use_filter: bool | str, origins: str,
                quality_rtol: float | None = None) -> pa.Table:
    """Labels of rows ``start:stop`` of ``source``, as a ``pyarrow.Table``; with
    ``quality_rtol``, their certified epsilon to that accuracy too.

    See :mod:`grasp_fc_ros.labelling.schema` for the columns.
    """
    from grasp_fc_ros.core import check_force_closure, epsilon_quality

    from .schema import label_table

    chunk = source.read(start, stop)
    torsional = _torsional(chunk)
    result = check_force_closure(chunk.positions, chunk.normals, chunk.mu,
                                 use_filter=use_filter, origins=origins,
                                 torsional_friction=torsional)
    epsilon = (None if quality_rtol is None else
               epsilon_quality(chunk.positions, chunk.normals, chunk.mu, rtol=quality_rtol,
                               torsional_friction=torsional))
    return label_table(chunk, result, source.object_name, epsilon)
