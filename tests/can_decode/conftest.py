"""Fixtures of the CAN decoding tests: a small DBC with Intel/Motorola, sign bits, mux and enums."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cantools.database.can import Database
from numpy.typing import NDArray

from drivers.can.checks import ChecksumAlgorithm, register_checksum
from drivers.can.dbc import load_dbc

DATA = Path(__file__).parent / "data"


class XorChecksum:
    """A toy algorithm for the tests: XOR of bytes 0..6 (the checksum lives in byte 7)."""

    @property
    def name(self) -> str:
        return "test_xor7"

    def supports(self, arbitration_id: int) -> bool:
        return arbitration_id == 0x100

    def compute(self, arbitration_id: int, data: bytes) -> int:
        out = 0
        for b in data[:7]:
            out ^= b
        return out

    def compute_many(self, arbitration_id: int, data: NDArray[np.uint8]) -> NDArray[np.int64]:
        return np.bitwise_xor.reduce(data[:, :7], axis=1).astype(np.int64)


XOR: ChecksumAlgorithm = XorChecksum()
register_checksum(XOR, replace=True)


@pytest.fixture
def small_db() -> Database:
    return load_dbc(DATA / "small.dbc", strict=True)


def small_roles() -> dict[str, Any]:
    """The role table used by most tests (as the TOML would give it)."""
    return {
        "roles": {
            "yaw_rate": {"message": "IMU_01", "signal": "IMU_Yaw", "unit": "deg/s", "invert": True},
            "lat_accel": {
                "message": "IMU_01",
                "signal": "IMU_Ay",
                "unit": "g",
                "valid_signal": "IMU_Ay_Valid",
                "valid_when": 1,
            },
            "imu_status": {"message": "IMU_01", "signal": "IMU_Status"},
            "swa": {
                "message": "STEER_01",
                "signal": "SWA_Mag",
                "unit": "deg",
                "sign_signal": "SWA_Sign",
                "sign_negative_when": 1,
            },
            "wheel_speed_fl": {"message": "STEER_01", "signal": "Wheel_FL"},  # unit from the DBC: km/h
            "mc_pressure": {"message": "STEER_01", "signal": "MC_Pressure", "unit": "bar"},
            "vsc_beta_estimate": {"message": "VSC_MUX", "signal": "Beta", "unit": "rad"},
            "vsc_mode": {"message": "VSC_MUX", "signal": "Mode"},
            "vsc_active": {"message": "VSC_MUX", "signal": "Active"},
        },
        "checks": {"IMU_01": {"checksum_signal": "IMU_CRC", "algorithm": "test_xor7"}},
    }
