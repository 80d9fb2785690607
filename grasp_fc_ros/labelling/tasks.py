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

    from grasp_fc_ros.core.robustness import (
        ForceClosureProbability,
        HoldsUnder,
        RobustnessRadii,
    )

    from .robustness import Robustness


def validate_chunk(source: Source, start: int, stop: int,
                   hard_only: bool = False) -> str | None:
    """The first problem of rows ``start:stop`` of ``source``, or None if all can be labelled.

    With ``hard_only`` (``--robustness``, whose radii are for hard contacts), a soft finger
    (torsional friction > 0) is a problem too.

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
    if not validation.valid.all():
        g = int(np.argmin(validation.valid))
        # The core names the grasp by its index in this chunk; name it by its file row
        # and id.
        detail = validation.reasons[g].removeprefix(f"grasp {g}")
        return f"{where(g)}{detail}"
    if hard_only and chunk.torsional is not None:
        soft = np.broadcast_to(chunk.torsional, chunk.positions.shape[:2]) > 0.0
        if soft.any():
            g, c = (int(i) for i in np.argwhere(soft)[0])
            return (f"{where(g)}, contact {c}: a soft finger (torsional friction "
                    f"{np.broadcast_to(chunk.torsional, soft.shape)[g, c]:g}): the "
                    "robustness columns are for hard contacts (docs/robustness.md#limits)")
    return None


def _grasp_names(path: str, chunk: GraspChunk) -> Callable[[int], str]:
    return lambda g: f"{path}: grasp {int(chunk.rows[g])} (id {int(chunk.ids[g])})"


def _torsional(chunk: GraspChunk) -> np.ndarray | float:
    """The chunk's torsional friction gamma as the core takes it: 0.0 (every contact
    hard) where the input has none."""
    return 0.0 if chunk.torsional is None else chunk.torsional


def label_chunk(source: Source, start: int, stop: int, use_filter: bool | str, origins: str,
                quality_rtol: float | None = None,
                robustness: Robustness | None = None) -> pa.Table:
    """Labels of rows ``start:stop`` of ``source``, as a ``pyarrow.Table``; with
    ``quality_rtol``, their certified epsilon to that accuracy too; with ``robustness``,
    the robustness columns it asks for.

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
    if robustness is None:
        return label_table(chunk, result, source.object_name, epsilon)
    return label_table(chunk, result, source.object_name, epsilon,
                       *_robustness_results(chunk, robustness))


def _robustness_results(chunk: GraspChunk, settings: Robustness) -> tuple[
        RobustnessRadii, HoldsUnder | None, ForceClosureProbability | None]:
    """The chunk's radii, and its holds_under and probability where asked for."""
    from grasp_fc_ros.core.robustness import (
        holds_under,
        probability_of_force_closure,
        robustness,
    )

    grasp = (chunk.positions, chunk.normals, chunk.mu)
    radii = robustness(*grasp, torsional_friction=_torsional(chunk))
    holds = (holds_under(*grasp, position_error=settings.position_error,
                         normal_error=settings.normal_error,
                         friction_error=settings.friction_error)
             if settings.holds else None)
    probability = (probability_of_force_closure(
        *grasp, position_sigma=settings.position_sigma, normal_sigma=settings.normal_sigma,
        friction_sigma=settings.friction_sigma, samples=settings.samples,
        confidence=settings.confidence, seed=settings.seed,
        torsional_friction=_torsional(chunk), grasp_ids=chunk.ids)
        if settings.probability else None)
    return radii, holds, probability
