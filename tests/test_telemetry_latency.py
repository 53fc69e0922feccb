"""Packet-to-force latency: from a packet's arrival (the kernel's stamp on Linux) to the first
command sent to the device that was computed from it, counted in bounded memory and reported.

Real sockets; the loop on the wall clock for the end-to-end case (its assertions are orderings
and counts, never wall-clock figures)."""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from carfeel.io.presets import load_shift
from carfeel.realtime.clock import SimulatedClock, WallClock
from carfeel.realtime.devices.virtual import virtual_joystick
from carfeel.realtime.loop import LoopConfig, run_loop
from carfeel.realtime.rendering import Gains, ShiftRenderer, default_scaling, velocity_sections
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.session import RealtimeRun, run_realtime
from carfeel.realtime.stability import size
from carfeel.telemetry.formats import encode_carfeel
from carfeel.telemetry.receiver import KERNEL_STAMPS, Receiver, Source
from carfeel.telemetry.source import Histogram, VehicleSource
from carfeel.telemetry.state import VehicleState

PACKET = encode_carfeel(VehicleState(speed_m_s=20.0, lateral_accel_m_s2=2.0))


@contextlib.contextmanager
def sender() -> Iterator[socket.socket]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        yield s
    finally:
        s.close()


def test_a_histogram_gives_the_bin_edges_of_its_percentiles():
    h = Histogram(0.001, 10)
    assert h.percentiles() == {}
    for value in [0.0005] * 98 + [0.0042, 0.5]:  # 98 in the first bin, one in the 5th, one past
        h.add(value)
    assert h.percentiles() == {"p50": 0.001, "p99": 0.005, "max": math.inf}
    h.add(-1e-6)  # a clock's rounding below zero counts in the first bin
    assert h.counts[0] == 99 and h.total == 101


def test_the_latency_counts_from_the_arrival_to_the_first_command_sent_from_it():
    """A packet waits in the socket; the latency of the command sent from it is at least that
    wait (the stamp is the kernel's arrival where it gives one, else the read), and a second
    command from the same packet adds nothing."""
    with sender() as s:
        source = VehicleSource(Receiver(Source.parse("carfeel:127.0.0.1:0")))
        assert source.receiver.stamped is KERNEL_STAMPS
        source.update(0.0)  # the first update drops what queued before the run
        before_send = time.perf_counter_ns()
        s.sendto(PACKET, source.receiver.address)
        time.sleep(0.03)
        source.update(0.001)
        assert source.state.speed_m_s == 20.0
        now = time.perf_counter_ns()
        source.commanded(now)
        source.commanded(now + 1_000_000)  # the next tick: the same packet, no new latency
        source.close()
    assert source.latencies.total == 1
    # At most the time since the send began, give or take the stamp's conversion: the kernel
    # stamps on the real-time clock, taken to the loop's by an offset read at the poll (1 ms of
    # slack, far more than two clock reads differ by).
    assert 0.0 <= source.latency_s <= (now - before_send) / 1e9 + 0.001
    assert any("packet-to-force latency" in e and "1 packets" in e for e in source.events)
    status = source.status()
    assert status["latency_s"] == source.latency_s
    assert float(status["latency_p99_s"]) >= source.latency_s


@pytest.mark.skipif(not KERNEL_STAMPS, reason="the kernel stamps datagrams on Linux only")
def test_the_kernel_stamps_the_arrival_not_the_read():
    """On Linux a datagram that waited 30 ms in the socket is dated 30 ms back.

    The kernel turns its receive stamps on a moment after the first socket asks (deferred work;
    seconds on a loaded machine) and until then dates a datagram at its read: the same packet is
    sent again until a stamp precedes the read, which the read-time fallback can never do."""
    with sender() as s:
        receiver = Receiver(Source.parse("carfeel:127.0.0.1:0"))
        try:
            waited_s = 0.0
            for _ in range(100):  # 100 x 30 ms: 3 s for the kernel to turn its stamps on
                s.sendto(PACKET, receiver.address)
                time.sleep(0.03)
                assert receiver.poll() == 1
                waited_s = (time.perf_counter_ns() - receiver.arrival_ns) / 1e9
                if waited_s >= 0.03:
                    break
        finally:
            receiver.close()
    assert waited_s >= 0.03, "the kernel never dated a datagram before its read"


def test_without_a_new_packet_no_latency_is_counted():
    source = VehicleSource(Receiver(Source.parse("carfeel:127.0.0.1:0")))
    for k in range(10):
        source.update(k * 0.001)
        source.commanded(time.perf_counter_ns())
    source.close()
    assert source.latencies.total == 0
    assert math.isnan(source.latency_s)
    assert not any("latency" in e for e in source.events)


def test_a_stamp_from_a_stepped_clock_is_not_believed(monkeypatch: pytest.MonkeyPatch) -> None:
    """The kernel stamps on the real-time clock: a stamp in the future (the clock stepped
    back) or from long ago falls back to the read time, never a negative or huge latency."""
    receiver = Receiver(Source.parse("carfeel:127.0.0.1:0"))
    wrong = time.time_ns() + 5_000_000_000
    queue = [(len(PACKET), ("127.0.0.1", 1), wrong)]

    def receive() -> tuple[int, tuple[str, int], int]:
        if not queue:
            raise BlockingIOError
        receiver._buffer[: len(PACKET)] = PACKET
        return queue.pop()

    monkeypatch.setattr(receiver, "_receive", receive)
    before = time.perf_counter_ns()
    receiver.poll()
    receiver.close()
    assert receiver.packets == 1
    assert receiver.arrival_ns >= before


class Timed(ShiftRenderer):
    """The shift's renderer, noting each time the loop says it sent the tick's commands."""

    def __init__(self, *args: object) -> None:
        super().__init__(*args)  # type: ignore[arg-type]
        self.sent_at: list[int] = []

    def commanded(self, now_ns: int) -> None:
        self.sent_at.append(now_ns)


@pytest.mark.parametrize("clock", [SimulatedClock(), WallClock()], ids=["simulated", "wall"])
def test_the_loop_tells_a_renderer_when_it_sent_on_the_wall_clock_only(clock):
    """Simulated time has no latency to count (a report stays the same run after run); on the
    wall clock the renderer hears of every tick's commands, after they went out."""
    device = virtual_joystick()
    gear = load_shift().params
    scaling = default_scaling(100.0, 0.045, device.info)
    gains = Gains.sized(size(device.info, 1000.0, velocity_sections(1000.0)), scaling)
    renderer = Timed(gear.gearbox, "impedance", scaling, 1000.0, gains)
    limits = SafetyLimits(max_force=10.0, max_slew_per_s=2000.0, fade_s=0.05)
    with device:
        summary = run_loop(renderer, device, clock, LoopConfig(1000.0, 0.05, False), limits)
    if isinstance(clock, SimulatedClock):
        assert renderer.sent_at == []
    else:
        assert len(renderer.sent_at) == summary.periods
        assert renderer.sent_at == sorted(renderer.sent_at)


@pytest.mark.slow
def test_a_wall_clock_run_reports_the_latency_of_the_packets_it_used():
    """The loop on the wall clock, a game sending at 100 Hz on loopback: the summary counts a
    latency for packets the loop used (each at most one per tick), all of them finite."""
    port_box: list[int] = []
    done = threading.Event()

    def game() -> None:
        with sender() as s:
            while not port_box and not done.is_set():
                time.sleep(0.001)
            while not done.is_set():
                s.sendto(PACKET, ("127.0.0.1", port_box[0]))
                time.sleep(0.01)

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    port_box.append(port)
    thread = threading.Thread(target=game, daemon=True)
    thread.start()
    try:
        run = RealtimeRun(model="steering", device="virtual:wheel", clock="wall",
                          duration_s=1.0, calibrate=False, identify="off",
                          telemetry=f"carfeel:127.0.0.1:{port}")  # fmt: skip
        result = run_realtime(run)
    finally:
        done.set()
        thread.join(timeout=2.0)
    notes = [n for n in result.summary.notes if "packet-to-force latency" in n]
    assert len(notes) == 1, result.summary.notes
    counted = int(notes[0].split("it, ")[1].split(" packets")[0])
    assert 1 <= counted <= result.summary.periods


def test_the_panel_shows_the_packet_age_and_the_latency():
    """The loop's process writes the packet age, the newest latency and the session's p99 into
    the panel's status (NaN without telemetry)."""
    from types import SimpleNamespace

    from carfeel.panel.worker import Observer

    source = VehicleSource(Receiver(Source.parse("carfeel:127.0.0.1:0")))
    for latency in [0.0008] * 99 + [0.004]:
        source.latencies.add(latency)
    source.latency_s, source.age_s = 0.004, 0.012
    observer = Observer(None, None, None)
    observer.parts = SimpleNamespace(renderer=SimpleNamespace(source=source))
    age, latency, p99 = observer._telemetry_status()
    assert (age, latency) == (0.012, 0.004)
    assert p99 == pytest.approx(0.00085)  # the bin of 0.8 ms: 0.80-0.85 ms
    source.close()
    observer.parts = SimpleNamespace(renderer=object())  # a run without telemetry
    assert all(math.isnan(v) for v in observer._telemetry_status())
