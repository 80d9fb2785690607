"""The output on disk: a directory of Parquet parts, one per chunk, or one Parquet file.

Each part is written to a hidden temporary file and renamed into place, so a part that
exists is complete; a re-run with the same manifest (inputs, chunking, settings) skips the
parts already there. ``OUT`` ending in ``.parquet`` is one file: the parts go to
``OUT.parts/`` first and are merged in chunk order at the end (one row group per part),
then removed; the merged file carries the manifest in its schema metadata.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow.parquet as pq

if TYPE_CHECKING:
    import pyarrow as pa

MANIFEST_NAME = "_grasp_fc_label.json"
METADATA_KEY = b"grasp_fc_label"
# Readers of the directory (pyarrow, pandas, Spark) skip names starting with "_" or ".".
TEMP_PREFIX = "."


class OutputConflict(Exception):
    """The output path holds something this run must not overwrite or mix with.

    Attributes
    ----------
    differing : tuple of str
        Where the output holds another run: the keys of the manifest (settings,
        ``sources``; inside a nested setting, ``robustness.samples``) in which that run
        differs from this one; else empty.
    """

    def __init__(self, message: str, differing: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.differing = differing


def _manifest_difference(stored: dict[str, Any], wanted: dict[str, Any],
                         prefix: str = "") -> tuple[str, ...]:
    """The keys whose values differ; inside entries that are dicts on both sides, their
    keys (``robustness.samples``)."""
    keys: list[str] = []
    for key in sorted(set(stored) | set(wanted)):
        old, new = stored.get(key), wanted.get(key)
        if isinstance(old, dict) and isinstance(new, dict):
            keys += _manifest_difference(old, new, f"{prefix}{key}.")
        elif old != new:
            keys.append(prefix + key)
    return tuple(keys) or (() if prefix else ("layout",))


class Output:
    """Where one run's parts go.

    Parameters
    ----------
    out : str or pathlib.Path
        A directory, or a file name ending in ``.parquet``.
    manifest : dict
        JSON-serialisable description of the run (inputs with sizes and modification
        times, chunk size, settings); parts are reused only under the same manifest.
    """

    def __init__(self, out: str | os.PathLike[str], manifest: dict[str, Any]) -> None:
        self.out = Path(out).resolve()
        self.single_file = self.out.suffix.lower() == ".parquet"
        self.parts_dir = (self.out.with_name(self.out.name + ".parts") if self.single_file
                          else self.out)
        self.manifest = manifest
        self.text = json.dumps(manifest, sort_keys=True, indent=1)

    def existing_parts(self) -> set[str] | None:
        """Names of the parts already written; None if the single output file is complete.

        Touches nothing. Raises :class:`OutputConflict` if the output belongs to another
        run or is not a labelling output.
        """
        if self.single_file and self.out.exists():
            try:
                metadata = pq.read_schema(self.out).metadata or {}
            except (OSError, ValueError):  # pyarrow's ArrowInvalid is a ValueError
                raise OutputConflict(f"{self.out} exists and is not a Parquet file") from None
            stored = metadata.get(METADATA_KEY)
            if stored is None or json.loads(stored) != self.manifest:
                differing = () if stored is None else _manifest_difference(
                    json.loads(stored), self.manifest)
                raise OutputConflict(
                    f"{self.out} already exists and holds another run's labels; remove it "
                    "or choose another --out", differing)
            return None
        if not self.parts_dir.exists():
            return set()
        if not self.parts_dir.is_dir():
            raise OutputConflict(f"{self.parts_dir} exists and is not a directory")
        manifest_path = self.parts_dir / MANIFEST_NAME
        if not manifest_path.exists():
            if any(self.parts_dir.iterdir()):
                raise OutputConflict(f"{self.parts_dir} exists, is not empty and is not a "
                                     "grasp-fc-label output")
            return set()
        stored = json.loads(manifest_path.read_text())
        if stored != self.manifest:
            differing = _manifest_difference(stored, self.manifest)
            raise OutputConflict(
                f"{self.parts_dir} holds a run with other inputs or settings (differs in: "
                f"{', '.join(differing)}); remove it or choose another --out", differing)
        return {path.name for path in self.parts_dir.glob("part-*.parquet")}

    def create(self) -> None:
        """Make the parts directory with its manifest; drop temporaries of killed runs."""
        self.parts_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.parts_dir.glob(TEMP_PREFIX + "*.tmp"):
            stale.unlink()
        manifest_path = self.parts_dir / MANIFEST_NAME
        if not manifest_path.exists():
            _atomic_write(manifest_path, lambda tmp: tmp.write_text(self.text))

    def write_part(self, name: str, table: pa.Table) -> None:
        """Write one chunk's table as part ``name``, atomically."""
        _atomic_write(self.parts_dir / name, lambda tmp: pq.write_table(table, tmp))

    def discard_parts(self) -> None:
        """Remove the parts directory of a single output file already merged."""
        if self.single_file and self.parts_dir.is_dir():
            shutil.rmtree(self.parts_dir)

    def finish(self, part_names: list[str], schema: pa.Schema) -> Path:
        """Merge the parts into the single output file if asked for one; return the output."""
        if not self.single_file:
            return self.out
        schema = schema.with_metadata({METADATA_KEY: self.text.encode()})

        def merge(tmp: Path) -> None:
            with pq.ParquetWriter(tmp, schema) as writer:
                for name in part_names:
                    writer.write_table(pq.read_table(self.parts_dir / name).cast(schema))

        _atomic_write(self.out, merge)
        shutil.rmtree(self.parts_dir)
        return self.out


def _atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Run ``write(tmp)`` on a temporary file beside ``path``, flush it, rename it to ``path``."""
    tmp = path.with_name(f"{TEMP_PREFIX}{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        write(tmp)
        with open(tmp, "rb+") as written:
            os.fsync(written.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
