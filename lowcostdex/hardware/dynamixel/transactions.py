"""One Dynamixel transaction at a time: unicast register access with bounded retries, (fast) sync
reads, and the late-reply defences (settle after a failure, flush, byte-exact replies, the
motor's Realtime Tick).

Protocol 2.0 status packets carry no sequence number, so a late reply to an earlier request looks
fresh. After any failed transaction the next one waits ``settle_ms`` first (late bytes arrive and
the SDK's ``clearPort`` flushes them), and a transaction that consumed other bytes than the
status packets it asked for (another count, another length), or left bytes waiting, is discarded
whole. A reply later than the timeout and the settle wait can still land in the slot of a lost
one; so a reply is tied to its request (``_read_block``): the present block is read as the
21-byte ``BLOCK`` until the first reply of a block read is lost, and from then on with the
motor's Realtime Tick in front (``TICK_BLOCK``, 27 bytes, from the start with
``DynamixelConfig.realtime_tick``). A late reply to a 21-byte request is refused by its length;
one to a 27-byte request by its tick, which did not advance with the host's clock since the
motor's last accepted reply (``_stale``). A clean bus keeps the short block (and the timing the
simulation's motion bound assumes, ``motion.PRESENT_BLOCK_BYTES``).
``SdkTransactions`` is the base of ``driver.DynamixelBus``, which supplies the state it uses
(``port``, ``ph``, ``config``, ``stats``, ``tables``, ``ids``, ``clock``, ``_note_alert``,
``_silent``, ``_dirty``, ``_last_tx``, ``_sample_time``, ``_ticks``, ``_unanswered``,
``_untrusted``).
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
TICK_WRAP = 32768  # Realtime Tick counts ms modulo this (e-Manual: 0 ~ 32,767)
TICK_HORIZON = 30.0  # [s] a reference older than this (near the wrap) gives no verdict
TICK_RISE = 0.001  # the most the lower bound of a motor's tick climbs per ms of host time

BLOCK = (Reg.PRESENT_CURRENT, Reg.PRESENT_VELOCITY, Reg.PRESENT_POSITION, Reg.VELOCITY_TRAJECTORY,
         Reg.POSITION_TRAJECTORY, Reg.PRESENT_INPUT_VOLTAGE, Reg.PRESENT_TEMPERATURE)
"""The contiguous block read every control step (addresses 126..146 on X-series)."""
TICK_BLOCK = (Reg.REALTIME_TICK, *BLOCK)
"""The block after the first lost reply, or always with ``DynamixelConfig.realtime_tick``
(120..146: Moving, Moving Status and Present PWM in between are read and not used): Realtime
Tick, the motor's ms clock (0..32767), tells a fresh reply from a late one to an earlier request
(``SdkTransactions._stale``), and its length tells it from a late reply to a ``BLOCK`` read."""
STATUS_BYTES = 11
"""Bytes of a Protocol 2.0 status packet without parameters (header 4, id, length 2,
instruction, error, CRC 2)."""


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

        data, _ = self._unicast(motor_id, f"reading {reg.value}", op, 1,
                                expected_bytes=STATUS_BYTES + it.size)
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

        self._unicast(motor_id, f"writing {reg.value}={value}", op, 1, tries,
                      expected_bytes=STATUS_BYTES)

    def _try_read(self, motor_id: int, address: int, size: int) -> int | None:
        self._begin()
        data, result, _ = self.ph.readTxRx(self.port, motor_id, address, size)
        self.stats.transactions += 1
        if result != COMM_SUCCESS or len(data) != size or not self._end(1, STATUS_BYTES + size):
            self._dirty = True
            return None
        return int.from_bytes(bytes(data), "little")

    def _unicast(self, motor_id: int, what: str, op, expected_headers: int,
                 tries: int | None = None, expected_bytes: int | None = None):
        """Run ``op`` with bounded retries; returns (payload, error byte). ``expected_bytes``:
        the status packet's length, when known (a late reply of another length is refused)."""
        result = COMM_SUCCESS
        tries = self.config.retries + 1 if tries is None else tries
        for _ in range(tries):
            self._begin()
            (payload, err), result, _ = op()
            self.stats.transactions += 1
            if result == COMM_SUCCESS and self._end(expected_headers, expected_bytes):
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
                if result == COMM_SUCCESS and len(data) != length:
                    break  # a packet of another length (a late reply): refused below
                if result == COMM_SUCCESS:
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
            # Accept only a transaction that consumed no packet it did not ask for, nor one of
            # another length: a late reply to an earlier read (there is no sequence number)
            # would otherwise pass as fresh.
            if not self._end(packets, packets * (STATUS_BYTES + length)):
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

    # -- the present block, tied to its request ------------------------------------------------
    def _set_block(self, block: tuple[Reg, ...]) -> None:
        """Read ``block`` (``BLOCK`` or ``TICK_BLOCK``) from now on: its address, length, dtype."""
        t = self.tables[self.ids[0]]
        self._block = block
        self._block_addr = t[block[0]].address
        self._block_len = t[block[-1]].end - self._block_addr
        self._dtype = np.dtype({
            "names": [r.name for r in block],
            "formats": [("<i" if r in SIGNED else "<u") + str(t[r].size) for r in block],
            "offsets": [t[r].address - self._block_addr for r in block],
            "itemsize": self._block_len})

    def _read_block(self, ids: tuple[int, ...], fast: bool
                    ) -> tuple[dict[int, bool], dict[int, int], dict[int, bytes]]:
        """One (fast) sync read of the present block of ``ids``: validity, error byte, data (in
        the layout of ``self._dtype``), every valid reply an answer to this request.

        The first read that loses a reply switches to ``TICK_BLOCK`` for good (the lost reply
        may still come, as late as it likes, and it would fit the next ``BLOCK`` read's slot):
        the valid replies of that read are fresh (no earlier block read had a reply outstanding)
        and come back padded to the new layout (their tick unknown: no reference is taken)."""
        valid, err, raw = self._sync_read(ids, self._block_addr, self._block_len, fast)
        if self._block is TICK_BLOCK:
            self._stale(ids, valid, raw, self._last_tx)  # the host's time before the request
        elif not all(valid.values()):
            short = self._block_len
            self._set_block(TICK_BLOCK)
            pad = bytes(self._block_len - short)
            raw = {i: pad + r for i, r in raw.items()}
            log.info("a reply was lost: reading the present block with Realtime Tick from now on "
                     "(%d -> %d bytes per motor), so a late reply cannot pass as fresh", short,
                     self._block_len)
        return valid, err, raw

    def _stale(self, ids: Sequence[int], valid: dict[int, bool], raw: dict[int, bytes],
               t: float) -> None:
        """Mark invalid the replies of a ``TICK_BLOCK`` read (requested at host time ``t``,
        before it was written) that answer an earlier request: a reply late beyond the status
        timeout and the settle wait that landed in the slot of a lost one. Protocol 2.0 status
        packets carry no sequence number; the motor's own ms clock does the job. A motor samples
        its tick after the request left the host, never before: against a lower bound of the
        motor's tick at the host's time (``_ticks``: host time, tick, trusted; from the replies
        accepted so far) a fresh reply's tick is at or ahead of it, a late one's is behind by
        about its age (refused beyond ``TICK_SLACK_MS`` + ``TICK_DRIFT`` of the time since the
        bound). The bound follows the lowest accepted tick at once and a higher one by at most
        ``TICK_RISE`` of the time (one slow request - a loaded host, a pty server - does not
        make the next fresh replies look late).

        Without a reference (the first tick read, after a reboot, after ``TICK_HORIZON``), a
        reply is accepted if no earlier request to its motor went unanswered since its last
        accepted reply (``_unanswered``: then nothing late can be in flight); else it is refused
        and kept as an untrusted reference, and the next reply consistent with it is accepted."""
        half = TICK_WRAP / 2
        for i in ids:
            if not valid[i]:
                self._unanswered.add(i)
                continue
            tick = self._tick(raw[i])
            ref = self._ticks.get(i)
            if ref is not None and t - ref[0] <= TICK_HORIZON:
                t0, tick0, trusted = ref
                elapsed = 1000.0 * (t - t0)
                # the tick's advance less the host's, in [-16.384, 16.384) s: a late reply is
                # behind by its age (modular: the tick wraps; a reply older than the reference
                # is behind too)
                behind = -((tick - tick0 - elapsed + half) % TICK_WRAP - half)
                if behind <= TICK_DRIFT * elapsed + TICK_SLACK_MS:
                    rise = max(0.0, -behind - TICK_RISE * elapsed)  # ahead beyond the rise
                    self._ticks[i] = (t, tick - rise, True)
                    self._unanswered.discard(i)
                    continue
                if not trusted:
                    self._ticks[i] = (t, tick, False)
                    self._untrusted += 1
                log.debug("motor %d: stale reply (Realtime Tick %.0f ms behind the host's clock)",
                          i, behind)
            elif i not in self._unanswered:
                self._ticks[i] = (t, tick, True)
                continue
            else:
                self._ticks[i] = (t, tick, False)
                self._untrusted += 1
                log.debug("motor %d: reply with no reference after a lost one: refused, kept as "
                          "the reference for the next", i)
            valid[i] = False
            self.stats.stale += 1
            self._unanswered.add(i)  # the fresh reply to this request may be in flight
            self._dirty = True  # more late replies may follow: settle first
