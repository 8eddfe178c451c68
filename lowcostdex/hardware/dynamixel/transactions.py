"""One Dynamixel transaction at a time: unicast register access with bounded retries, (fast) sync
reads, and the late-reply defences (settle after a failure, flush, contamination check, the
motor's Realtime Tick).

Protocol 2.0 status packets carry no sequence number, so a late reply to an earlier request looks
fresh. After any failed transaction the next one waits ``settle_ms`` first (late bytes arrive and
the SDK's ``clearPort`` flushes them), and a transaction that consumed more status packets than it
asked for, or left bytes waiting, is discarded whole. A reply later than the timeout and the
settle wait that lands in the slot of a lost one passes as fresh unless the block carries the
motor's Realtime Tick (``DynamixelConfig.realtime_tick``, opt-in): then it is refused
(``_stale``).
``SdkTransactions`` is the base of ``driver.DynamixelBus``, which supplies the state it uses
(``port``, ``ph``, ``config``, ``stats``, ``tables``, ``clock``, ``_note_alert``, ``_silent``,
``_dirty``, ``_last_tx``, ``_sample_time``, ``_dtype``, ``_ticks``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.dynamixel.config import InstructionError
from lowcostdex.hardware.dynamixel.control_table import SIGNED, Reg, load_control_table
from lowcostdex.hardware.dynamixel.protocol import (
    BROADCAST_ID,
    HEADER,
    ErrorNumber,
    le_bytes,
    to_signed,
)

log = logging.getLogger(__name__)

TICK_SLACK_MS = 2.0  # Realtime Tick is whole ms; the motor's clock against the host's
TICK_DRIFT = 0.02  # ... plus this share of the time between two reads (oscillator tolerance)


class SdkTransactions:
    """Register access and sync reads on ``self.port`` through ``self.ph`` (the SDK's
    ``PacketHandler``), one transaction at a time (see the module docstring)."""

    # -- registers -------------------------------------------------------------------------------
    def ping(self, motor_id: int, retries: int | None = None) -> tuple[int, int] | None:
        """(model number, firmware version), or None if the motor does not answer."""
        tries = (self.config.retries if retries is None else retries) + 1
        for _ in range(tries):
            self._begin()
            model, result, err = self.ph.ping(self.port, motor_id)
            self.stats.transactions += 1
            if result == COMM_SUCCESS and self._end(1):
                self._note_alert(motor_id, err)
                fw = self._try_read(motor_id, 6, 1)
                return model, (fw if fw is not None else -1)
            self._dirty = True
        return None

    def read_register(self, motor_id: int, reg: Reg) -> int:
        """Read one item (signed items decoded); raises BusError / InstructionError."""
        it = self.tables[motor_id][reg] if motor_id in self.tables else load_control_table(
            self.config.models[0])[reg]

        def op():
            data, result, err = self.ph.readTxRx(self.port, motor_id, it.address, it.size)
            if result == COMM_SUCCESS and len(data) != it.size:
                result = COMM_RX_CORRUPT
            return (data, err), result, err

        data, _ = self._unicast(motor_id, f"reading {reg.value}", op, 1)
        raw = int.from_bytes(bytes(data), "little")
        return to_signed(raw, it.size) if reg in SIGNED else raw

    def write_register(self, motor_id: int, reg: Reg, value: int, tries: int | None = None
                       ) -> None:
        """Write one item and check the status; raises BusError / InstructionError.
        ``tries``: attempts (default ``config.retries`` + 1)."""
        it = self.tables[motor_id][reg] if motor_id in self.tables else load_control_table(
            self.config.models[0])[reg]
        data = list(le_bytes(value, it.size))

        def op():
            result, err = self.ph.writeTxRx(self.port, motor_id, it.address, it.size, data)
            return (None, err), result, err

        self._unicast(motor_id, f"writing {reg.value}={value}", op, 1, tries)

    def _try_read(self, motor_id: int, address: int, size: int) -> int | None:
        self._begin()
        data, result, _ = self.ph.readTxRx(self.port, motor_id, address, size)
        self.stats.transactions += 1
        if result != COMM_SUCCESS or len(data) != size or not self._end(1):
            self._dirty = True
            return None
        return int.from_bytes(bytes(data), "little")

    def _unicast(self, motor_id: int, what: str, op, expected_headers: int,
                 tries: int | None = None):
        """Run ``op`` with bounded retries; returns (payload, error byte)."""
        result = COMM_SUCCESS
        tries = self.config.retries + 1 if tries is None else tries
        for _ in range(tries):
            self._begin()
            (payload, err), result, _ = op()
            self.stats.transactions += 1
            if result == COMM_SUCCESS and self._end(expected_headers):
                num = err & 0x7F
                if num == ErrorNumber.CRC:
                    continue  # the motor saw a corrupted instruction: resend
                self._note_alert(motor_id, err)
                if num:
                    raise InstructionError(motor_id, what, err)
                return payload, err
            self._dirty = True
        hint = ""
        if result == COMM_RX_TIMEOUT and not self.port.is_emulated and self.port.latency_ms < 16:
            hint = (f" (the status timeouts assume a USB latency timer of "
                    f"{self.port.latency_ms:g} ms; on a pty or an adapter whose latency timer "
                    "cannot be read, pass --latency-ms 16)")
        raise BusError(f"motor {motor_id}: {what} failed after {tries} "
                       f"attempts: {self.ph.getTxRxResult(result)}{hint}")

    # -- transactions ------------------------------------------------------------------------------
    def _begin(self) -> None:
        if self._dirty:
            self.port.sleep(self.config.settle_ms / 1000.0)
            self._dirty = False
        self.port.is_using = False
        self.port.rx_trace.clear()
        self._last_tx = self.clock()

    def _end(self, expected_headers: int, expected_bytes: int | None = None) -> bool:
        """True if the transaction consumed exactly the expected status packets."""
        trace = self.port.rx_trace
        clean = (trace.count(HEADER) == expected_headers if expected_bytes is None
                 else len(trace) == expected_bytes)
        if clean and self.port.getBytesAvailable() == 0:
            return True
        self.stats.contaminated += 1
        return False

    def _sync_read(self, ids: tuple[int, ...], address: int, length: int, fast: bool
                   ) -> tuple[dict[int, bool], dict[int, int], dict[int, bytes]]:
        """One (fast) sync read of ``length`` bytes at ``address``: validity, error byte, data."""
        n = len(ids)
        valid = dict.fromkeys(ids, False)
        err: dict[int, int] = dict.fromkeys(ids, -1)
        raw: dict[int, bytes] = {}
        self._begin()
        self.stats.transactions += 1
        self.stats.reads += 1
        result = self.ph.syncReadTx(self.port, address, length, list(ids), n, fast)
        # the motors sample their present values when the instruction has arrived: the time
        # the request left is a better timestamp than the end of n status packets (at 1 Mbit/s
        # a full block from 10 motors takes ~2.5 ms, a systematic lag in identification logs)
        self._sample_time = self.clock()
        if result != COMM_SUCCESS:
            self.port.is_using = False
            self._dirty = True
            return valid, err, raw
        if fast:
            data, result, _ = self.ph.fastSyncReadRx(self.port, BROADCAST_ID, (length + 4) * n)
            size = length + 4
            if result == COMM_SUCCESS and len(data) == size * n and self._end(
                    1, 8 + size * n):
                for j, i in enumerate(ids):
                    s = j * size
                    if data[s + 1] != i:
                        break
                    err[i] = data[s]
                    raw[i] = bytes(data[s + 2:s + 2 + length])
                    valid[i] = not err[i] & 0x7F
                else:
                    return valid, err, raw
                valid = dict.fromkeys(ids, False)
            self._count_failure(result)
        else:
            packets = 0
            for i in ids:
                data, result, e = self.ph.readRx(self.port, i, length)
                if result == COMM_SUCCESS and len(data) == length:
                    packets += 1
                    err[i], raw[i] = e, bytes(data)
                    valid[i] = not e & 0x7F
                    self._silent.discard(i)
                else:
                    self._count_failure(result)
                    if result != COMM_RX_CORRUPT:
                        self._silent.add(i)
                        break  # timed out: later replies were consumed looking for this one
                    packets += 1
            # Accept only a transaction that consumed no packet it did not ask for: a late reply
            # to an earlier read (there is no sequence number) would otherwise pass as fresh.
            if not self._end(packets):
                valid = dict.fromkeys(ids, False)
        if not all(valid.values()):
            self._dirty = True
        return valid, err, raw

    def _count_failure(self, result: int) -> None:
        if result == COMM_RX_CORRUPT:
            self.stats.corrupt += 1
        elif result != COMM_SUCCESS:
            self.stats.timeouts += 1

    def _tick(self, data: bytes) -> int:
        return int(np.frombuffer(data, self._dtype)[Reg.REALTIME_TICK.name][0])

    def _stale(self, ids: Sequence[int], valid: dict[int, bool], raw: dict[int, bytes],
               t: float) -> None:
        """Mark invalid the replies whose Realtime Tick did not advance with the host's clock
        since the motor's last accepted reply: a reply to an earlier request (late beyond the
        status timeout and the settle wait) that landed in the slot of a lost one. Protocol 2.0
        status packets carry no sequence number; the motor's own ms clock does the job."""
        if not self.config.realtime_tick:
            return
        for i in ids:
            if not valid[i] or i not in self._ticks:
                continue
            t_prev, tick_prev = self._ticks[i]
            elapsed = 1000.0 * (t - t_prev)
            if elapsed > 30_000.0:  # the tick wraps at 32768 ms: no verdict
                continue
            advance = (self._tick(raw[i]) - tick_prev) % 32768
            if advance < elapsed * (1 - TICK_DRIFT) - TICK_SLACK_MS:
                # refused, and the reference kept: a motor whose clock restarted without a
                # reboot from this driver (a brown-out: torque off too) keeps being refused
                # until the Robot's invalid-read limit stops the run
                valid[i] = False
                self.stats.stale += 1
                self._dirty = True  # more late replies may follow: settle first
                log.debug("motor %d: stale reply (Realtime Tick advanced %d ms in %.1f ms)", i,
                          advance, elapsed)
