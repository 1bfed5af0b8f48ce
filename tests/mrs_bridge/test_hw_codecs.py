"""The pure codecs of mrs_bridge/hw/ (P2OS packets, SCIP 2.0): round trips, checksums, truncated
and corrupted frames -- no port, no thread."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from mrs_bridge.hw import p2os, scip


# ---------------------------------------------------------------------------- P2OS
def sip_payload(x=100, y=200, th=300, lv=-5, rv=7, batt=125, sonars=((0, 40), (3, 900)), tail=True) -> bytes:
    head = struct.pack("<BHHhhhBHhHBB", p2os.SIP_MOVING, x, y, th, lv, rv, batt, 0x0101, 0, 1, 0, len(sonars))
    body = b"".join(struct.pack("<BH", n, r) for n, r in sonars)
    # TIMER (its high byte: the gripper state byte), ANALOG, DIGIN, DIGOUT, BATTERYX10, CHARGESTATE
    return head + body + (struct.pack("<HBBBHB", 0x15 << 8, 3, 0x0F, 0x02, 131, 1) if tail else b"")


def test_p2os_packet_round_trip_through_the_reader():
    payload = sip_payload()
    frame = p2os.packet(payload)
    assert frame[:2] == p2os.HEADER and frame[2] == len(payload) + 2
    assert int.from_bytes(frame[-2:], "big") == p2os.checksum(payload)
    r = p2os.PacketReader()
    assert r.feed(frame) == [payload]
    sip = p2os.decode_sip(payload)
    assert (sip.moving, sip.xpos, sip.ypos, sip.thpos, sip.l_vel, sip.r_vel) == (True, 100, 200, 300, -5, 7)
    assert sip.sonars == ((0, 40), (3, 900)) and sip.stalled and sip.motors_enabled
    assert (sip.gripper, sip.digin, sip.digout, sip.battery_x10, sip.charge_state) == (0x15, 0x0F, 0x02, 131, 1)
    assert sip.volts == pytest.approx(13.1)


def test_p2os_checksum_of_an_odd_payload_xors_the_last_byte():
    assert p2os.checksum(b"\x01\x02\x03") == (0x0102 ^ 0x03)
    assert p2os.checksum(b"\xff\xff\xff\xff") == 0xFFFE  # truncated to 16 bits


def test_p2os_string_command_frames_its_length():
    frame = p2os.command(p2os.SYNC2, "ab")
    assert frame[3:7] == bytes([p2os.SYNC2, p2os.ARG_STR, 2]) + b"a" and frame[7:8] == b"b"
    assert p2os.PacketReader().feed(frame) == [frame[3:-2]]


def test_p2os_truncated_frame_is_skipped_and_the_next_one_read():
    good = p2os.packet(sip_payload())
    r = p2os.PacketReader()
    assert r.feed(good[:-5]) == []  # waits for the rest
    assert r.feed(good) == [sip_payload()]  # the truncated one ran into this one: resynchronised
    assert r.bad == 1 and r.packets == 1


def test_p2os_header_split_across_reads_and_noise_counted():
    good = p2os.packet(bytes([p2os.SYNC0]))
    r = p2os.PacketReader()
    assert r.feed(b"noise" + good[:1]) == []
    assert r.feed(good[1:]) == [bytes([p2os.SYNC0])]
    assert r.skipped == 5


def test_p2os_corrupted_checksum_is_dropped():
    bad = bytearray(p2os.packet(b"\x32\x00"))
    bad[-1] ^= 0xFF
    r = p2os.PacketReader()
    assert r.feed(bytes(bad)) == [] and r.bad == 1


def test_p2os_sip_without_the_optional_tail():
    sip = p2os.decode_sip(sip_payload(tail=False, sonars=()))
    assert sip.gripper is None and sip.sonars == () and sip.volts == pytest.approx(12.5)


# ---------------------------------------------------------------------------- SCIP 2.0
def test_scip_values_round_trip_for_every_width():
    rng = np.random.default_rng(3)
    for n in (2, 3, 4):
        v = rng.integers(0, 1 << (6 * n), 50)
        assert np.array_equal(scip.decode_values(scip.encode_values(v, n), n), v)


def test_scip_scan_frame_round_trip_with_check_characters():
    mm = np.arange(20, 20 + 3 * 100, 3)
    stamp = scip.encode_values([1234], 4)
    assert len(stamp) == 4
    lines = [stamp + bytes([scip.check_char(stamp)])]
    lines += scip.data_lines(scip.encode_values(mm, 3))
    status = b"99" + bytes([scip.check_char(b"99")])
    raw = b"\n".join([b"MD0044072501000", status, *lines])
    ts, got = scip.decode_scan(scip.parse_frame(raw))
    assert ts == 1234 and np.array_equal(got, mm)
    assert all(len(ln) <= scip.LINE + 1 for ln in lines)


def test_scip_truncated_scan_and_bad_check_are_errors():
    data = scip.encode_values(np.arange(10), 3)
    line = scip.data_lines(data)[0]
    with pytest.raises(scip.ScipError, match="check character"):
        scip.parse_frame(b"GD\n00P\n" + line[:-2] + line[-1:])
    fr = scip.Frame(b"GD", b"00", (scip.encode_values([5], 4), data[:-1]))
    with pytest.raises(scip.ScipError, match="whole number"):
        scip.decode_scan(fr)
    with pytest.raises(scip.ScipError, match="outside the SCIP range"):
        scip.decode_values(b"\x20\x30\x30", 3)


def test_scip_pp_fields_fill_the_params():
    fields = {"MODL": "UTM-30LX(Hokuyo)", "DMIN": "23", "DMAX": "60000", "ARES": "1440", "AFRT": "540"}
    pp = scip.params_from_pp(fields, scip.MODELS["URG-04LX"])
    assert (pp.model, pp.dmin, pp.dmax, pp.ares, pp.afrt) == ("UTM-30LX", 23, 60000, 1440, 540)
    assert pp.amin == scip.MODELS["URG-04LX"].amin  # missing: the fallback's
    assert pp.step(pp.angle(700)) == 700
