"""Protocol 2.0 codec: CRC vectors, stuffing, packet building/parsing, value encoding.

Known answers come from the ROBOTIS e-Manual examples and from dynamixel_sdk itself (the SDK's
own transmitted bytes are the oracle for stuffing and framing).
"""

from __future__ import annotations

import numpy as np
import pytest
from dynamixel_sdk import PacketHandler, PortHandler

from lowcostdex.hardware.dynamixel import protocol as P


class _CaptureSerial:
    def __init__(self):
        self.sent = bytearray()
        self.is_open = True

    def write(self, data):
        self.sent += bytes(data)
        return len(data)

    def read(self, n=1):
        return b""

    @property
    def in_waiting(self):
        return 0

    def reset_input_buffer(self):
        pass

    def close(self):
        pass


class CapturePort(PortHandler):
    """Records what the SDK transmits; never answers."""

    def setupPort(self, cflag_baud):  # noqa: N802
        self.ser = _CaptureSerial()
        self.is_open = True
        self.tx_time_per_byte = 0.01
        return True


@pytest.fixture
def sdk():
    port = CapturePort("capture")
    port.openPort()
    return port, PacketHandler(2.0)


def test_crc_check_value_and_emanual_examples():
    assert P.crc16(b"123456789") == 0xFEE8  # CRC-16/BUYPASS check value
    assert P.instruction_packet(1, P.Instruction.PING) == bytes.fromhex("fffffd0001030001194e")
    assert P.status_packet(1, 0, bytes((0x06, 0x04, 0x26))) == bytes.fromhex(
        "fffffd0001070055000604266 55d".replace(" ", ""))
    # e-Manual Sync Read example: read 4 bytes at 132 from ids 1 and 2
    sync = P.instruction_packet(P.BROADCAST_ID, P.Instruction.SYNC_READ,
                                bytes((0x84, 0x00, 0x04, 0x00, 0x01, 0x02)))
    assert sync[-2:] == bytes((0xCE, 0xFA))


def test_crc_matches_sdk_table_on_random_data():
    rng = np.random.default_rng(7)
    ph = PacketHandler(2.0)
    for _ in range(300):
        data = rng.integers(0, 256, size=int(rng.integers(1, 200))).tolist()
        assert P.crc16(bytes(data)) == ph.updateCRC(0, data, len(data))
    # continuing a CRC equals one CRC over the concatenation
    a, b = b"\x01\x02\xff", b"\xfd\x00\x10"
    assert P.crc16(b, P.crc16(a)) == P.crc16(a + b)


def test_crc_table_builder_matches_the_sdks_table():
    # CRC_TABLE is built at import, so a check of crc16 cannot reach its builder (mutmut cannot
    # switch code that ran before the test): the builder itself against the SDK's table, whose
    # entry i is the CRC of the single byte i from 0 (non-reflected CRC-16, init 0)
    ph = PacketHandler(2.0)
    sdk = [ph.updateCRC(0, [i], 1) for i in range(256)]
    assert P._crc_table(0x8005) == tuple(sdk) == P.CRC_TABLE
    assert sdk[:4] == [0x0000, 0x8005, 0x800F, 0x000A]


def test_stuffing_of_header_pattern():
    body = bytes((0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFF))
    assert P.stuff(body) == bytes((0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0xFF))
    assert P.unstuff(P.stuff(body)) == body
    # FF FF FD FD in the data stuffs to FF FF FD FD FD and back
    assert P.stuff(b"\xff\xff\xfd\xfd") == b"\xff\xff\xfd\xfd\xfd"
    assert P.unstuff(b"\xff\xff\xfd\xfd\xfd") == b"\xff\xff\xfd\xfd"


def test_stuff_roundtrip_random_bodies_never_contain_a_header():
    rng = np.random.default_rng(3)
    alphabet = np.array([0xFF, 0xFD, 0x00, 0x55], dtype=np.uint8)
    for _ in range(500):
        body = bytes(rng.choice(alphabet, size=int(rng.integers(1, 40))).tolist())
        stuffed = P.stuff(body)
        assert P.unstuff(stuffed) == body
        packet = P.instruction_packet(7, P.Instruction.WRITE, body)
        assert packet.count(P.HEADER) == 1  # a header can only start the packet
        (parsed,) = P.parse_packets(packet)
        assert parsed.crc_ok and parsed.params == body and parsed.id == 7


def test_extended_goal_needing_stuffing_from_sdk_and_from_builder(sdk):
    """-131073 = 0xFFFDFFFF puts FF FF FD in the params.

    dynamixel_sdk 4.1.0 transmits it *unstuffed*: ``txPacket`` ignores ``addStuffing``'s result
    when stuffing would lengthen the packet (it rebinds a local list). Our builder stuffs as the
    protocol says; the device-side parser must accept both, with the same value.
    """
    port, ph = sdk
    ph.write4ByteTxOnly(port, 1, 116, P.to_unsigned(-131073, 4))
    sent = bytes(port.ser.sent)
    body = bytes((P.Instruction.WRITE, 116, 0)) + P.le_bytes(-131073, 4)
    head = P.HEADER + bytes((1, len(body) + 2, 0))
    crc = P.crc16(head + body)
    assert sent == head + body + bytes((crc & 0xFF, crc >> 8))  # the SDK's (unstuffed) frame
    ours = P.instruction_packet(1, P.Instruction.WRITE, body[1:])
    assert b"\xff\xff\xfd\xfd" in ours and len(ours) == len(sent) + 1
    assert ours[5] | (ours[6] << 8) == len(ours) - 7  # LEN counts the stuffed bytes
    for frame in (sent, ours):
        (pkt,) = P.parse_packets(frame)
        assert pkt.crc_ok and pkt.params == body[1:]
        assert P.to_signed(int.from_bytes(pkt.params[2:6], "little"), 4) == -131073


def test_builder_matches_sdk_bytes_for_sync_write_and_read(sdk):
    port, ph = sdk
    ph.syncWriteTxOnly(port, 116, 4, [10, 1, 2, 3, 4, 11, 5, 6, 7, 8], 10)
    assert bytes(port.ser.sent) == P.instruction_packet(
        P.BROADCAST_ID, P.Instruction.SYNC_WRITE, bytes((116, 0, 4, 0, 10, 1, 2, 3, 4,
                                                          11, 5, 6, 7, 8)))
    port.ser.sent.clear()
    ph.syncReadTx(port, 126, 21, [10, 11, 12], 3, True)
    assert bytes(port.ser.sent) == P.instruction_packet(
        P.BROADCAST_ID, P.Instruction.FAST_SYNC_READ, bytes((126, 0, 21, 0, 10, 11, 12)))


def test_parser_skips_garbage_and_reports_corruption():
    a = P.status_packet(3, 0x80, b"\x01\x02")
    b = bytearray(P.status_packet(4, 0, b"\xff\xff\xfd\x07"))
    c = P.status_packet(5, 0x07)
    bad = bytearray(b)
    bad[-3] ^= 0x40
    reader = P.PacketReader()
    stream = b"\x00\xff\x12" + a + bytes(bad) + c
    for k in range(0, len(stream), 5):  # arrives in pieces
        reader.feed(stream[k:k + 5])
    out = list(reader)
    assert [(p.id, p.crc_ok) for p in out] == [(3, True), (4, False), (5, True)]
    assert out[0].error == 0x80 and out[0].data == b"\x01\x02"
    assert out[2].error == 0x07
    good = P.parse_packets(bytes(b))[0]
    assert good.data == b"\xff\xff\xfd\x07"  # un-stuffed


def test_fast_status_packet_layout_and_crc():
    slots = [(0, 10, b"\x01\x02"), (0x80, 11, b"\x03\x04")]
    pkt = P.fast_status_packet(slots)
    assert pkt[:8] == P.HEADER + bytes((0xFE, 1 + 2 * 6, 0, 0x55))
    assert len(pkt) == 8 + 2 * (2 + 4)
    assert P.crc16(pkt[:-2]) == pkt[-2] | (pkt[-1] << 8)  # last slot CRC = packet CRC
    # an absent second device: the header still announces both slots
    short = P.fast_status_packet(slots[:1], count=12)
    assert short[5] == 13 and len(short) == 8 + 6


@pytest.mark.parametrize("value,size", [(-1, 4), (-1, 2), (-2, 4), (-2147483648, 4),
                                        (2147483647, 4), (-32768, 2), (32767, 2), (-128, 1)])
def test_signed_roundtrip_is_exact_for_negatives(value, size):
    raw = P.to_unsigned(value, size)
    assert 0 <= raw < 1 << (8 * size)
    assert P.to_signed(raw, size) == value
    assert int.from_bytes(P.le_bytes(value, size), "little", signed=True) == value


def test_minus_one_is_not_off_by_one():
    # ROBEL's client encodes -1 as 2^32 - 2 and decodes it as -2; ours must not
    assert P.to_unsigned(-1, 4) == 0xFFFFFFFF
    assert P.to_signed(0xFFFFFFFF, 4) == -1
    assert P.to_signed(0xFFFFFFFE, 4) == -2
    with pytest.raises(ValueError):
        P.to_unsigned(1 << 32, 4)


def test_error_and_hardware_names():
    assert P.hardware_error_names(0x24) == ("overheating", "overload")
    assert P.hardware_error_names(0x02) == ("bit 1",)
    assert P.status_error_text(0x80) == "alert (hardware error latched)"
    assert P.status_error_text(0x86) == "data limit error, alert (hardware error latched)"
    assert P.status_error_text(0) == "ok"


def test_wire_byte_counts_and_time():
    assert P.sync_read_bytes(9, 21) == (23, 9 * 32)
    assert P.sync_read_bytes(9, 21, fast=True) == (23, 8 + 9 * 25)
    assert P.sync_write_bytes(9, 4) == 59
    assert P.wire_time(100, 1_000_000) == pytest.approx(1e-3)
    assert P.baud_code(4_000_000) == 6
    with pytest.raises(ValueError, match="valid"):
        P.baud_code(12345)
