"""CAN FD bit timing for PCAN adapters, derived from the bitrates and sample points.

PCAN-Basic opens an FD channel only from a full timing string (``f_clock`` and the nominal and data
prescaler, segments and SJW; python-can's ``PcanBus`` passes them through), never from bitrates
alone. :func:`pcan_fd_timing` finds one that gives the bitrates *exactly*, on one of the clocks a
PCAN FD adapter runs at, with the sample points nearest to those asked for.

Defaults (fractions of the bit time): 0.80 nominal, 0.75 data. 0.75 is the CiA-recommended sample
point above 800 kbit/s that the Linux kernel's bit-timing calculator uses
(``drivers/net/can/dev/calc_bittiming.c``: > 800 kbit/s 75 %, > 500 kbit/s 80 %, else 87.5 %; PEAK's
own Linux driver uses the same table); every CAN FD data phase is above 800 kbit/s. 0.80 is that
table's next band, chosen for the arbitration phase of a CAN FD bus because CiA 601-3 asks for the
same time quantum in both phases and a sample point not later than needed (87.5 % would leave only
one or two quanta of phase segment 2 at 500 kbit/s with the data phase's quantum). Both can be set
with the ``[[can]]`` keys ``sample_point`` and ``data_sample_point``.

Rules kept (CiA 601-3): one prescaler for both phases where possible (the same time quantum), an
SJW as large as phase segment 2; PCAN-Basic's register ranges (python-can's ``PcanBus``
documentation): nominal BRP 1–1024, TSEG1 1–256, TSEG2 1–128, SJW 1–128; data BRP 1–1024,
TSEG1 1–32, TSEG2 1–16, SJW 1–16.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

from vsccore.errors import ConfigError

__all__ = [
    "DEFAULT_DATA_SAMPLE_POINT",
    "DEFAULT_SAMPLE_POINT",
    "PCAN_FD_CLOCKS_HZ",
    "PCAN_FD_TIMING_KEYS",
    "PcanFdTiming",
    "pcan_fd_timing",
]

DEFAULT_SAMPLE_POINT = 0.80
"""Nominal (arbitration) sample point (module docstring says where it comes from)."""
DEFAULT_DATA_SAMPLE_POINT = 0.75
"""Data-phase sample point (module docstring says where it comes from)."""

PCAN_FD_CLOCKS_HZ = (80_000_000, 60_000_000, 40_000_000, 30_000_000, 24_000_000, 20_000_000)
"""Clocks a PCAN FD channel runs at (python-can's ``VALID_PCAN_FD_CLOCKS``), the fastest (finest quantum) first."""

PCAN_FD_TIMING_KEYS = ("nom_brp", "nom_tseg1", "nom_tseg2", "nom_sjw", "data_brp", "data_tseg1", "data_tseg2",
                       "data_sjw")
"""The timing keys PCAN-Basic needs besides the clock (``f_clock`` or ``f_clock_mhz``)."""

_NOM = {"brp": 1024, "tseg1": 256, "tseg2": 128, "sjw": 128}
_DATA = {"brp": 1024, "tseg1": 32, "tseg2": 16, "sjw": 16}


@dataclass(frozen=True, slots=True)
class PcanFdTiming:
    """A PCAN FD timing: the clock, and prescaler, segments and SJW of each phase (in time quanta)."""

    f_clock: int
    nom_brp: int
    nom_tseg1: int
    nom_tseg2: int
    nom_sjw: int
    data_brp: int
    data_tseg1: int
    data_tseg2: int
    data_sjw: int

    @property
    def nom_bitrate(self) -> Fraction:
        """Nominal bitrate (bit/s), exact."""
        return Fraction(self.f_clock, self.nom_brp * (1 + self.nom_tseg1 + self.nom_tseg2))

    @property
    def data_bitrate(self) -> Fraction:
        """Data-phase bitrate (bit/s), exact."""
        return Fraction(self.f_clock, self.data_brp * (1 + self.data_tseg1 + self.data_tseg2))

    @property
    def nom_sample_point(self) -> Fraction:
        """Nominal sample point as a fraction of the bit time."""
        return Fraction(1 + self.nom_tseg1, 1 + self.nom_tseg1 + self.nom_tseg2)

    @property
    def data_sample_point(self) -> Fraction:
        """Data-phase sample point as a fraction of the bit time."""
        return Fraction(1 + self.data_tseg1, 1 + self.data_tseg1 + self.data_tseg2)

    def as_options(self) -> dict[str, int]:
        """The python-can ``PcanBus`` keyword arguments."""
        return {"f_clock": self.f_clock, **{key: getattr(self, key) for key in PCAN_FD_TIMING_KEYS}}


def _phase(f_clock: int, bitrate: int, brp: int, sample_point: float, limits: dict[str, int]
           ) -> tuple[int, int, int] | None:
    """``(tseg1, tseg2, sjw)`` for an exact ``bitrate`` with prescaler ``brp`` (None if none fits)."""
    quanta, rest = divmod(f_clock, bitrate * brp)
    if rest or quanta < 3:  # sync + at least one quantum before and after the sample point
        return None
    tseg1 = min(max(round(sample_point * quanta) - 1, 1), quanta - 2)
    tseg2 = quanta - 1 - tseg1
    if tseg1 > limits["tseg1"] or tseg2 > limits["tseg2"]:
        return None
    return tseg1, tseg2, min(tseg2, limits["sjw"])


def pcan_fd_timing(
    bitrate: int,
    data_bitrate: int,
    *,
    sample_point: float = DEFAULT_SAMPLE_POINT,
    data_sample_point: float = DEFAULT_DATA_SAMPLE_POINT,
    where: str = "can",
) -> PcanFdTiming:
    """The PCAN FD timing giving ``bitrate`` and ``data_bitrate`` exactly, sample points nearest those asked for.

    Preference: the same prescaler in both phases, then the smallest sample-point error (both phases
    added), then the fastest clock and smallest prescaler (the finest quantum).

    Raises:
        ConfigError: no PCAN clock and prescalers give both bitrates exactly within PCAN's register
            ranges; the message names the keys to give instead (under ``where``).
    """
    if not 0.5 <= sample_point < 1.0 or not 0.5 <= data_sample_point < 1.0:
        raise ConfigError(f"{where}: sample points must lie in [0.5, 1), got {sample_point} and {data_sample_point}")
    best: tuple[tuple[float, ...], PcanFdTiming] | None = None
    for clock_rank, f_clock in enumerate(PCAN_FD_CLOCKS_HZ):
        for nom_brp in range(1, _NOM["brp"] + 1):
            if f_clock < bitrate * nom_brp * 3:
                break
            nominal = _phase(f_clock, bitrate, nom_brp, sample_point, _NOM)
            if nominal is None:
                continue
            for data_brp in range(1, _DATA["brp"] + 1):
                if f_clock < data_bitrate * data_brp * 3:
                    break
                data = _phase(f_clock, data_bitrate, data_brp, data_sample_point, _DATA)
                if data is None:
                    continue
                timing = PcanFdTiming(f_clock, nom_brp, *nominal, data_brp, *data)
                error = (abs(float(timing.nom_sample_point) - sample_point)
                         + abs(float(timing.data_sample_point) - data_sample_point))
                key = (0.0 if nom_brp == data_brp else 1.0, round(error, 9), float(clock_rank), float(nom_brp))
                if best is None or key < best[0]:
                    best = (key, timing)
    if best is None:
        clocks = ", ".join(f"{c // 1_000_000}" for c in PCAN_FD_CLOCKS_HZ)
        raise ConfigError(
            f"{where}: no PCAN FD timing gives bitrate {bitrate} and data_bitrate {data_bitrate} exactly "
            f"(clocks {clocks} MHz); give the timing in options: f_clock (or f_clock_mhz), "
            + ", ".join(PCAN_FD_TIMING_KEYS)
        )
    return best[1]
