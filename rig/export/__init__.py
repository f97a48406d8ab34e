"""Getting data out of a session: one module per format, dispatched by :data:`EXPORTERS`.

- :mod:`~rig.export.raw_gnss`: each receiver's port bytes and the relayed corrections, byte-exact, for
  RTKLIB and NovAtel tools;
- :mod:`~rig.export.csv`: decoded tables as CSV;
- :mod:`~rig.export.parquet`, :mod:`~rig.export.mdf4`, :mod:`~rig.export.mat`: every group of topics
  through the streaming group reader (:func:`rig.data.stream.iter_groups`), chunk by chunk with bounded
  memory; a damaged chunk or an unfinished part is skipped with a warning and every intact chunk exported.

The format modules are imported when used, so that ``rig --help`` stays light.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from rig.export.files import ExportedFile, ExportKind, ExportReport

__all__ = [
    "EXPORTERS",
    "ExportFormat",
    "ExportKind",
    "ExportReport",
    "ExportedFile",
    "Exporter",
    "exporter",
]


class ExportFormat(StrEnum):
    """Output format of ``rig export --format``."""

    MDF4 = "mdf4"
    PARQUET = "parquet"
    MAT = "mat"
    CSV = "csv"


@dataclass(frozen=True, slots=True)
class Exporter:
    """Where a format's export function lives (imported when used) and what it takes."""

    module: str
    function: str
    topics: bool
    """Takes ``topics=`` and ``progress=`` (the streamed table formats)."""

    def load(self) -> Callable[..., ExportReport]:
        fn: Callable[..., ExportReport] = getattr(importlib.import_module(self.module), self.function)
        return fn


EXPORTERS: dict[ExportFormat, Exporter] = {
    ExportFormat.MDF4: Exporter("rig.export.mdf4", "export_mdf4", topics=True),
    ExportFormat.PARQUET: Exporter("rig.export.parquet", "export_parquet", topics=True),
    ExportFormat.MAT: Exporter("rig.export.mat", "export_mat", topics=True),
    ExportFormat.CSV: Exporter("rig.export.csv", "export_csv", topics=False),
}
"""The table formats of ``rig export --format``; adding one touches its module and this table."""


def exporter(fmt: ExportFormat | str) -> Callable[..., ExportReport]:
    """The export function of a format (:data:`EXPORTERS`)."""
    return EXPORTERS[ExportFormat(fmt)].load()

