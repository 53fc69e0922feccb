"""Telemetry in: decoders against the real captures and against packets built from the published
layouts, the receiver on real loopback sockets (garbage, NaN, flood), and the staleness fade."""

from __future__ import annotations

import ipaddress
import itertools
import math
import socket
import struct
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import formats, replay
from carfeel.telemetry.formats import FORMATS, FORZA_MAX_ORDINAL, Format, G, encode_carfeel
from carfeel.telemetry.receiver import MAX_PER_POLL, Receiver, Source
from carfeel.telemetry.source import FADE_S, STALE_AFTER_S, VehicleSource
from carfeel.telemetry.state import BAD, NEUTRAL, REVERSE, VehicleState, plausible
from tests.datafiles import data_file

CAPTURE_RATE_HZ = 60.0
"""Both captures: AC's lapTime steps 16-20 ms, Forza's README says 60 Hz."""


def ac_capture() -> Path:
    return data_file("telemetry", "assetto-corsa-rtcarinfo-monza.raw")


def forza_capture() -> Path:
    return data_file("telemetry", "forza-motorsport-2023-dash.raw")


def _packets(path: Path, size: int) -> list[bytes]:
    return replay.datagrams(path, size)


def _drain(receiver: Receiver, until: float, expected: int) -> list[VehicleState]:
    """Poll in a tight, bounded loop; every good state, in order, through the poll's sink (two
    datagrams arriving between polls are both kept: the latest-of-a-poll lost one)."""
    states: list[VehicleState] = []
    while time.monotonic() < until and receiver.packets < expected:
        receiver.poll(states.append)
        time.sleep(0.0002)
    return states


# --- the real captures ------------------------------------------------------------------------


def test_assetto_capture_decodes_to_si_units() -> None:
    packets = _packets(ac_capture(), 328)
    assert len(packets) == 2000  # datagrams 1500..3499 of the published 8641 (tests/data)
    states = [formats.decode_datagram(FORMATS["assetto"], p, VehicleState()) for p in packets]
    assert all(s is not None and plausible(s) for s in states)  # every real packet is good
    for p, s in zip(packets, states, strict=True):
        assert s is not None
        # speed_Ms against speed_Kmh / 3.6: float32 rounding of both, so 1e-3 m/s.
        assert s.speed_m_s == pytest.approx(formats.assetto_speed_kmh(p) / 3.6, abs=1e-3)
    gears = {s.gear for s in states if s is not None}
    assert gears <= {NEUTRAL, 1, 2, 3, 4, 5}  # raw 1..6 (1 = neutral) as the README's 1-6
    ay = [s.lateral_accel_m_s2 for s in states if s is not None]
    # README: accG_horizontal -1.1..1.9 g (the slice holds both extremes); Ay is its opposite
    # (left positive), in m/s^2.
    assert min(ay) == pytest.approx(-1.86 * G, abs=0.05 * G)
    assert max(ay) == pytest.approx(1.11 * G, abs=0.05 * G)
    rpm = [s.engine_speed_rpm for s in states if s is not None]
    assert 7000 < max(rpm) < 8500
    steer = [abs(s.steering_angle_rad) for s in states if s is not None]
    assert math.radians(250) < max(steer) < math.radians(320)  # "about +-300 deg"
    assert all(0.0 <= s.clutch_pedal <= 1.0 for s in states if s is not None)
    assert all(math.isnan(s.time_s) for s in states if s is not None)  # RTCarInfo has no clock


def test_forza_capture_decodes_to_si_units() -> None:
    packets = _packets(forza_capture(), 331)
    assert len(packets) == 1793
    states = [formats.decode_datagram(FORMATS["forza"], p, VehicleState()) for p in packets]
    ok = [s for s in states if s is not None and plausible(s)]
    assert len(ok) == len(packets)  # IsRaceOn = 1 throughout; every real packet is good
    for p, s in zip(packets, ok, strict=True):
        # Speed against the local velocity's magnitude: both float32, 1e-3 m/s.
        assert s.speed_m_s == pytest.approx(formats.forza_velocity_speed(p), abs=1e-3)
    assert {s.gear for s in ok} == {3, 4, 5, NEUTRAL}  # 11 in the raw data is neutral
    assert max(s.speed_m_s for s in ok) == pytest.approx(60.0, abs=1.0)
    # Ay against speed x yaw rate, equal in a steady turn (the sideslip's rate makes the rest):
    # measured here 0.99 correlation, 0.82 m/s^2 rms apart, the same sign in 99.6 % of the
    # samples with |Ay| > 3 m/s^2, median 5 % apart. The bounds leave margin for all four.
    ay = [s.lateral_accel_m_s2 for s in ok]
    derived = [s.speed_m_s * s.yaw_rate_rad_s for s in ok]
    rms = math.sqrt(sum((a - d) ** 2 for a, d in zip(ay, derived, strict=True)) / len(ay))
    assert rms < 1.2
    turning = [(a, d) for a, d in zip(ay, derived, strict=True) if abs(a) > 3.0]
    assert len(turning) > 1000
    assert sum(a * d > 0 for a, d in turning) > 0.98 * len(turning)
    apart = sorted(abs(d - a) / abs(a) for a, d in turning)
    assert apart[len(apart) // 2] < 0.1
    assert max(abs(s.lateral_accel_m_s2) for s in ok) < 2.5 * G
    assert {s.car for s in ok} == {"445"} and all(s.cylinders == 6 for s in ok)
    # The packets' own clock (TimestampMS, whole ms): 60 Hz, so 15-17 ms apart, or 31-32 ms
    # where the capture itself missed one (124 times); 29.9 s from first to last.
    steps = [round((b.time_s - a.time_s) * 1000) for a, b in itertools.pairwise(ok)]
    assert set(steps) == {15, 16, 31, 32} and sum(d > 20 for d in steps) == 124
    assert ok[-1].time_s - ok[0].time_s == pytest.approx(29.937, abs=1e-3)


def _serve_assetto(
    packets: list[bytes], rate_hz: float, sent: list[int] | None = None
) -> tuple[tuple[str, int], threading.Thread]:
    bound: list[tuple[str, int]] = []
    ready = threading.Event()
    counts = sent if sent is not None else []

    def on_ready(address: tuple[str, int]) -> None:
        bound.append(address)
        ready.set()

    def serve() -> None:
        counts.append(
            replay.serve_assetto(
                packets, ("127.0.0.1", 0), rate_hz, car="ks_audi_r8_lms", wait_s=5.0,
                ready=on_ready,
            )
        )  # fmt: skip

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    assert ready.wait(5.0)
    return bound[0], thread


def test_assetto_replayed_over_loopback_handshake_subscribe_dismiss() -> None:
    packets = _packets(ac_capture(), 328)[1500:1620]  # 2 s at the capture's rate
    (host, port), thread = _serve_assetto(packets, CAPTURE_RATE_HZ)
    with Receiver(Source.parse(f"assetto:{host}:{port}")) as receiver:
        states = _drain(receiver, time.monotonic() + 6.0, len(packets))
        assert receiver.subscribed
        assert receiver.car == "ks_audi_r8_lms"
    thread.join(5.0)
    assert not thread.is_alive()
    assert receiver.packets == len(packets)  # none dropped at 60 Hz
    expected = [formats.decode_assetto(p, VehicleState()) for p in packets]
    # Every packet, in order, as decoded offline, with the car's name from the handshake.
    assert states == [e._replace(car="ks_audi_r8_lms") for e in expected if e is not None]


def test_assetto_dismiss_stops_the_stream() -> None:
    """The client's dismiss on close stops the game's stream (600 packets, 10 s, cut at 30)."""
    packets = _packets(ac_capture(), 328)[:600]
    sent: list[int] = []
    (host, port), thread = _serve_assetto(packets, CAPTURE_RATE_HZ, sent)
    with Receiver(Source.parse(f"assetto:{host}:{port}")) as receiver:
        _drain(receiver, time.monotonic() + 5.0, 30)
    thread.join(2.0)  # 2 s: the server sees the dismiss at its next packet (17 ms)
    assert not thread.is_alive()
    assert sent and sent[0] < 100


def test_forza_replayed_over_loopback_no_packet_dropped() -> None:
    packets = _packets(forza_capture(), 331)[:120]  # 2 s at the capture's rate
    with Receiver(Source.parse("forza:127.0.0.1:0")) as receiver:
        sender = threading.Thread(
            target=replay.send, args=(packets, receiver.address, CAPTURE_RATE_HZ), daemon=True
        )
        sender.start()
        states = _drain(receiver, time.monotonic() + 6.0, len(packets))
        sender.join(5.0)
    assert receiver.packets == len(packets)  # none dropped
    assert receiver.bad == 0
    expected = [formats.decode_forza(p, VehicleState()) for p in packets]
    assert states == expected  # every packet, in order, as decoded offline


def test_forza_horizon_and_sled_sizes_decode_the_same_fields() -> None:
    """FH4/5 insert 12 bytes between the sled and the dash (and end with a pad byte: 324);
    the sled alone has no dash."""
    p = _packets(forza_capture(), 331)[500]
    fm = formats.decode_forza(p, VehicleState())
    fh = formats.decode_forza(p[:232] + bytes(12) + p[232:311] + bytes(1), VehicleState())
    sled = formats.decode_forza(p[:232], VehicleState())
    assert fm == fh
    assert sled is not None and fm is not None
    assert sled.gear == NEUTRAL and math.isnan(sled.throttle)  # no dash: no gear or pedals
    assert sled.speed_m_s == pytest.approx(fm.speed_m_s, abs=1e-3)  # from the velocity


# --- formats without a capture: packets built from the published layouts ----------------------


def test_codemasters_extradata_reads_each_field_at_its_offset() -> None:
    """Every float used carries its own value, so a field read 4 bytes off (throttle from the
    steer) or two fields swapped (brake and clutch: the game's clutch drives the synchronizer)
    gives another number."""
    f = [0.0] * 66
    f[0], f[7], f[29], f[30], f[31], f[32], f[33], f[34], f[37], f[63], f[65] = (
        12.5, 25.0, 0.8, -0.3, 0.1, 0.6, 3.0, 0.5, 650.0, 800.0, 6.0,
    )  # fmt: skip
    f[28], f[35], f[36] = 0.45, 0.35, 0.25  # the neighbours: a read off by one shows
    s = formats.decode_codemasters(struct.pack("<66f", *f), VehicleState())
    assert s is not None and plausible(s)
    assert (s.speed_m_s, s.gear, s.engine_speed_rpm, s.engine_max_rpm) == (25.0, 3, 6500, 8000)
    assert s.lateral_accel_m_s2 == pytest.approx(-0.5 * G)
    # float32 of 0.8, 0.1, 0.6: 1e-7 relative.
    assert (s.throttle, s.brake, s.clutch_pedal) == pytest.approx((0.8, 0.1, 0.6), rel=1e-6)
    assert s.time_s == 12.5
    assert math.isnan(s.steering_angle_rad)  # a normalized input, not an angle
    f[33] = 10.0  # DiRT Rally 1's reverse
    r = formats.decode_codemasters(struct.pack("<66f", *f), VehicleState())
    assert r is not None and r.gear == REVERSE
    for index, value in ((33, 2.5), (33, math.nan), (33, 1e30), (65, 6.5), (37, -1.0)):
        g = list(f)
        g[index] = value  # a gear that is not whole, NaN (round() raised), a negative rpm
        assert formats.decode_codemasters(struct.pack("<66f", *g), VehicleState()) is BAD


def _f1_header(packet_id: int, player: int = 3, packet_format: int = 2023) -> bytes:
    return struct.pack(
        "<HBBBBBQfIIBB", packet_format, 23, 1, 0, 1, packet_id, 42, 61.5, 7, 7, player, 255
    )


UNIT = 32767  # the motion packet's direction vectors: unit vectors as int16


def _f1_motion(player: int = 3) -> bytes:
    cars = [struct.pack("<6f6h6f", *([0.0] * 6), 0, 0, UNIT, UNIT, 0, 0, *([0.0] * 6))] * 22
    cars[player] = struct.pack(
        "<6f6h6f", 100.0, 2.0, -50.0, 30.0, 0.0, 40.0, 0, 0, UNIT, UNIT, 0, 0,
        1.2, 0.1, 0.0, 0.6, 0.01, 0.0,
    )  # fmt: skip
    return _f1_header(0, player) + b"".join(cars)


def _f1_telemetry(player: int = 3, clutch: int = 50, gear: int = -1) -> bytes:
    cars = [bytes(60)] * 22
    cars[player] = struct.pack(
        "<HfffBbHBBH4H4B4BH4f4B", 180, 0.7, -0.2, 0.4, clutch, gear, 11000, 0, 50, 0,
        *([0] * 4), *([0] * 4), *([0] * 4), 90, *([0.0] * 4), *([0] * 4),
    )  # fmt: skip
    return _f1_header(6, player) + b"".join(cars) + bytes(3)


def test_f1_motion_and_telemetry_merge() -> None:
    motion, telemetry = _f1_motion(), _f1_telemetry()
    assert (len(motion), len(telemetry)) == (formats.F1_MOTION_SIZE, formats.F1_TELEMETRY_SIZE)
    s = formats.decode_f1(motion, VehicleState())
    assert s is not None and plausible(s)
    s = formats.decode_f1(telemetry, s)
    assert s is not None and plausible(s)
    assert s.speed_m_s == pytest.approx(50.0)  # |(30, 0, 40)|: the motion packet's, kept
    assert s.lateral_accel_m_s2 == pytest.approx(-1.2 * G, rel=1e-6)
    assert (s.gear, s.engine_speed_rpm, s.clutch_pedal) == (REVERSE, 11000.0, 0.5)
    # Throttle 0.7 and brake 0.4 with the steer (-0.2) between them: a swap or an offset shows.
    assert (s.throttle, s.brake) == pytest.approx((0.7, 0.4), rel=1e-6)  # float32
    assert s.time_s == 61.5  # the header's sessionTime
    assert formats.decode_f1(_f1_header(2) + bytes(100), s) is None  # another packet type
    older = _f1_header(6, packet_format=2022) + telemetry[29:]
    assert formats.decode_f1(older, s) is None  # an older game's layout: ignored, not misread
    assert formats.decode_f1(_f1_telemetry(clutch=101), s) is BAD  # clutch is 0..100
    assert formats.decode_f1(_f1_telemetry(gear=9), s) is BAD  # gears -1..8
    assert formats.decode_f1(motion[:20], s) is BAD  # shorter than a header
    garbage = bytes(range(256)) * 6
    assert formats.decode_f1(garbage[: formats.F1_MOTION_SIZE], s) is BAD  # not a header


def test_f1_player_index_picks_the_car() -> None:
    """The player's car is the header's index: the others' values are not read."""
    s = formats.decode_f1(_f1_motion(player=0), VehicleState())
    assert s is not None and s.speed_m_s == pytest.approx(50.0)
    assert formats.decode_f1(_f1_header(0, player=22) + bytes(1320), VehicleState()) is BAD


def test_outgauge_and_outsim_against_lfs_insim() -> None:
    """Packets packed by an independent implementation (lfs-insim, test-only) decode to the
    values it was given (float32: 1e-6 relative)."""
    packets = pytest.importorskip("lfs_insim.packets")
    gauge = packets.OutGaugePack(
        Time=1, Car="XRT", Gear=3, Speed=27.5, RPM=5200.0, Throttle=0.7, Brake=0.0, Clutch=0.25
    ).pack()
    s = formats.decode_outgauge(gauge, VehicleState())
    assert s is not None
    assert (s.gear, s.car) == (2, "XRT")
    assert s.speed_m_s == pytest.approx(27.5)
    assert s.engine_speed_rpm == pytest.approx(5200.0)
    assert s.clutch_pedal == pytest.approx(0.25)
    heading = 0.7
    vector = packets.Vector
    # A left turn at 20 m/s, Ay = 5 m/s^2 toward the car's left, (-cos h, -sin h) in the world.
    left = (-math.cos(heading), -math.sin(heading))
    sim = packets.OutSimPack(
        Time=1, AngVel=vector(X=0.0, Y=0.0, Z=0.25), Heading=heading,
        Accel=vector(X=5.0 * left[0], Y=5.0 * left[1], Z=0.0),
        Vel=vector(X=-20.0 * math.sin(heading), Y=20.0 * math.cos(heading), Z=0.0),
    ).pack()  # fmt: skip
    assert len(sim) in FORMATS["outsim"].sizes
    o = formats.decode_outsim(sim, VehicleState())
    assert o is not None and o.lateral_derived
    assert o.lateral_accel_m_s2 == pytest.approx(5.0, rel=1e-5)
    assert o.speed_m_s == pytest.approx(20.0, rel=1e-6)
    assert o.yaw_rate_rad_s == pytest.approx(0.25)


def test_beamng_motionsim_derives_ay_from_speed_and_yaw_rate() -> None:
    values = [0.0] * 21
    values[3:6] = [12.0, 16.0, 0.0]  # velocity: 20 m/s
    values[9:12] = [0.0, 0.0, 1.0]  # the up vector: a unit vector
    values[15:18] = [0.0, 0.0, 0.3]  # roll, pitch, yaw rate
    s = formats.decode_beamng(struct.pack("<4s21f", b"BNG1", *values), VehicleState())
    assert s is not None and s.lateral_derived and plausible(s)
    assert s.lateral_accel_m_s2 == pytest.approx(20.0 * 0.3, rel=1e-6)
    assert formats.decode_beamng(struct.pack("<4s21f", b"XXXX", *values), VehicleState()) is BAD
    values[9:12] = [0.0, 0.0, 0.0]  # no up vector: not a car's pose
    assert formats.decode_beamng(struct.pack("<4s21f", b"BNG1", *values), VehicleState()) is BAD


def test_carfeel_format_round_trip_and_version() -> None:
    state = VehicleState(12.5, 3.0, 0.24, 3100.0, 2, 0.0, 0.4, 0.0, 0.1)
    s = formats.decode_carfeel(encode_carfeel(state, 7, 1.5), VehicleState())
    assert s is not None
    assert s[:9] == pytest.approx(tuple(state[:9]), rel=1e-6)  # float32
    assert s.time_s == 1.5  # the sender's time (f64)
    packet = encode_carfeel(state, 2**32 + 5, 1.5)
    assert struct.unpack_from("<HI", packet, 6) == (0, 5)  # flags 0; the sequence wraps
    wrong = bytearray(encode_carfeel(state))
    wrong[4] = 2  # version 2: ours, but not this version: ignored, not misread
    assert formats.decode_carfeel(bytes(wrong), VehicleState()) is None
    assert formats.decode_carfeel(b"XXXX" + bytes(52), VehicleState()) is BAD  # not ours


# --- the receiver: bad input, flood, never blocking --------------------------------------------


def _sender() -> socket.socket:
    return socket.socket(socket.AF_INET, socket.SOCK_DGRAM)


def test_receiver_rejects_garbage_nan_and_keeps_good() -> None:
    with Receiver(Source.parse("carfeel:127.0.0.1:0")) as receiver, _sender() as s:
        to = receiver.address
        assert receiver.poll() == 0  # nothing waiting: returns at once
        s.sendto(b"\xff" * 13, to)  # wrong size
        s.sendto(encode_carfeel(VehicleState(speed_m_s=math.inf)), to)  # fails the checks
        s.sendto(encode_carfeel(VehicleState(speed_m_s=1e6)), to)  # beyond a car
        s.sendto(b"XXXX" + bytes(52), to)  # right size, not ours
        s.sendto(b"CRFL\x02" + bytes(51), to)  # ours, a later version
        s.sendto(encode_carfeel(VehicleState(speed_m_s=10.0, gear=3)), to)
        time.sleep(0.05)
        assert receiver.poll() == 1
        assert (receiver.bad, receiver.ignored, receiver.packets) == (4, 1, 1)
        assert receiver.latest.speed_m_s == 10.0
        assert receiver.errors == 0 and receiver.foreign == 0


def test_flood_is_bounded_per_poll() -> None:
    """5000 datagrams waiting: one poll reads at most MAX_PER_POLL (the kernel's small buffer
    drops the rest), so a flood costs the loop a bounded time per tick."""
    with Receiver(Source.parse("carfeel:127.0.0.1:0")) as receiver, _sender() as s:
        good = encode_carfeel(VehicleState(speed_m_s=5.0))
        for i in range(5000):
            s.sendto(good if i % 2 else b"garbage", receiver.address)
        before = receiver.bad + receiver.packets
        receiver.poll()
        assert receiver.bad + receiver.packets - before <= MAX_PER_POLL
        for _ in range(200):  # bounded: the backlog drains in a few polls
            receiver.poll()
        assert receiver.poll() == 0


def test_source_errors_are_clear() -> None:
    with pytest.raises(InputError, match="not one of"):
        Source.parse("gt7:127.0.0.1:33740")
    with pytest.raises(InputError, match="port"):
        Source.parse("forza:127.0.0.1:port")
    with Receiver(Source.parse("forza:127.0.0.1:0")) as r:
        host, port = r.address
        # The port in use names the fix: stop the other program or choose another port.
        with pytest.raises(InputError, match=f"in use.*Stop it.*forza:127.0.0.1:{port + 1}"):
            Receiver(Source.parse(f"forza:{host}:{port}"))


# --- staleness: stop, fade, recover ------------------------------------------------------------


def test_stale_stream_fades_and_recovers() -> None:
    """Simulated time, real packets: weight 1 while packets come; stopping the sender fades it
    to 0 within STALE_AFTER_S + FADE_S; restarting brings it back within FADE_S."""
    with _sender() as s:
        source = VehicleSource(Receiver(Source.parse("carfeel:127.0.0.1:0")))
        to = source.receiver.address
        packet = encode_carfeel(VehicleState(speed_m_s=20.0, lateral_accel_m_s2=2.0))
        weights = {}
        dt = 0.001
        for k in range(1500):  # 1.5 s of 1 ms ticks; 60 Hz packets but in 0.4..0.9 s
            t = k * dt
            if k % 17 == 0 and not 0.4 <= t < 0.9:
                s.sendto(packet, to)
                time.sleep(0.0005)  # loopback delivery is immediate; this is margin
            weights[k] = source.update(t)[1]
        source.close()
    assert weights[399] == 1.0
    stop = max(k for k in range(400) if k % 17 == 0) / 1000  # the last packet before the gap
    gone = round((stop + STALE_AFTER_S + FADE_S) * 1000) + 2  # + 2 ticks of rounding
    assert weights[gone] == 0.0
    assert 0.0 < weights[round((stop + STALE_AFTER_S + FADE_S / 2) * 1000)] < 1.0
    first = min(k for k in range(900, 1500) if k % 17 == 0) / 1000  # the first one after
    back = round((first + FADE_S) * 1000) + 2
    assert weights[back] == 1.0
    assert weights[back - 100] < 1.0  # it ramps back, no jump
    assert any("stale" in e for e in source.events) and any("back" in e for e in source.events)


def test_nan_in_a_needed_field_counts_as_no_data() -> None:
    with _sender() as s:
        source = VehicleSource(Receiver(Source.parse("carfeel:127.0.0.1:0")))
        for k in range(400):
            if k % 10 == 0:
                s.sendto(encode_carfeel(VehicleState()), source.receiver.address)  # all NaN
                time.sleep(0.0005)
            _, weight = source.update(k * 0.001)
            assert weight == 0.0
        source.close()


def _pack2(packets: Any, options: int, kwargs: dict[str, object]) -> tuple[bytes, Format]:
    """OutSimPack2 packed by lfs-insim with the parts these tests do not read filled in, and
    the format carfeel makes of the same options."""
    if options & 64:
        kwargs.update(CurrentLapDist=10.0, IndexedDistance=11.0)
    if options & 128:
        kwargs["OSWheels"] = [packets.OutSimWheel() for _ in range(4)]
    if options & 256:
        kwargs["SteerTorque"] = 2.0
    data = packets.OutSimPack2(**kwargs).pack()
    return data, Source.parse(f"outsim@{options:x}:127.0.0.1:0").format


@pytest.mark.parametrize("options", [0x1FF, 0x3D, 0x08])
def test_outsim_pack2_against_lfs_insim(options: int) -> None:
    """OutSimPack2 packed by lfs-insim with LFS's OutSim Opts decodes to what it was given."""
    packets = pytest.importorskip("lfs_insim.packets")
    vector = packets.Vector
    main = packets.OutSimMain(
        AngVel=vector(X=0.0, Y=0.0, Z=-0.2), Heading=0.0,
        Accel=vector(X=4.0, Y=0.0, Z=0.0), Vel=vector(X=0.0, Y=30.0, Z=0.0),
    )  # fmt: skip
    kwargs: dict[str, object] = {"OSOpts": options, "OSMain": main}
    if options & 2:
        kwargs["ID"] = 9
    if options & 4:
        kwargs["Time"] = 123
    if options & 16:
        kwargs["OSInputs"] = packets.OutSimInputs(Throttle=0.6, Brake=0.1, Clutch=0.9)
    if options & 32:
        kwargs.update(Gear=4, EngineAngVel=500.0, MaxTorqueAtVel=300.0)
    data, fmt = _pack2(packets, options, kwargs)
    assert len(data) in fmt.sizes
    s = fmt.decode(data, VehicleState())
    assert s is not None
    # Heading 0 faces +y; +x is the car's right: Ay = -4 (a right turn, yaw rate negative).
    assert s.lateral_accel_m_s2 == pytest.approx(-4.0)
    assert s.speed_m_s == pytest.approx(30.0)
    assert s.yaw_rate_rad_s == pytest.approx(-0.2)
    if options & 32:
        assert s.gear == 3
        assert s.engine_speed_rpm == pytest.approx(500.0 * 30 / math.pi, rel=1e-6)
    if options & 16:
        assert (s.throttle, s.brake, s.clutch_pedal) == pytest.approx((0.6, 0.1, 0.9))
    else:  # no OSO_INPUTS: no pedals (NaN, the model's own then)
        assert math.isnan(s.throttle) and math.isnan(s.brake) and math.isnan(s.clutch_pedal)
    if not options & 32:  # no OSO_DRIVE: neutral, no engine
        assert s.gear == NEUTRAL and math.isnan(s.engine_speed_rpm)
    assert (s.time_s == 0.123) if options & 4 else math.isnan(s.time_s)
    with pytest.raises(InputError, match="OSMain"):
        Source.parse("outsim@10:127.0.0.1:0")


# --- each plausibility check on its own: one field past the game's range is bad ---------------


def _with(packet: bytes, offset: int, layout: str, value: float | bytes) -> bytes:
    data = bytearray(packet)
    struct.pack_into(layout, data, offset, value)
    return bytes(data)


def _outgauge() -> bytes:
    return struct.pack("<I4sHBB7f2I3f16s16s", 1000, b"XRT", 0, 3, 0, 20.0, 5000.0,
                       *([0.5] * 5), 0, 0, 0.5, 0.0, 0.2, b"", b"")  # fmt: skip


def _outsim() -> bytes:
    return struct.pack("<I3f3f3f3f3i", 1000, 0.0, 0.0, 0.2, 0.7, 0.0, 0.0, 1.0, 2.0, 0.0,
                       -10.0, 14.0, 0.0, 0, 0, 0)  # fmt: skip


def _beamng() -> bytes:
    values = [0.0] * 21
    values[3:6] = [12.0, 16.0, 0.0]
    values[9:12] = [0.0, 0.0, 1.0]
    values[17] = 0.3
    return struct.pack("<4s21f", b"BNG1", *values)


def _codemasters() -> bytes:
    f = [0.0] * 66
    f[0], f[7], f[29], f[33], f[37], f[63], f[65] = 12.5, 25.0, 0.8, 3.0, 650.0, 800.0, 6.0
    return struct.pack("<66f", *f)


def _forza_sled() -> bytes:
    """The first real packet's sled, its velocity set to (10, 0, 0) (no dash to agree with)."""
    p = _packets(forza_capture(), 331)[0][:232]
    return _with(_with(_with(p, 32, "<f", 10.0), 36, "<f", 0.0), 40, "<f", 0.0)


def _assetto() -> bytes:
    return _packets(ac_capture(), 328)[0]


def _forza() -> bytes:
    return _packets(forza_capture(), 331)[0]


CHECKS: list[tuple[str, str, Any, int, str, Any, Any]] = [
    # format, what, packet, offset, layout, a value past the range, the bound itself (good)
    ("forza", "IsRaceOn", _forza, 0, "<i", 2, 1),
    ("forza", "a rumble flag", _forza, 124, "<i", 2, 1),
    ("forza", "car ordinal", _forza, 212, "<i", FORZA_MAX_ORDINAL + 1, FORZA_MAX_ORDINAL),
    ("forza", "car ordinal 0", _forza, 212, "<i", 0, 1),
    ("forza", "car class", _forza, 216, "<i", 16, 15),
    ("forza", "car class < 0", _forza, 216, "<i", -1, 0),
    ("forza", "performance index", _forza, 220, "<i", 1101, 1100),
    ("forza", "performance index < 0", _forza, 220, "<i", -1, 0),
    ("forza", "drivetrain", _forza, 224, "<i", 3, 2),
    ("forza", "drivetrain < 0", _forza, 224, "<i", -1, 0),
    ("forza", "cylinders", _forza, 228, "<i", 17, 16),
    ("forza", "cylinders < 0", _forza, 228, "<i", -1, 0),
    ("forza", "EngineMaxRpm", _forza, 8, "<f", 30_001.0, 30_000.0),
    ("forza", "EngineMaxRpm < 0", _forza, 8, "<f", -1.0, 0.0),
    ("forza", "EngineIdleRpm", _forza, 12, "<f", 30_001.0, 30_000.0),
    ("forza", "EngineIdleRpm < 0", _forza, 12, "<f", -1.0, 0.0),
    ("forza", "fuel", _forza, 232 + 44, "<f", 1.01, 1.0),
    ("forza", "fuel < 0", _forza, 232 + 44, "<f", -0.01, 0.0),
    ("forza", "gear", _forza, 232 + 75, "<B", 12, 11),
    ("forza", "velocity NaN", _forza_sled, 36, "<f", math.nan, 0.0),
    ("forza", "velocity x", _forza_sled, 32, "<f", 150.5, 149.5),
    ("assetto", "identifier", _assetto, 0, "<c", b"b", b"a"),
    ("assetto", "size", _assetto, 4, "<i", 327, 328),
    ("assetto", "a flag byte", _assetto, 22, "<B", 2, 1),
    ("assetto", "lap time < 0", _assetto, 40, "<i", -1, 0),
    ("assetto", "last lap < 0", _assetto, 44, "<i", -1, 0),
    ("assetto", "best lap < 0", _assetto, 48, "<i", -1, 0),
    ("assetto", "lap count < 0", _assetto, 52, "<i", -1, 0),
    ("assetto", "gear", _assetto, 76, "<i", 12, 11),
    ("assetto", "gear < 0", _assetto, 76, "<i", -1, 0),
    ("codemasters", "gear", _codemasters, 4 * 33, "<f", 10.5, 10.0),
    ("codemasters", "gear < -1", _codemasters, 4 * 33, "<f", -2.0, -1.0),
    ("codemasters", "gear count", _codemasters, 4 * 65, "<f", 13.0, 12.0),
    ("codemasters", "gear count not whole", _codemasters, 4 * 65, "<f", 5.5, 0.0),
    ("codemasters", "engine rate", _codemasters, 4 * 37, "<f", 3001.0, 3000.0),
    ("codemasters", "engine rate < 0", _codemasters, 4 * 37, "<f", -1.0, 0.0),
    ("codemasters", "max rpm", _codemasters, 4 * 63, "<f", 3001.0, 3000.0),
    ("codemasters", "max rpm < 0", _codemasters, 4 * 63, "<f", -1.0, 0.0),
    ("codemasters", "time", _codemasters, 0, "<f", 1.5e9, -9.9e8),
    ("codemasters", "steer", _codemasters, 4 * 30, "<f", 1.02, -1.0),
    ("outgauge", "car name", _outgauge, 4, "<4s", b"X\x01T\x00", b"beam"),
    ("outgauge", "car name after its end", _outgauge, 4, "<4s", b"X\x00T\x00", b"X\x00\x00\x00"),
    ("outgauge", "car name > 0x7e", _outgauge, 4, "<4s", b"X\x7f\x00\x00", b"X~ \x00"),
    ("outgauge", "gear", _outgauge, 10, "<B", 13, 12),
    ("outgauge", "fuel", _outgauge, 28, "<f", 1.01, 1.0),
    ("outgauge", "fuel < 0", _outgauge, 28, "<f", -0.01, 0.0),
    ("outsim", "roll rate", _outsim, 4, "<f", 50.5, -50.0),  # the yaw rate: plausible, 20
    ("outsim", "heading", _outsim, 16, "<f", 6.5, -6.3),
    ("outsim", "roll", _outsim, 24, "<f", -6.5, 6.3),
    ("outsim", "acceleration", _outsim, 36, "<f", 500.5, -500.0),
    ("outsim", "velocity", _outsim, 48, "<f", 150.5, -100.0),
    ("beamng", "up vector short", _beamng, 48, "<f", 0.94, 0.96),
    ("beamng", "up vector long", _beamng, 48, "<f", 1.06, 1.04),
    ("beamng", "up vector huge", _beamng, 40, "<f", 3.0, 0.0),
    ("beamng", "velocity", _beamng, 24, "<f", 150.5, 50.0),
    ("beamng", "acceleration", _beamng, 36, "<f", -500.5, -499.0),
    ("beamng", "an angle", _beamng, 60, "<f", 6.5, -6.3),
    ("beamng", "a rate", _beamng, 64, "<f", 50.5, -50.0),
    ("beamng", "position", _beamng, 4, "<f", 1.1e7, -9.9e6),
    ("beamng", "an angular acceleration", _beamng, 84, "<f", math.inf, 9.9e6),
]


@pytest.mark.parametrize(
    ("name", "what", "base", "offset", "layout", "bad", "good"), CHECKS, ids=[c[1] for c in CHECKS]
)
def test_each_check_alone_makes_a_packet_bad(
    name: str, what: str, base: Any, offset: int, layout: str, bad: Any, good: Any
) -> None:
    """A good packet with one field set past the game's range is bad; at the range's bound it
    is still good (so a check neither missing nor off by one passes)."""
    fmt, packet = FORMATS[name], base()
    assert plausible(formats.decode_datagram(fmt, packet, VehicleState()) or BAD), "the base"
    assert formats.decode_datagram(fmt, _with(packet, offset, layout, bad), VehicleState()) is BAD
    state = formats.decode_datagram(fmt, _with(packet, offset, layout, good), VehicleState())
    assert state is not None and plausible(state), what


def test_assetto_speed_fields_must_agree() -> None:
    """km/h against m/s x 3.6 and mph against km/h / 1.609 (1 % and 0.5 km/h of slack): one of
    the three off by 5 % is bad, each alone."""
    p = _assetto()
    kmh, mph, ms = struct.unpack_from("<3f", p, 8)
    fmt = FORMATS["assetto"]
    for values in ((kmh * 1.05, kmh * 1.05 / 1.609344, ms), (kmh, mph * 1.05, ms),
                   (kmh, mph, ms * 1.05)):  # fmt: skip
        data = bytearray(p)
        struct.pack_into("<3f", data, 8, *values)
        assert formats.decode_datagram(fmt, bytes(data), VehicleState()) is BAD, values
    data = bytearray(p)
    struct.pack_into("<3f", data, 8, kmh * 1.005, mph * 1.005, ms)  # within the slack
    assert plausible(formats.decode_datagram(fmt, bytes(data), VehicleState()) or BAD)


def test_forza_dash_speed_must_agree_with_the_velocity() -> None:
    p = _forza()
    speed = formats.forza_velocity_speed(p)
    fmt = FORMATS["forza"]
    assert formats.decode_datagram(fmt, _with(p, 244, "<f", speed + 1.0 + 0.06 * speed),
                                   VehicleState()) is BAD  # fmt: skip
    good = formats.decode_datagram(fmt, _with(p, 244, "<f", speed + 0.9), VehicleState())
    assert good is not None and plausible(good) and good.speed_m_s == pytest.approx(speed + 0.9)


@pytest.mark.parametrize(
    ("offset", "layout", "bad", "good", "what"),
    [
        (0, "<H", 2031, 2030, "packet format"),
        (0, "<H", 2016, 2023, "packet format, too early"),
        (6, "<B", 16, 15, "packet id"),
        (27, "<B", 22, 21, "player index"),
        (28, "<B", 22, 255, "second player"),
        (15, "<f", -0.5, 0.0, "session time"),
        (15, "<f", 1.5e9, 9.9e8, "session time, large"),
    ],
)
def test_f1_header_checks(offset: int, layout: str, bad: float, good: float, what: str) -> None:
    packet = _f1_motion()
    assert formats.decode_f1(_with(packet, offset, layout, bad), VehicleState()) is BAD, what
    state = formats.decode_f1(_with(packet, offset, layout, good), VehicleState())
    if what == "packet id":  # id 15 is another packet type: ignored, not bad
        assert state is None
    else:
        assert state is not None and plausible(state), what


@pytest.mark.parametrize(
    ("packet", "offset", "layout", "bad", "good", "what"),
    [
        ("motion", 233 + 4, "<h", 0, UNIT, "forward direction not a unit vector"),
        ("motion", 239, "<h", 0, UNIT, "right direction not a unit vector"),
        ("motion", 209, "<f", 1.5e5, -9.9e4, "position"),
        ("motion", 229, "<f", 150.5, 40.0, "velocity"),
        ("motion", 257, "<f", 6.5, -6.3, "yaw"),
        ("telemetry", 223, "<B", 101, 100, "clutch"),
        ("telemetry", 224, "<b", 9, 8, "gear"),
        ("telemetry", 224, "<b", -2, -1, "gear < -1"),
        ("telemetry", 227, "<B", 2, 1, "DRS"),
        ("telemetry", 228, "<B", 101, 100, "rev lights"),
        ("telemetry", 215, "<f", 1.02, -1.0, "steer"),
    ],
)
def test_f1_car_checks(
    packet: str, offset: int, layout: str, bad: float, good: float, what: str
) -> None:
    base = _f1_motion() if packet == "motion" else _f1_telemetry()
    last = VehicleState(speed_m_s=10.0)
    assert formats.decode_f1(_with(base, offset, layout, bad), last) is BAD, what
    state = formats.decode_f1(_with(base, offset, layout, good), last)
    assert state is not None and plausible(state), what


def test_f1_speed_from_telemetry_without_motion_and_the_sizes() -> None:
    """Without a motion packet first, the speed is the telemetry's km/h; a motion id at the
    telemetry's size (or the reverse) is bad; an F1 packet of any other size is ignored."""
    s = formats.decode_f1(_f1_telemetry(), VehicleState())
    assert s is not None and s.speed_m_s == pytest.approx(180 / 3.6)
    motion, telemetry = _f1_motion(), _f1_telemetry()
    assert formats.decode_f1(motion[:6] + b"\x06" + motion[7:], VehicleState()) is BAD
    assert formats.decode_f1(telemetry[:6] + b"\x00" + telemetry[7:], VehicleState()) is BAD
    assert formats.decode_f1(motion + bytes(10), VehicleState()) is None
    assert formats.decode_datagram(FORMATS["f1"], motion + bytes(10), VehicleState()) is None


@pytest.mark.parametrize("options", [0x1FF, 0x3D])
def test_outsim_pack2_checks(options: int) -> None:
    """OutSimPack2's own fields: the LFST header, inputs' steer and handbrake, the gear, and its
    Time as the packet's time stamp."""
    packets = pytest.importorskip("lfs_insim.packets")
    vector = packets.Vector
    main = packets.OutSimMain(AngVel=vector(X=0.0, Y=0.0, Z=0.1), Heading=0.2,
                              Accel=vector(X=1.0, Y=0.0, Z=0.0),
                              Vel=vector(X=0.0, Y=20.0, Z=0.0))  # fmt: skip
    kwargs: dict[str, object] = {"OSOpts": options, "OSMain": main, "Time": 4321,
                                 "OSInputs": packets.OutSimInputs(Throttle=0.5, Brake=0.0,
                                                                  InputSteer=0.2, Clutch=0.0,
                                                                  Handbrake=0.0),
                                 "Gear": 3, "EngineAngVel": 300.0,
                                 "MaxTorqueAtVel": 200.0}  # fmt: skip
    if options & 2:
        kwargs["ID"] = 1
    data, fmt = _pack2(packets, options, kwargs)
    state = fmt.decode(data, VehicleState())
    assert state is not None and plausible(state) and state.time_s == 4.321
    inputs = 4 * (bool(options & 1) + bool(options & 2) + bool(options & 4)) + 60
    drive = inputs + 20
    for offset, layout, bad in ((inputs + 8, "<f", 1.02), (inputs + 8, "<f", -1.5),
                                (inputs + 16, "<f", 1.02), (inputs + 16, "<f", -0.5),
                                (drive, "<B", 13), (inputs - 60, "<f", math.inf),
                                (inputs - 60 + 24, "<f", 9.0)):  # fmt: skip
        # (the last: an acceleration of 9 m/s^2 is not a pitch of 9 rad: a slice off by one)
        expected = BAD if offset != inputs - 60 + 24 else None
        decoded = fmt.decode(_with(data, offset, layout, bad), VehicleState())
        assert decoded is BAD if expected is BAD else plausible(decoded or BAD)
    geared = fmt.decode(_with(data, drive, "<B", 12), VehicleState())
    assert geared is not None and geared.gear == 11  # 12 is the last raw gear taken
    if options & 1:
        assert fmt.decode(b"LFSX" + data[4:], VehicleState()) is BAD


# --- sources: whom they accept, where they bind ------------------------------------------------


def test_sources_accept_the_games_host_by_default_and_what_they_are_told() -> None:
    net = ipaddress.IPv4Network
    local = Source.parse("forza:127.0.0.1:5300")
    assert (local.bind_host, local.accept) == ("127.0.0.1", (net("127.0.0.1/32"),))
    assert Source.parse("forza:5300").host == "127.0.0.1"  # FORMAT:PORT is on loopback
    assert Source.parse("forza").port == 5300  # the format's port
    named = Source.parse("forza:localhost:5300")
    assert named.bind_host == "127.0.0.1"  # looked up once, here
    assert Source.parse("forza:127.0.0.1:0,from=any").accept is None
    assert Source.parse("forza:127.0.0.1:0", accept_from="10.1.2.3/8").accept == (
        net("10.0.0.0/8"),
    )
    assert Source.parse("forza:127.0.0.1:0,from=10.0.0.1", accept_from="any").accept is None
    assert Source.parse("forza:0.0.0.0:0,from=localhost").accept == (net("127.0.0.1/32"),)
    wild = Source.parse("forza:0.0.0.0:0,from=192.168.1.20")
    assert wild.describe_accept() == "192.168.1.20" and wild.bind_host == "0.0.0.0"
    assert Source.parse("forza:0.0.0.0:0,from=192.168.1.0/24").describe_accept() == (
        "192.168.1.0/24"
    )
    assert Source.parse("forza:0.0.0.0:0,from=any").describe_accept() == "any address"
    for text, match in (
        ("forza:0.0.0.0:0", "every interface"),
        ("forza:0.0.0.0:0,from=", "one option"),
        ("forza:0.0.0.0:0,from=300.1.1.0/24", "not an IPv4 network"),
        ("forza:no-such-host.invalid:0", "unknown host"),
        ("forza:127.0.0.1:0,from=no-such-host.invalid", "unknown --accept-from host"),
        ("forza:127.0.0.1:70000", "not a number 0..65535"),
        ("assetto:127.0.0.1:0", "the game's port"),
    ):
        with pytest.raises(InputError, match=match):
            Source.parse(text)


def test_assetto_binds_the_interface_that_reaches_the_game() -> None:
    """Loopback for a game on this machine; for one elsewhere the interface the system routes
    to it by (never 127.0.0.1, and no longer 0.0.0.0 unless nothing routes there), accepting
    the game's address only; refused where the network is not allowed (the local panel)."""
    local = Source.parse("assetto:127.0.0.1:9996")
    assert local.bind_host == "127.0.0.1"
    assert local.accept == (ipaddress.IPv4Network("127.0.0.1/32"),)
    remote = Source.parse("assetto:192.0.2.7:9996")  # TEST-NET-1: routed, never answered
    assert remote.bind_host != "127.0.0.1"
    assert remote.accept == (ipaddress.IPv4Network("192.0.2.7/32"),)
    with pytest.raises(InputError, match="started for this machine only"):
        Source.parse("assetto:192.0.2.7:9996", network=False)
    assert Source.parse("assetto:127.0.0.1:9996", network=False).bind_host == "127.0.0.1"


def test_the_receiver_accepts_by_network_and_remembers() -> None:
    source = Source.parse("carfeel:127.0.0.1:0,from=10.0.0.0/8")
    with Receiver(source) as receiver:
        assert receiver.accepts("10.200.1.2") and not receiver.accepts("11.0.0.1")
        assert not receiver.accepts("not-an-address")
        assert receiver.accepts("10.200.1.2")  # the memo's answer is the same
        for _ in range(3):
            receiver._foreign("11.0.0.1")
        for k in range(20):
            receiver._foreign(f"12.0.0.{k}")
        assert receiver.foreign == 23 and len(receiver.foreign_from) == 8
        assert receiver.foreign_from["11.0.0.1"] == 3
        text = receiver.counts()
        assert "23 from addresses not accepted" in text and "11.0.0.1 (3)" in text
        assert ", ...;" in text and "accepted: 10.0.0.0/8" in text


def test_gear_names() -> None:
    from carfeel.telemetry.state import gear_name

    assert [gear_name(g) for g in (-1, 0, 1, 6)] == ["R", "N", "1", "6"]


def test_outgauge_fields_and_gears() -> None:
    """Gear 0 R, 1 N, 2 first; Time in ms is the packet's stamp; the car's name stops at its
    first NUL; no Ay (NaN, the steering fades), nothing derived."""
    base = _outgauge()
    for raw, gear in ((0, REVERSE), (1, NEUTRAL), (2, 1), (7, 6)):
        s = formats.decode_outgauge(_with(base, 10, "<B", raw), VehicleState())
        assert s is not None and s.gear == gear
    s = formats.decode_outgauge(_with(base, 4, "<4s", b"XR\x00\x00"), VehicleState())
    assert s is not None and s.car == "XR" and s.time_s == 1.0
    assert math.isnan(s.lateral_accel_m_s2) and not s.lateral_derived and s.cylinders == 0
    assert (s.throttle, s.brake, s.clutch_pedal) == pytest.approx((0.5, 0.0, 0.2))


def test_outsim_pack2_reads_every_part_where_the_options_put_it() -> None:
    """A pose where heading, pitch and roll differ, and every input differs: each value comes
    from its own field (a slice off by one, or the pitch for the heading, gives another)."""
    packets = pytest.importorskip("lfs_insim.packets")
    vector = packets.Vector
    heading = 0.9
    left = (-math.cos(heading), -math.sin(heading))
    main = packets.OutSimMain(
        AngVel=vector(X=0.05, Y=-0.04, Z=0.3), Heading=heading, Pitch=0.1, Roll=-0.2,
        Accel=vector(X=3.0 * left[0], Y=3.0 * left[1], Z=9.0),
        Vel=vector(X=-20.0 * math.sin(heading), Y=20.0 * math.cos(heading), Z=0.5),
    )  # fmt: skip
    inputs = packets.OutSimInputs(Throttle=0.7, Brake=0.2, InputSteer=-0.3, Clutch=0.4,
                                  Handbrake=0.1)  # fmt: skip
    data = packets.OutSimPack2(OSOpts=0x3D, OSMain=main, Time=2500, OSInputs=inputs, Gear=0,
                               EngineAngVel=400.0, MaxTorqueAtVel=100.0).pack()  # fmt: skip
    fmt = Source.parse("outsim@3d:127.0.0.1:0").format
    s = fmt.decode(data, VehicleState())
    assert s is not None and plausible(s) and s.lateral_derived
    assert s.lateral_accel_m_s2 == pytest.approx(3.0, rel=1e-5)  # float32
    assert s.speed_m_s == pytest.approx(math.hypot(20.0, 0.5), rel=1e-6)
    assert s.yaw_rate_rad_s == pytest.approx(0.3, rel=1e-6)
    assert (s.throttle, s.brake, s.clutch_pedal) == pytest.approx((0.7, 0.2, 0.4), rel=1e-6)
    assert s.gear == REVERSE and s.time_s == 2.5 and s.car == "" and s.cylinders == 0
    assert s.engine_speed_rpm == pytest.approx(400.0 * 30 / math.pi, rel=1e-6)
    assert fmt.name == "outsim@3d" and fmt.default_port == 4123 and "3d" in fmt.describe
    neutral = fmt.decode(_with(data, 4 + 4 + 60 + 20, "<B", 1), VehicleState())
    assert neutral is not None and neutral.gear == NEUTRAL
    with pytest.raises(InputError, match="OSMain"):
        Source.parse("outsim@208:127.0.0.1:0")  # a bit above 0x100 (no such part)
    assert Source.parse("outsim@1ff:127.0.0.1:0").format.sizes == frozenset({280})


def test_beamng_up_vector_any_direction() -> None:
    """The up vector's length, whatever its direction: (0.6, 0, 0.8) is a unit vector, (0.6,
    0.6, 0.8) is not."""
    base = _beamng()
    tilted = _with(_with(base, 40, "<f", 0.6), 48, "<f", 0.8)
    s = formats.decode_beamng(tilted, VehicleState())
    assert s is not None and plausible(s)
    assert formats.decode_beamng(_with(tilted, 44, "<f", 0.6), VehicleState()) is BAD
    assert formats.decode_beamng(_with(base, 40, "<f", 0.6), VehicleState()) is BAD  # 1.17


def test_a_source_on_an_address_this_machine_lacks_says_so() -> None:
    with pytest.raises(InputError, match="no interface of this machine has that address"):
        Receiver(Source.parse("forza:192.0.2.1:0,from=any"))


def test_what_each_model_needs_of_the_state() -> None:
    """The paper's law needs the speed and Ay or, failing it, the yaw rate (AC, Codemasters and
    F1 send Ay and no yaw rate; BeamNG the reverse); the H-pattern the speed and rpm."""
    from carfeel.telemetry.driving import hpattern_needs, speed_needs, steering_needs

    nan = math.nan
    assert steering_needs(VehicleState(speed_m_s=10.0, lateral_accel_m_s2=2.0))
    assert steering_needs(VehicleState(speed_m_s=10.0, yaw_rate_rad_s=0.1))
    assert not steering_needs(VehicleState(speed_m_s=10.0))
    assert not steering_needs(VehicleState(speed_m_s=nan, lateral_accel_m_s2=2.0))
    assert speed_needs(VehicleState(speed_m_s=0.0)) and not speed_needs(VehicleState())
    assert hpattern_needs(VehicleState(speed_m_s=5.0, engine_speed_rpm=900.0))
    assert not hpattern_needs(VehicleState(speed_m_s=5.0))
    assert not hpattern_needs(VehicleState(engine_speed_rpm=900.0))


# --- every component its own value (a product or a slice off by one shows) --------------------

F1_FORWARD = (21845, 10922, 21845)  # (2/3, 1/3, 2/3) x 32767: a unit vector
F1_RIGHT = (-10922, -21845, 21845)  # (-1/3, -2/3, 2/3): unit, square to the forward one


def test_f1_values_with_every_component_its_own() -> None:
    car = struct.pack("<6f6h6f", 100.0, 2.0, -50.0, 30.0, 12.0, 40.0, *F1_FORWARD, *F1_RIGHT,
                      1.2, 0.1, 0.3, 0.6, 0.01, 0.02)  # fmt: skip
    motion = _f1_header(0) + bytes(60) * 3 + car + bytes(60) * 18
    s = formats.decode_f1(motion, VehicleState())
    assert s is not None and plausible(s)
    assert s.speed_m_s == pytest.approx(math.sqrt(30**2 + 12**2 + 40**2), rel=1e-7)
    assert s.time_s == 61.5 and s.lateral_accel_m_s2 == pytest.approx(-1.2 * G, rel=1e-6)
    # The telemetry's own speed (200 km/h) is not the motion's: the motion's is kept.
    tele = bytearray(_f1_telemetry(gear=0))
    struct.pack_into("<H", tele, 209, 200)
    merged = formats.decode_f1(bytes(tele), s)
    assert merged is not None and merged.speed_m_s == s.speed_m_s
    assert merged.gear == NEUTRAL  # 0 is neutral, -1 reverse
    alone = formats.decode_f1(bytes(tele), VehicleState())
    assert alone is not None and alone.speed_m_s == pytest.approx(200 / 3.6)


def test_beamng_values_with_every_component_its_own() -> None:
    values = [10.0, 20.0, 30.0, 12.0, 16.0, 3.0, 1.0, 2.0, 9.8, 0.36, 0.48, 0.8,
              0.1, 0.2, 1.5, 0.05, -0.02, 0.3, 0.1, 0.2, 0.3]  # fmt: skip
    data = struct.pack("<4s21f", b"BNG1", *values)
    s = formats.decode_beamng(data, VehicleState())
    assert s is not None and plausible(s) and s.lateral_derived
    speed = math.sqrt(12**2 + 16**2 + 3**2)
    assert s.speed_m_s == pytest.approx(speed, rel=1e-6)
    assert s.yaw_rate_rad_s == pytest.approx(0.3, rel=1e-6)
    assert s.lateral_accel_m_s2 == pytest.approx(speed * 0.3, rel=1e-6)
    assert (s.car, s.cylinders, math.isnan(s.time_s)) == ("", 0, True)
    for index, value in ((4, 1.5e7), (19, 1.5e7), (16, 51.0), (13, 7.0), (7, 501.0), (10, 3.0)):
        bad = list(values)
        bad[index - 1] = value  # position, angular acceleration, rate, angle, accel, up
        assert formats.decode_beamng(struct.pack("<4s21f", b"BNG1", *bad), VehicleState()) is BAD


def test_outsim_values_with_every_component_its_own() -> None:
    heading = 0.7
    ax, ay = 1.0, 2.0
    data = struct.pack("<I3f3f3f3f3i", 1234, 0.05, -0.04, 0.2, heading, 0.1, -0.05, ax, ay, 9.8,
                       -10.0, 14.0, 0.3, 5, 6, 7)  # fmt: skip
    s = formats.decode_outsim(data, VehicleState())
    assert s is not None and plausible(s) and s.lateral_derived
    lateral = -ax * math.cos(heading) - ay * math.sin(heading)
    assert s.lateral_accel_m_s2 == pytest.approx(lateral, rel=1e-6)
    assert s.speed_m_s == pytest.approx(math.sqrt(100 + 196 + 0.09), rel=1e-6)
    assert s.yaw_rate_rad_s == pytest.approx(0.2, rel=1e-6)
    assert (s.time_s, s.car, s.cylinders, s.gear) == (1.234, "", 0, NEUTRAL)
    for offset, value in ((4, 51.0), (28, 501.0), (48, 151.0), (24, 7.0)):
        assert formats.decode_outsim(_with(data, offset, "<f", value), VehicleState()) is BAD


def test_assetto_steer_sign_and_speed_slack() -> None:
    """AC's steer is degrees at the wheel, right positive: the state's angle is left positive.
    The km/h field may be 0.5 km/h + 1 % off the m/s one x 3.6, not more."""
    p = _assetto()
    right = formats.decode_assetto(_with(p, 72, "<f", 90.0), VehicleState())
    assert right is not None and right.steering_angle_rad == pytest.approx(-math.pi / 2)
    assert not right.lateral_derived and right.cylinders == 0
    ms = struct.unpack_from("<f", p, 16)[0]
    for off_kmh, good in ((1.0, True), (1.8, False)):  # slack 0.5 + 1 % of 75 km/h = 1.25
        data = bytearray(p)
        struct.pack_into("<2f", data, 8, 3.6 * ms + off_kmh, (3.6 * ms + off_kmh) / 1.609344)
        state = formats.decode_assetto(bytes(data), VehicleState())
        assert (state is not BAD) == good, off_kmh


def test_assetto_car_name_from_hostile_bytes() -> None:
    """The handshake's car name: UTF-16 up to a NUL or the first %, printable only; invalid
    UTF-16 and control characters do not raise and do not come through."""
    name = "ks_audi%r8".encode("utf-16-le") + b"\x00\x00" + "junk".encode("utf-16-le")
    assert formats.ac_car_name(name.ljust(408, b"\x00")) == "ks_audi"
    hostile = b"\x00\xd8" + "a\x07b".encode("utf-16-le")  # a lone surrogate, a bell
    assert formats.ac_car_name(hostile.ljust(408, b"\x00")) == "\ufffdab"
    long = ("x" * 60).encode("utf-16-le")  # beyond wchar_t[50]: the rest is the driver's
    assert formats.ac_car_name(long.ljust(408, b"\x00")) == "x" * 50


def test_gear_numbers_of_each_format() -> None:
    """Every game's gear numbering to -1 R, 0 N, 1..: Codemasters (-1 or 10 reverse, 10 a
    gear where the car has 10), Forza (0 R, 11 N), F1 (-1 R, 0 N)."""
    cm = _codemasters()
    for raw, gears, gear in ((-1.0, 6.0, REVERSE), (0.0, 6.0, NEUTRAL), (1.0, 6.0, 1),
                             (10.0, 6.0, REVERSE), (10.0, 10.0, 10), (9.0, 9.0, 9)):  # fmt: skip
        packet = _with(_with(cm, 4 * 33, "<f", raw), 4 * 65, "<f", gears)
        s = formats.decode_codemasters(packet, VehicleState())
        assert s is not None and s.gear == gear, (raw, gears)
    fz = _forza()
    for raw, gear in ((0, REVERSE), (1, 1), (10, 10), (11, NEUTRAL)):
        s = formats.decode_forza(_with(fz, 232 + 75, "<B", raw), VehicleState())
        assert s is not None and s.gear == gear, raw
    for raw, gear in ((-1, REVERSE), (0, NEUTRAL), (8, 8)):
        s = formats.decode_f1(_f1_telemetry(gear=raw), VehicleState())
        assert s is not None and s.gear == gear, raw


def test_forza_pedals_and_the_sleds_signs() -> None:
    """Accel, brake and clutch are 0..255 (255 is 1.0); the sled alone gives the dash's Ay and
    yaw rate, signs turned to left positive."""
    fz = _forza()
    for offset, name in ((232 + 71, "throttle"), (232 + 72, "brake"), (232 + 73, "clutch_pedal")):
        s = formats.decode_forza(_with(fz, offset, "<B", 255), VehicleState())
        assert s is not None and getattr(s, name) == 1.0, name
    dash = formats.decode_forza(fz, VehicleState())
    sled = formats.decode_forza(fz[:232], VehicleState())
    assert dash is not None and sled is not None
    assert (sled.lateral_accel_m_s2, sled.yaw_rate_rad_s) == (
        dash.lateral_accel_m_s2, dash.yaw_rate_rad_s,
    )  # fmt: skip
    ax, yaw = struct.unpack_from("<f", fz, 20)[0], struct.unpack_from("<f", fz, 48)[0]
    assert (dash.lateral_accel_m_s2, dash.yaw_rate_rad_s) == (-ax, -yaw) and ax != 0 != yaw
    assert not dash.lateral_derived and not sled.lateral_derived
    assert formats.decode_forza(_with(fz[:232], 40, "<f", 151.0), VehicleState()) is BAD  # vz


def test_constant_fields_of_the_formats_without_them() -> None:
    """No car name, no cylinders, nothing derived where the format sends none."""
    cm = formats.decode_codemasters(_codemasters(), VehicleState())
    crfl = formats.decode_carfeel(encode_carfeel(VehicleState(speed_m_s=1.0)), VehicleState())
    for s in (cm, crfl):
        assert s is not None and (s.car, s.cylinders, s.lateral_derived) == ("", 0, False)


@pytest.mark.parametrize("offset", [209, 213, 217])
def test_f1_each_position_component(offset: int) -> None:
    assert formats.decode_f1(_with(_f1_motion(), offset, "<f", 2e5), VehicleState()) is BAD


@pytest.mark.parametrize(("offset", "bad"), [(221, 151.0), (225, 151.0), (229, 151.0),
                                             (257, 7.0), (261, 7.0), (265, 7.0)])  # fmt: skip
def test_f1_each_velocity_and_angle_component(offset: int, bad: float) -> None:
    assert formats.decode_f1(_with(_f1_motion(), offset, "<f", bad), VehicleState()) is BAD


def test_f1_a_header_alone_is_ignored() -> None:
    """29 bytes: a header with no body is not a packet this reads (ignored), not garbage."""
    assert formats.decode_f1(_f1_header(2), VehicleState()) is None


@pytest.mark.parametrize(("index", "bad"), [(4, 151.0), (5, 151.0), (6, 151.0), (7, 501.0),
                                            (8, 501.0), (9, 501.0), (13, 7.0), (14, 7.0),
                                            (15, 7.0), (16, 51.0), (17, 51.0), (18, 51.0),
                                            (1, 1.5e7), (2, 1.5e7), (3, 1.5e7), (19, 1.5e7),
                                            (20, 1.5e7), (21, 1.5e7)])  # fmt: skip
def test_beamng_each_component(index: int, bad: float) -> None:
    """Index into the 21 floats after the magic, 1-based: position, velocity, acceleration,
    (up vector), angles, rates, angular accelerations."""
    assert formats.decode_beamng(_with(_beamng(), 4 * index, "<f", bad), VehicleState()) is BAD


@pytest.mark.parametrize(("offset", "bad"), [(4, 51.0), (8, 51.0), (16, 7.0), (20, 7.0),
                                             (28, 501.0), (32, 501.0), (40, 151.0),
                                             (44, 151.0)])  # fmt: skip
def test_outsim_each_component(offset: int, bad: float) -> None:
    assert formats.decode_outsim(_with(_outsim(), offset, "<f", bad), VehicleState()) is BAD
