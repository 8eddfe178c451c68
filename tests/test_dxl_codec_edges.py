"""Protocol 2.0 codec edges a user relies on, with the vendor's numbers typed in.

Byte traces are the ROBOTIS e-Manual's Protocol 2.0 examples (emanual.robotis.com, "DYNAMIXEL
Protocol 2.0", sections Ping / Read / Write / Sync Read: ID 1 is an XM430-W210, Goal Position is
address 116 = 0x74, Present Position 132 = 0x84; also reference 05-dynamixel-protocol.md section 3
and section 4's control table). Limits are dynamixel_sdk 4.1.0's
(``protocol2_packet_handler.RXPACKET_MAX_LEN = 1 * 1024``). Long packets are checked against the
bytes the SDK itself transmits. None of the expected numbers is read from the project's constants.
"""

from __future__ import annotations

import heapq

import pytest
from dynamixel_sdk import PacketHandler
from test_dxl_protocol import CapturePort

from lowcostdex.hardware.dynamixel import protocol as P

# e-Manual Protocol 2.0 examples (XM430-W210, ID 1)
PING_INST = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
PING_STATUS = bytes.fromhex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")  # model 1030, fw 38
READ_INST = bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")  # 4 bytes at 132
READ_STATUS = bytes.fromhex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")  # 166
WRITE_INST = bytes.fromhex("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")  # 512 at 116
WRITE_STATUS = bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C")  # no params, no error
# e-Manual Sync Read example, the reply of ID 2 (Present Position 2079)
SYNC_READ_STATUS_2 = bytes.fromhex("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")
SDK_RXPACKET_MAX_LEN = 1024  # dynamixel_sdk 4.1.0 protocol2_packet_handler


def _sdk_bytes(send) -> bytes:
    port = CapturePort("capture")
    port.openPort()
    send(port, PacketHandler(2.0))
    return bytes(port.ser.sent)


# -- building -------------------------------------------------------------------------------------


def test_emanual_instruction_and_status_packets_are_built_byte_for_byte():
    assert P.instruction_packet(1, P.Instruction.READ, bytes((0x84, 0x00, 0x04, 0x00))) \
        == READ_INST
    assert P.instruction_packet(1, P.Instruction.WRITE,
                                bytes((0x74, 0x00)) + (512).to_bytes(4, "little")) == WRITE_INST
    assert P.status_packet(1, 0, (166).to_bytes(4, "little")) == READ_STATUS
    assert P.status_packet(2, 0, (2079).to_bytes(4, "little")) == SYNC_READ_STATUS_2
    # the status of a WRITE carries no error and no parameters: what status_packet(id) sends
    assert P.status_packet(1) == WRITE_STATUS
    assert P.status_packet(1, 0) == WRITE_STATUS


def test_a_packet_longer_than_255_bytes_carries_the_high_length_byte_like_the_sdks():
    # WRITE of 300 data bytes: LEN = 1 (inst) + 2 (addr) + 300 + 2 (crc) = 305 = 0x0131, the
    # first length that needs LEN_H (e-Manual: LEN is two bytes, little-endian)
    data = bytes((i * 7 + 1) % 251 for i in range(300))  # no FF FF FD: nothing to stuff
    sent = _sdk_bytes(lambda port, ph: ph.writeTxOnly(port, 1, 168, 300, list(data)))
    ours = P.instruction_packet(1, P.Instruction.WRITE, bytes((168, 0)) + data)
    assert sent[5:7] == bytes((0x31, 0x01))
    assert ours == sent
    (pkt,) = P.parse_packets(ours)
    assert pkt.crc_ok and pkt.id == 1 and pkt.instruction == 0x03
    assert pkt.params == bytes((168, 0)) + data and pkt.size == len(sent) == 7 + 305
    # a status packet that long: LEN = 0x55 + error + 300 + crc = 304 = 0x0130
    st = P.status_packet(3, 0, data)
    assert st[5:7] == bytes((0x30, 0x01)) and len(st) == 7 + 304
    (pkt,) = P.parse_packets(st)
    assert pkt.crc_ok and pkt.data == data


def test_a_fast_sync_read_reply_of_30_devices_announces_its_length_in_two_bytes():
    # reference 05 section 3: LEN = 1 + N (L + 4), total 8 + N (L + 4); N 30, L 6 -> 301 = 0x012D
    slots = [(0, i + 1, bytes(6)) for i in range(30)]
    pkt = P.fast_status_packet(slots)
    assert pkt[4] == 0xFE and pkt[5:7] == bytes((0x2D, 0x01)) and pkt[7] == 0x55
    assert len(pkt) == 8 + 30 * 10
    assert PacketHandler(2.0).updateCRC(0, list(pkt[:-2]), len(pkt) - 2) \
        == pkt[-2] | (pkt[-1] << 8)


# -- CRC ------------------------------------------------------------------------------------------


def test_crc_of_any_iterable_of_byte_values():
    # crc16 takes bytes or any iterable of ints (its signature): the CRC-16/BUYPASS check value
    assert P.crc16(list(b"123456789")) == 0xFEE8
    assert P.crc16(iter(b"123456789")) == 0xFEE8
    assert P.crc16(bytearray(b"123456789")) == 0xFEE8
    assert P.crc16(memoryview(b"123456789")) == 0xFEE8
    assert P.crc16(tuple(PING_INST[:-2])) == 0x4E19


# -- parsing --------------------------------------------------------------------------------------


def test_parsed_emanual_packets_give_id_instruction_params_and_size():
    for raw, (pid, inst, params) in [
            (PING_INST, (1, 0x01, b"")),  # LEN 3: the shortest instruction packet
            (READ_INST, (1, 0x02, bytes((0x84, 0, 4, 0)))),
            (WRITE_INST, (1, 0x03, bytes((0x74, 0, 0, 2, 0, 0)))),
            (WRITE_STATUS, (1, 0x55, b"\x00")),  # LEN 4: the shortest status packet
            (PING_STATUS, (1, 0x55, bytes((0, 0x06, 0x04, 0x26)))),
            (SYNC_READ_STATUS_2, (2, 0x55, bytes((0, 0x1F, 0x08, 0, 0))))]:
        (pkt,) = P.parse_packets(raw)
        assert (pkt.id, pkt.instruction, pkt.params, pkt.crc_ok, pkt.size) \
            == (pid, inst, params, True, len(raw))
    (pkt,) = P.parse_packets(PING_STATUS)
    assert int.from_bytes(pkt.data[:2], "little") == 1030  # XM430-W210's model number


def test_a_packet_fed_one_byte_at_a_time_is_parsed_once_complete():
    # a header split across reads (serial reads return whatever has arrived)
    reader = P.PacketReader()
    out = []
    stream = WRITE_STATUS + READ_STATUS
    for k in range(len(stream)):
        reader.feed(stream[k:k + 1])
        got = list(reader)
        out += got
        if k + 1 < len(WRITE_STATUS):
            assert got == []
    assert [(p.id, p.params, p.size) for p in out] == [
        (1, b"\x00", 11), (1, bytes((0, 0xA6, 0, 0, 0)), 15)]


def test_garbage_before_a_split_header_keeps_the_header_bytes():
    reader = P.PacketReader()
    reader.feed(b"\x12\x34\x56\x78" + READ_STATUS[:3])  # garbage, then FF FF FD
    assert list(reader) == []
    reader.feed(READ_STATUS[3:])
    (pkt,) = list(reader)
    assert pkt.crc_ok and pkt.data == (166).to_bytes(4, "little")


@pytest.mark.parametrize("length", [0, 1, 2, SDK_RXPACKET_MAX_LEN + 1, 0xFFFF])
def test_a_false_header_with_an_impossible_length_does_not_hold_up_the_next_packet(length):
    # LEN < 3 cannot hold an instruction and a CRC; LEN > 1024 is rejected by the SDK: such a
    # "header" is line noise and the packet behind it comes out at once, in the same pass
    junk = P.HEADER + bytes((1, length & 0xFF, length >> 8))
    reader = P.PacketReader()
    reader.feed(junk + WRITE_STATUS)
    assert [(p.id, p.params, p.crc_ok) for p in reader] == [(1, b"\x00", True)]


def test_the_largest_length_the_sdk_accepts_is_parsed():
    params = bytes((i * 5 + 2) % 251 for i in range(SDK_RXPACKET_MAX_LEN - 4))
    st = P.status_packet(7, 0, params)  # LEN = 0x55 + err + 1020 + CRC = 1024
    assert st[5] | (st[6] << 8) == SDK_RXPACKET_MAX_LEN
    (pkt,) = P.parse_packets(st)
    assert pkt.crc_ok and pkt.data == params and pkt.size == 7 + SDK_RXPACKET_MAX_LEN


def test_a_corrupted_packet_reports_its_instruction_raw_params_and_size():
    # the emulator answers a corrupted unicast instruction with a CRC error for that
    # instruction: the instruction byte of a bad packet is still reported
    bad = bytearray(WRITE_INST)
    bad[-1] ^= 0x01
    stuffed_body = bytes((0x74, 0x00)) + b"\xff\xff\xfd\x00"  # Goal Position -131073 = 0xFFFDFFFF
    good = P.instruction_packet(1, P.Instruction.WRITE, stuffed_body)
    bad2 = bytearray(good)
    bad2[-2] ^= 0x80
    out = P.parse_packets(bytes(bad) + bytes(bad2) + WRITE_STATUS)
    assert [(p.crc_ok, p.id, p.instruction, p.size) for p in out] == [
        (False, 1, 0x03, 16), (False, 1, 0x03, len(good)), (True, 1, 0x55, 11)]
    assert out[0].params == bytes((0x74, 0, 0, 2, 0, 0))
    assert out[1].params == bytes((0x74, 0x00)) + b"\xff\xff\xfd\xfd\x00"  # raw: still stuffed


# -- values ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("value,size", [(-129, 1), (-32769, 2), (-(1 << 31) - 1, 4)])
def test_a_value_below_the_signed_range_does_not_fit(value, size):
    # two's complement in n bytes holds -2^(8n-1) .. 2^(8n)-1 (signed or unsigned use);
    # int16 goal current -32769 must not wrap to +32767
    with pytest.raises(ValueError, match=rf"{value} does not fit in {size} bytes"):
        P.to_unsigned(value, size)
    assert P.to_unsigned(value + 1, size) == 1 << (8 * size - 1)


def test_unknown_error_numbers_are_named_by_number():
    # e-Manual: error numbers 1-7 are defined; anything else is reported with its number
    assert P.status_error_text(0x09) == "unknown error 9"
    assert P.status_error_text(0x89) == "unknown error 9, alert (hardware error latched)"
    assert P.status_error_text(0x03) == "crc error"


def test_replies_due_at_the_same_time_leave_in_the_order_they_were_sent():
    a, b, c = P.Reply(1e-3, b"a", seq=0), P.Reply(1e-3, b"b", seq=1), P.Reply(0.5e-3, b"c", seq=2)
    assert sorted([b, c, a]) == [c, a, b]
    heap = []
    for r in (b, a, c):
        heapq.heappush(heap, r)
    assert [heapq.heappop(heap).data for _ in range(3)] == [b"c", b"a", b"b"]
    # strict order: a reply is not before itself (sorting keeps equal keys in arrival order)
    assert not (a < a)
    twin = P.Reply(1e-3, b"twin", seq=0)
    assert [r.data for r in sorted([a, twin])] == [b"a", b"twin"]
    assert [r.data for r in sorted([twin, a])] == [b"twin", b"a"]
