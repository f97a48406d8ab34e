"""What every exporter shares: the report of the files written, the output folder, a partial file renamed
when complete, progress."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from rig.data.stream import SessionStream, open_stream
from vsccore.errors import SessionFileError


class ExportKind(StrEnum):
    """What an exported file holds."""

    GNSS_RAW = "gnss_raw"
    CORRECTIONS = "corrections"
    TABLE = "table"


@dataclass(frozen=True, slots=True)
class ExportedFile:
    """One file written by an export."""

    path: Path
    kind: ExportKind
    source: str
    """The topic (raw streams) or what the table holds (``gnss rover_a bestpos``)."""
    bytes: int
    records: int
    """Messages concatenated (raw streams) or rows (tables)."""
    first_ns: int | None = None
    last_ns: int | None = None
    parts: int = 0
    """Session parts that contributed (raw streams)."""
    sequence_breaks: int = 0
    """Places where the topic's sequence numbers do not run on by one (lost or repeated reads)."""


@dataclass(frozen=True, slots=True)
class ExportReport:
    """The files an export wrote, and what it noticed."""

    files: tuple[ExportedFile, ...]
    warnings: tuple[str, ...] = ()

    @property
    def total_bytes(self) -> int:
        return sum(f.bytes for f in self.files)


def check_new(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise SessionFileError(f"{path} already exists (remove it or pass --overwrite)")


def export_dir(out_dir: Path | str) -> Path:
    """The export directory, made when missing (a SessionFileError naming it when it cannot be)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"{out}: cannot create the export directory: {exc}") from exc
    return out


def single_file_export(
    path: Path | str, out_dir: Path | str, suffix: str, overwrite: bool,
) -> tuple[SessionStream, Path]:
    """The session's stream and its one export file ``<out_dir>/<session><suffix>``: refused when it exists and
    ``overwrite`` is not set (before the directory is made), the directory made."""
    stream = open_stream(path)
    final = Path(out_dir) / f"{stream.name}{suffix}"
    check_new(final, overwrite)
    export_dir(out_dir)
    return stream, final


def partial_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.partial")


def progress_fn(progress: Callable[[int, int, int], None] | None, stream: SessionStream
                 ) -> Callable[[int], None] | None:
    if progress is None:
        return None
    return lambda t: progress(t, stream.start_ns, stream.end_ns)

