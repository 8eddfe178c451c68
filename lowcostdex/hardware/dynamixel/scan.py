"""``scan``: find the Dynamixel motors on a port and read their state without configuring them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from dynamixel_sdk import COMM_SUCCESS, PacketHandler

from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.dynamixel import transport
from lowcostdex.hardware.dynamixel.control_table import model_name
from lowcostdex.hardware.dynamixel.protocol import hardware_error_names


@dataclass(frozen=True)
class MotorInfo:
    """What ``scan`` finds about one motor."""

    motor_id: int
    model_number: int
    model: str
    firmware: int | None = None
    temperature: int | None = None
    voltage: float | None = None
    torque_enabled: bool | None = None
    hardware_error: tuple[str, ...] = ()


def scan(port: str | transport.DxlPort, baudrate: int = 1_000_000,
         ids: Sequence[int] | None = None) -> list[MotorInfo]:
    """Find motors (broadcast ping, or ping ``ids``) and read their state, without configuring.

    Returns one ``MotorInfo`` per motor found, sorted by id.
    """
    if isinstance(port, str):
        port = transport.DxlPort(port, latency_ms=16.0)  # not time critical: be patient
    port.baudrate = baudrate
    try:
        opened = port.openPort()
    except OSError as exc:  # pyserial: a path that is not a serial port, a device gone
        raise BusError(f"cannot open {port.getPortName()} as a serial port at {baudrate} bps "
                       f"({exc})") from None
    if not opened:
        raise BusError(f"cannot open {port.getPortName()} at {baudrate} bps")
    ph = PacketHandler(2.0)
    try:
        if ids is None:
            found, result = ph.broadcastPing(port)
            found = {i: (v[0], v[1]) for i, v in found.items()}
        else:
            found = {}
            for i in ids:
                model, result, _ = ph.ping(port, i)
                if result == COMM_SUCCESS:
                    fw, res, _ = ph.read1ByteTxRx(port, i, 6)
                    found[i] = (model, fw if res == COMM_SUCCESS else None)
        out = []
        for i in sorted(found):
            model, fw = found[i]

            def rd(address: int, size: int, motor: int = i) -> int | None:
                data, res, _ = ph.readTxRx(port, motor, address, size)
                return int.from_bytes(bytes(data), "little") if res == COMM_SUCCESS and len(
                    data) == size else None

            temp, volt, torque, hw = rd(146, 1), rd(144, 2), rd(64, 1), rd(70, 1)
            out.append(MotorInfo(i, model, model_name(model), fw, temp,
                                 None if volt is None else volt / 10.0,
                                 None if torque is None else bool(torque),
                                 hardware_error_names(hw) if hw else ()))
        return out
    finally:
        port.closePort()
