"""Vectorised CAN payload encoder: many rows of one DBC message into payload bytes at once.

The mirror of :mod:`drivers.can.vector_decode`. :class:`MessageEncoder` gives the bytes cantools'
``Message.encode(values, scaling=True, padding=False, strict=True)`` gives row by row (tests hold
the two to byte equality), with the DBC's range check done once over all rows. Integer signals of
messages up to 8 bytes with at most one multiplexer are packed with numpy from the signals' bit
layout; anything else (float signals, CAN FD lengths, nested multiplexing) is encoded row by row
with cantools. Used by the simulated VSC ECU, which encodes a whole drive before it starts sending.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from cantools.database.can import Message

from vsccore.errors import EncodeError

__all__ = ["MessageEncoder", "SignalLayout"]

FloatArray = npt.NDArray[np.float64]
_U64 = np.uint64


@dataclass(frozen=True, slots=True)
class SignalLayout:
    """Where one signal's raw bits go in the payload, and its conversion (from the DBC)."""

    name: str
    shift: int
    """Bit position of the raw value's LSB: in the little-endian integer of the payload for Intel
    signals, in the big-endian integer for Motorola ones."""
    big_endian: bool
    length: int
    signed: bool
    scale: float
    offset: float
    minimum: float | None
    maximum: float | None
    choices: frozenset[int]
    """Raw values of the signal's value table (cantools skips the range check for them)."""
    mux_ids: frozenset[int] | None
    """Multiplexer values that select this signal (None: always present)."""


def _payload_bits(lay: SignalLayout, length: int) -> int:
    """The bits a signal occupies, as a mask on the little-endian integer of the payload."""
    if not lay.big_endian:
        return ((1 << lay.length) - 1) << lay.shift
    mask = 0
    for pos in range(lay.shift, lay.shift + lay.length):  # positions in the big-endian integer
        mask |= 1 << (8 * (length - 1 - pos // 8) + pos % 8)
    return mask


class MessageEncoder:
    """Encodes rows of physical values of one DBC message (see the module docstring).

    Raises:
        EncodeError: two signals of one multiplexer page share bits (cantools cannot encode them either).
    """

    def __init__(self, message: Message) -> None:
        self.message = message
        self._mux_name: str | None = next((s.name for s in message.signals if s.is_multiplexer), None)
        self._mux_signals: dict[int, list[str]] = {}
        if message.is_multiplexed():
            for sig in message.signals:
                for mux_id in sig.multiplexer_ids or ():
                    self._mux_signals.setdefault(mux_id, []).append(sig.name)
        self.layouts = self._vector_layouts(message)
        """The signals' bit layouts when numpy packs the message; None: cantools, row by row."""

    def encode_many(self, signals: Mapping[str, npt.ArrayLike], n: int) -> npt.NDArray[np.uint8]:
        """``n`` rows of physical values (one array per signal) → ``(n, length)`` payload bytes.

        Raises:
            EncodeError: naming the message and signal, for a missing signal, a wrong number of
                values or a value the DBC cannot carry.
        """
        values = {k: np.asarray(v, dtype=np.float64).reshape(-1) for k, v in signals.items()}
        for k, v in values.items():
            if v.size != n:
                raise EncodeError(f"{self.message.name}.{k} has {v.size} values for {n} frames")
        return self._pack(values, n) if self.layouts is not None else self._pack_cantools(values, n)

    def _vector_layouts(self, message: Message) -> list[SignalLayout] | None:
        """The signals' layouts when numpy can pack the message, else None (cantools row by row)."""
        length = int(message.length)
        if length > 8 or sum(1 for s in message.signals if s.is_multiplexer) > 1:
            return None
        layouts = []
        for s in message.signals:
            if s.conversion.is_float or s.length > 64 or s.length < 1:
                return None
            if s.multiplexer_signal is not None and s.multiplexer_signal != self._mux_name:
                return None
            if s.byte_order == "big_endian":
                msb = 8 * (s.start // 8) + (7 - s.start % 8)  # cantools' start_bit(): MSB, counted from byte 0 bit 7
                shift = 8 * length - msb - s.length
            else:
                shift = s.start
            if shift < 0 or shift + s.length > 8 * length:
                return None
            choices = frozenset(int(k) for k in (s.conversion.choices or {}))
            mux_ids = None if s.multiplexer_ids is None else frozenset(int(i) for i in s.multiplexer_ids)
            layouts.append(SignalLayout(
                s.name, shift, s.byte_order == "big_endian", int(s.length), bool(s.is_signed), float(s.scale),
                float(s.offset), None if s.minimum is None else float(s.minimum),
                None if s.maximum is None else float(s.maximum), choices, mux_ids,
            ))
        pages: list[frozenset[int] | None] = [None, *(frozenset({i}) for i in self._mux_signals)]
        for page in pages:  # signals that share bits cannot both be encoded (cantools fails on them too)
            used = 0
            for lay in layouts:
                if page is not None and lay.mux_ids is not None and not (lay.mux_ids & page):
                    continue
                if page is None and lay.mux_ids is not None:
                    continue
                bits = _payload_bits(lay, length)
                if used & bits:
                    raise EncodeError(f"{message.name}.{lay.name} overlaps another signal")
                used |= bits
        return layouts


    def _pack(self, values: Mapping[str, FloatArray], n: int) -> npt.NDArray[np.uint8]:
        message = self.message
        assert self.layouts is not None
        length = int(message.length)
        page: npt.NDArray[np.int64] | None = None
        if self._mux_name is not None:
            page = self._raw(self._layout(self._mux_name), values, np.ones(n, dtype=bool))
            unknown = ~np.isin(page, list(self._mux_signals))
            if unknown.any():
                raise EncodeError(f"{message.name}.{self._mux_name} = {int(page[unknown][0])} "
                                      f"selects no signals (pages {sorted(self._mux_signals)})")
        le = np.zeros(n, dtype=_U64)
        be = np.zeros(n, dtype=_U64)
        for lay in self.layouts:
            rows = np.ones(n, dtype=bool) if lay.mux_ids is None or page is None else np.isin(page, list(lay.mux_ids))
            if not rows.any():
                continue
            raw = np.where(rows, self._raw(lay, values, rows), 0)
            mask = _U64((1 << lay.length) - 1)
            bits = (raw.astype(_U64) & mask) << _U64(lay.shift)  # two's complement by the wrap of the cast
            if lay.big_endian:
                be |= bits
            else:
                le |= bits
        out = le.astype("<u8").view(np.uint8).reshape(n, 8)[:, :length]
        if self.layouts and any(lay.big_endian for lay in self.layouts):
            be_bytes = (be << _U64(8 * (8 - length))).astype(">u8").view(np.uint8).reshape(n, 8)[:, :length]
            out = out | be_bytes
        return np.ascontiguousarray(out, dtype=np.uint8)


    def _layout(self, name: str) -> SignalLayout:
        assert self.layouts is not None
        return next(lay for lay in self.layouts if lay.name == name)


    def _raw(self, lay: SignalLayout, values: Mapping[str, FloatArray], rows: npt.NDArray[np.bool_]
             ) -> npt.NDArray[np.int64]:
        """Raw integers of one signal (rows outside ``rows`` are not checked and come out as 0)."""
        where = f"{self.message.name}.{lay.name}"
        v = values.get(lay.name)
        if v is None:
            raise EncodeError(f"{where}: no values for this signal")
        v = np.where(rows, v, lay.offset)
        if not np.isfinite(v).all():
            raise EncodeError(f"{where}: non-finite value")
        raw = np.round((v - lay.offset) / lay.scale).astype(np.int64)
        check = rows & ~np.isin(raw, list(lay.choices)) if lay.choices else rows
        tol = abs(lay.scale) * 1e-6
        if lay.minimum is not None and (check & (v < lay.minimum - tol)).any():
            raise EncodeError(f"{where}: value {float(v[check & (v < lay.minimum - tol)][0])} below the DBC "
                                  f"minimum {lay.minimum}")
        if lay.maximum is not None and (check & (v > lay.maximum + tol)).any():
            raise EncodeError(f"{where}: value {float(v[check & (v > lay.maximum + tol)][0])} above the DBC "
                                  f"maximum {lay.maximum}")
        lo, hi = (-(1 << (lay.length - 1)), (1 << (lay.length - 1)) - 1) if lay.signed else (0, (1 << lay.length) - 1)
        if lay.length < 64 and ((raw < lo) | (raw > hi)).any():
            raise EncodeError(f"{where}: raw value outside {lay.length}-bit range [{lo}, {hi}]")
        return np.asarray(raw, dtype=np.int64)


    def _pack_cantools(self, values: Mapping[str, FloatArray], n: int) -> npt.NDArray[np.uint8]:
        message = self.message
        out = np.zeros((n, int(message.length)), dtype=np.uint8)
        for i in range(n):
            row = {k: float(v[i]) for k, v in values.items()}
            if self._mux_signals:
                assert self._mux_name is not None
                page = int(row[self._mux_name])
                row = {self._mux_name: page, **{k: row[k] for k in self._mux_signals.get(page, [])}}
            try:
                encoded = message.encode(row, scaling=True, padding=False, strict=True)
            except (ValueError, KeyError) as exc:  # cantools' EncodeError is a ValueError
                raise EncodeError(f"{message.name} frame {i}: {exc}") from exc
            out[i, : len(encoded)] = np.frombuffer(encoded, dtype=np.uint8)
        return out
