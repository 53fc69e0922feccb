"""Hostile bytes never end a session: every decoder is total over bytes (a datagram of any size
and content is a state, ignored or bad, never an exception), random bytes of a format's size are
counted bad, and `Receiver.poll` never raises (issue 26)."""

from __future__ import annotations

import math
import random
import socket
import struct
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.telemetry import formats
from carfeel.telemetry.formats import FORMATS, Format, decode_datagram, encode_carfeel
from carfeel.telemetry.receiver import Receiver, Source
from carfeel.telemetry.state import BAD, VehicleState, plausible

SPECIAL = (math.nan, math.inf, -math.inf, 1e30, -1e30, 0.0, 3.0, -1.0, 1.0, 5e-324)
"""The floats a fuzzer tries (the review's set, and a denormal): what raised in round() and
math.cos."""
PACK2 = tuple(Source.parse(f"outsim@{o:x}:127.0.0.1:0").format for o in (0x1FF, 0x3D, 0x08, 0x9))
ALL: tuple[Format, ...] = (*FORMATS.values(), *PACK2)
SIZES = [(f, size) for f in ALL for size in sorted(f.sizes)]
FUZZ_COUNT = 10_000


def _ids(item: tuple[Format, int]) -> str:
    return f"{item[0].name}-{item[1]}"


def _classify(fmt: Format, data: bytes, last: VehicleState) -> str:
    """good, bad or ignored; an exception propagates (the test then fails)."""
    state = decode_datagram(fmt, data, last)
    if state is None:
        return "ignored"
    assert isinstance(state, VehicleState)
    return "good" if plausible(state) else "bad"


def _special(size: int, rng: random.Random) -> bytes:
    """Floats from SPECIAL at every 4-byte offset (as the layouts are aligned)."""
    floats = [struct.pack("<f", v) for v in SPECIAL]
    return b"".join(rng.choice(floats) for _ in range(size // 4)) + rng.randbytes(size % 4)


GOOD_RANDOM_BOUND = {"outsim": 10, "outsim@8": 10}
"""Of 5,000 random datagrams, how many may look like a car. OutSim (and OutSimPack2 with
OSMain alone) is 12 floats with no flag, magic or id: a random float lies within a car's bound
with probability about 0.53 (its exponent byte), all twelve with 0.53^12 = 5e-4, so about 2.5
in 5,000; 10 leaves room for the seed. Every other format has a magic, a flag, an id or a whole
number that random bytes miss: none may pass."""


@pytest.mark.parametrize("item", SIZES, ids=_ids)
def test_ten_thousand_fuzzed_datagrams_per_size_no_exception_and_random_counted_bad(
    item: tuple[Format, int],
) -> None:
    """5,000 random datagrams and 5,000 of floats from SPECIAL per accepted size: none raises;
    the random ones are bad; the SPECIAL ones may be anything (all 0, 1 and 3 can be a car at
    rest, and Forza's IsRaceOn = 0 a menu)."""
    fmt, size = item
    rng = random.Random(f"{fmt.name}-{size}")
    random_counts = {"good": 0, "bad": 0, "ignored": 0}
    special_counts = dict(random_counts)
    last = VehicleState(speed_m_s=10.0, gear=2)  # F1 merges onto the last state
    for _ in range(FUZZ_COUNT // 2):
        random_counts[_classify(fmt, rng.randbytes(size), last)] += 1
        special_counts[_classify(fmt, _special(size, rng), last)] += 1
    assert sum(random_counts.values()) == sum(special_counts.values()) == FUZZ_COUNT // 2
    assert random_counts["good"] <= GOOD_RANDOM_BOUND.get(fmt.name, 0), random_counts
    # Random bytes are never "another packet type" (F1: a random header is not one either).
    assert random_counts["ignored"] == 0, random_counts


@pytest.mark.parametrize("fmt", ALL, ids=lambda f: f.name)
@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=1500))
def test_any_size_any_bytes_is_decoded_ignored_or_bad(fmt: Format, data: bytes) -> None:
    outcome = _classify(fmt, data, VehicleState())
    if len(data) not in fmt.sizes and not fmt.other_sizes:
        assert outcome == "bad"  # the wrong size


def _packed(layout: str) -> st.SearchStrategy[bytes]:
    """Datagrams of a layout with each float from SPECIAL or any float32, ints anything."""
    parts: list[st.SearchStrategy[bytes]] = []
    number = ""
    for ch in layout.lstrip("<"):
        if ch.isdigit():
            number += ch
            continue
        count, number = int(number or 1), ""
        if ch == "f":
            value = st.one_of(st.sampled_from(SPECIAL), st.floats(width=32))
            parts += [value.map(lambda v: struct.pack("<f", v))] * count
        elif ch in "xs":  # pad bytes and byte strings: any bytes
            parts.append(st.binary(min_size=count, max_size=count))
        else:
            width = struct.calcsize("<" + ch)
            parts += [st.binary(min_size=width, max_size=width)] * count
    return st.tuples(*parts).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(data=_packed("<66f"))
def test_codemasters_any_floats(data: bytes) -> None:
    _classify(FORMATS["codemasters"], data, VehicleState())


@settings(max_examples=300, deadline=None)
@given(data=_packed("<I3f3f3f3f3i"), extra=st.binary(min_size=0, max_size=4))
def test_outsim_any_floats(data: bytes, extra: bytes) -> None:
    data = data + extra if len(extra) in (0, 4) else data
    _classify(FORMATS["outsim"], data, VehicleState())


@settings(max_examples=300, deadline=None)
@given(data=_packed("<4s21f"), magic=st.booleans())
def test_beamng_any_floats(data: bytes, magic: bool) -> None:
    if magic:
        data = b"BNG1" + data[4:]
    _classify(FORMATS["beamng"], data, VehicleState())


@settings(max_examples=300, deadline=None)
@given(data=_packed("<4sHHId4fb3x4f"))
def test_carfeel_any_values(data: bytes) -> None:
    state = decode_datagram(FORMATS["carfeel"], b"CRFL\x01\x00" + data[6:], VehicleState())
    assert state is not None and isinstance(state, VehicleState)  # ours: decoded, then checked


@settings(max_examples=200, deadline=None)
@given(
    floats=st.lists(
        st.one_of(st.sampled_from(SPECIAL), st.floats(width=32)), min_size=18, max_size=18
    ),
    packet_id=st.sampled_from([0, 6]),
    player=st.integers(0, 255),
)
def test_f1_header_right_payload_any(floats: list[float], packet_id: int, player: int) -> None:
    """A valid F1 header over any car values (the checks past the header's)."""
    header = struct.pack("<HBBBBBQfIIBB", 2023, 23, 1, 0, 1, packet_id, 1, 1.0, 1, 1, player, 255)
    unit = struct.pack("<6h", 0, 0, 32767, 32767, 0, 0)  # forward and right: unit vectors
    car = struct.pack("<6f", *floats[:6]) + unit + struct.pack("<6f", *floats[6:12])
    size = formats.F1_MOTION_SIZE if packet_id == 0 else formats.F1_TELEMETRY_SIZE
    data = (header + car * 22 + bytes(3))[:size]
    _classify(FORMATS["f1"], data, VehicleState())


def test_a_random_forza_horizon_datagram_is_not_a_car() -> None:
    """The review's case: one random 324-byte datagram was taken as a good Forza packet
    ("car": "501154294"). Random bytes, and the same bytes with IsRaceOn forced to 1."""
    rng = random.Random(324)
    for _ in range(1000):
        data = bytearray(rng.randbytes(324))
        data[0:4] = struct.pack("<i", 1)
        assert decode_datagram(FORMATS["forza"], bytes(data), VehicleState()) is BAD


# --- the receiver on a real socket ------------------------------------------------------------


def _sent(receiver: Receiver, datagrams: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for d in datagrams:
            s.sendto(d, receiver.address)


def _poll_all(receiver: Receiver, total: int, timeout_s: float = 5.0) -> list[VehicleState]:
    states: list[VehicleState] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        receiver.poll(states.append)
        if receiver.packets + receiver.bad + receiver.ignored >= total:
            break
        time.sleep(0.001)
    return states


def _nan_free(state: VehicleState | None) -> tuple[object, ...]:
    """A state's fields with NaN as None: NaN != NaN (a decoded NaN is a new float)."""
    assert state is not None
    return tuple(None if isinstance(v, float) and math.isnan(v) else v for v in state)


def _good_packets(name: str) -> list[bytes]:
    """Good packets to interleave: the real Forza capture, carfeel packets; none elsewhere."""
    if name == "forza":
        from carfeel.telemetry import replay
        from tests.datafiles import data_file

        return replay.datagrams(data_file("telemetry", "forza-motorsport-2023-dash.raw"), 331)
    if name == "carfeel":
        return [encode_carfeel(VehicleState(speed_m_s=0.01 * k, gear=2)) for k in range(5000)]
    return []


@pytest.mark.parametrize("name", sorted(FORMATS))
def test_poll_never_raises_on_fuzz_and_keeps_the_good_in_order(name: str) -> None:
    """Fuzzed datagrams of every size of the format and of odd sizes (empty, 1, 3, 1500
    bytes), interleaved with good packets where there are some (the real Forza capture): every
    datagram is counted once, the good ones come through, all of them, in order. Sent in
    batches that the receive buffer holds (the kernel would drop the rest, as it should)."""
    fmt = FORMATS[name]
    rng = random.Random(name)
    sizes = [*sorted(fmt.sizes), 0, 1, 3, 1500]
    good = _good_packets(name)[:250]
    expected = [decode_datagram(fmt, g, VehicleState()) for g in good]
    source = Source.parse(f"{name}:127.0.0.1:{fmt.default_port if name == 'assetto' else 0}")
    with Receiver(source, 4 * 1024 * 1024) as receiver:
        states: list[VehicleState] = []
        total = 0
        for k in range(10):
            batch = [rng.randbytes(rng.choice(sizes)) for _ in range(50)]
            if good:
                batch[1::2] = good[25 * k : 25 * (k + 1)]
            if name == "assetto":  # the client's own socket: sent as the game, from 127.0.0.1
                batch = [b for b in batch if len(b) != formats.AC_RESPONSE_SIZE]
            _sent(receiver, batch)
            total += len(batch)
            states += _poll_all(receiver, total)
        assert receiver.packets + receiver.bad + receiver.ignored == total
        assert receiver.errors == 0
    assert [_nan_free(s) for s in states[: len(expected)]] == [_nan_free(e) for e in expected]
    assert receiver.packets - len(expected) <= GOOD_RANDOM_BOUND.get(name, 0)


def test_poll_survives_a_decoder_that_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    """The last line of defence: a decoder bug is counted bad and named, the good packets
    around it still come through, and the poll returns normally."""

    def broken(data: object, last: VehicleState) -> VehicleState | None:
        if bytes(data)[20:24] == struct.pack("<f", 13.0):  # type: ignore[call-overload]
            raise ZeroDivisionError("a bug")
        return formats.decode_carfeel(data, last)

    source = Source.parse("carfeel:127.0.0.1:0")
    fmt = Format("carfeel", source.format.sizes, broken, 0, "test")
    with Receiver(source) as receiver:
        monkeypatch.setattr(receiver, "format", fmt)
        good = [encode_carfeel(VehicleState(speed_m_s=float(v))) for v in (10, 13, 11, 13, 12)]
        _sent(receiver, good)
        states = _poll_all(receiver, 5)
    assert [s.speed_m_s for s in states] == [10.0, 11.0, 12.0]
    assert (receiver.packets, receiver.bad, receiver.errors) == (3, 2, 2)
    assert "ZeroDivisionError: a bug" in receiver.first_error
    assert "raised in the decoder" in receiver.counts()
