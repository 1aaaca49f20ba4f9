"""The USB adapter model (:mod:`swerve.emulator.adapter`): the pure delivery function over its
input space, exact round trips through it in lockstep robot time, the robot file's key and the
``--adapter-latency-ms`` option. No verdict depends on wall-clock timing."""
from __future__ import annotations

import bisect
import math
import signal
import subprocess
import sys
import time

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.core.errors import ConfigError
from swerve.configs.loader import parse_yaml_text
from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config, parse_robot_config
from swerve.emulator.adapter import (AdapterSettings, UsbAdapter, byte_arrivals, check_latency_ms, deliver)
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S
from swerve.emulator.server import LinkSettings
from swerve.emulator.factory import build_emulator
from swerve.emulator.timing import Frozen, Lockstep
from swerve.tools.cli import main
from swerve.tools.commands.emulate import parse_control, parse_port_line
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock

BYTE_S = 10 / 1_000_000          # one byte at 1 Mbps, 8N1
MS = 1e-3
#: A byte within this of a send is in it (the model's allowance for float round-off on the grid).
SLACK_S = 1.01e-9


def _on_grid(t: float, step: float) -> bool:
    return abs(t / step - round(t / step)) < 1e-6


# --- the pure function: exact cases --------------------------------------------------------------

def test_a_short_reply_waits_for_the_latency_timer():
    # 15 bytes (a 4-byte read's status) leaving the cable 0.70..0.84 ms after the last send at 0
    arrivals = byte_arrivals(0.0, [(0.69 * MS, 15)], BYTE_S)
    assert arrivals[0] == pytest.approx(0.70 * MS) and arrivals[-1] == pytest.approx(0.84 * MS)
    assert deliver(AdapterSettings(1), arrivals).times_s == (1 * MS,) * 15
    d16 = deliver(AdapterSettings(16), arrivals)
    assert d16.times_s == (16 * MS,) * 15 and d16.last_send_s == 16 * MS


def test_full_packets_go_at_the_next_frame_and_restart_the_timer():
    # the loop's Sync Read: 8 replies of 21 bytes back to back from 0.5 ms, 10 us per byte
    arrivals = byte_arrivals(0.0, [(0.5 * MS, 168)], BYTE_S)
    d = deliver(AdapterSettings(16), arrivals)
    # bytes 1-62 fill a packet at 1.12 ms and 63-124 at 1.74 ms: both reach the host at the 2 ms
    # frame; the last 44 wait for the timer, 16 ms after that send
    assert d.times_s[:124] == (2 * MS,) * 124
    assert d.times_s[124:] == (18 * MS,) * 44
    # at 1 ms the timer wins: 1 ms (50 bytes), 2 ms (a full packet), 3 ms (the rest)
    d1 = deliver(AdapterSettings(1), arrivals)
    assert d1.times_s == (1 * MS,) * 50 + (2 * MS,) * 62 + (3 * MS,) * 56


def test_an_idle_timer_keeps_its_phase_from_the_last_send():
    # last send at 5 ms: the 16 ms timer expires at 21, 37, 53 ms, ... whether or not data waits
    d = deliver(AdapterSettings(16), [40 * MS, 40.01 * MS], last_send_s=5 * MS)
    assert d.times_s == (53 * MS, 53 * MS)


def test_latency_timer_values_are_whole_ms_in_1_to_255():
    assert check_latency_ms(1) == 1 and check_latency_ms(255.0) == 255
    for bad in (0, -1, 256, 1.5, math.nan, math.inf, "16", True, None):
        with pytest.raises(ConfigError, match="latency"):
            check_latency_ms(bad)
    with pytest.raises(ConfigError, match="0 is not a valid FTDI latency timer"):
        AdapterSettings(0)
    with pytest.raises(ValueError, match="non-decreasing"):
        deliver(AdapterSettings(1), [2 * MS, 1 * MS])


# --- the pure function: properties over the space ---------------------------------------------

latencies = st.integers(1, 255)
#: Byte gaps in us: back to back at 4.5 Mbps (2.2 us) up to idle gaps of 40 ms.
gaps_us = st.lists(st.one_of(st.just(10.0), st.floats(2.2, 50.0), st.floats(0.0, 40_000.0)), max_size=400)


def _arrivals(start_us: float, gaps: list[float]) -> list[float]:
    t, out = start_us, []
    for g in gaps:
        t += g
        out.append(t * 1e-6)
    return out


@given(latencies, st.floats(0.0, 100_000.0), gaps_us, st.integers(0, 300))
@example(16, 500.0, [10.0] * 168, 0)
@example(1, 999.999, [0.002, 10.0], 0)       # a byte 1 ns after the send: the slack's edge
@settings(max_examples=300, deadline=None)
def test_delivery_rules_hold_for_any_arrivals(latency_ms, start_us, gaps, last_send_ms):
    s = AdapterSettings(latency_ms)
    arrivals = _arrivals(start_us, gaps)
    last = last_send_ms * MS
    d = deliver(s, arrivals, last)
    assert len(d.times_s) == len(arrivals)
    for a, t in zip(arrivals, d.times_s):
        assert t >= a - SLACK_S                                 # never before it reached the adapter
        assert t <= max(a, last) + s.latency_s + s.frame_s + 1e-9   # one timer period and a frame at most
        assert _on_grid(t, s.frame_s)                           # on a USB frame
    assert list(d.times_s) == sorted(d.times_s)                 # in order
    assert d.last_send_s >= last and d.end_s == (d.times_s[-1] if arrivals else last)
    # a byte that did not go in a full packet went when the timer expired: a whole number of
    # periods after the previous send, or on the frame after a full packet filled
    sends = sorted(set(d.times_s))
    for prev, t in zip([last] + sends, sends):
        n = sum(1 for u in d.times_s if u == t)
        by_timer = _on_grid(t - prev, s.latency_s) and t - prev > 0
        assert by_timer or n >= s.payload_bytes


@given(latencies, st.floats(0.0, 100_000.0), gaps_us, st.data())
@settings(max_examples=200, deadline=None)
def test_two_exchanges_in_turn_equal_one_call(latency_ms, start_us, gaps, data):
    """The state carried between exchanges (the last send) is all the adapter remembers."""
    s = AdapterSettings(latency_ms)
    arrivals = _arrivals(start_us, gaps)
    whole = deliver(s, arrivals)
    adapter = UsbAdapter(s)
    # split where the host has had the first exchange's bytes before the next one starts
    cut = data.draw(st.integers(0, len(arrivals)))
    first = adapter.plan(arrivals[:cut])
    adapter.commit(first)
    if cut < len(arrivals) and arrivals[cut] < first.end_s:
        return                                  # the second exchange started before the host had the first
    second = adapter.plan(arrivals[cut:])
    adapter.commit(second)
    assert first.times_s + second.times_s == whole.times_s
    assert adapter.last_send_s == whole.last_send_s


@given(st.lists(st.floats(0.0, 30_000.0), max_size=60))
@settings(max_examples=200, deadline=None)
def test_at_1_ms_a_sparse_byte_reaches_the_host_at_the_next_frame(gaps):
    """With a 1 ms timer on 1 ms frames and fewer than 62 bytes per frame, the adapter only
    rounds up to the frame after the byte (the next frame if it lands on a boundary's edge)."""
    s = AdapterSettings(1)
    arrivals = _arrivals(100.0, [g + 1000.0 / 61 for g in gaps])   # < 62 bytes per ms
    d = deliver(s, arrivals)
    for a, t in zip(arrivals, d.times_s):
        assert t == pytest.approx(max(math.ceil(a / MS - 1e-6), 1) * MS, abs=1e-12)


# --- in the emulator, lockstep: exact round trips --------------------------------------------

@pytest.fixture(params=[None, 1, 16], ids=["no adapter", "1 ms", "16 ms"])
def lockstep_bus(request):
    with build_emulator(ids=[1, 2], timing=Lockstep(), adapter_latency_ms=request.param) as emu:
        with LockstepLoopClock(emu.control.path) as clock, Bus(emu.port, 1_000_000, default_model="xh430-w210",
                                                           timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            yield request.param, emu, bus, clock


def test_a_read_round_trip_in_robot_time(lockstep_bus):
    latency_ms, emu, bus, clock = lockstep_bus
    assert clock.info()["adapter_latency_ms"] == (latency_ms or 0)
    cable_s = 14 * BYTE_S + emu.servo(1).return_delay_s + DEFAULT_REPLY_LATENCY_S + 15 * BYTE_S  # 0.84 ms
    trips = []
    for _ in range(3):
        t0 = clock.now()
        bus.read(1, Reg.PRESENT_POSITION)         # 14-byte request, 15-byte status
        trips.append(clock.now() - t0)
    if latency_ms is None:
        assert trips == [pytest.approx(cable_s, abs=1e-12)] * 3
    else:
        # the status leaves the cable 0.84 ms after the request starts; the adapter's timer,
        # restarted by its previous send, lets it go a whole period after that send
        assert trips == [pytest.approx(latency_ms * MS, abs=1e-12)] * 3
        assert emu.adapter.last_send_s == pytest.approx(3 * latency_ms * MS, abs=1e-12)


def test_a_write_without_reply_costs_no_adapter_time(lockstep_bus):
    latency_ms, emu, bus, clock = lockstep_bus
    t0, sent = clock.now(), bus.bytes_written
    bus.sync_write(Reg.LED, {1: 1, 2: 1})          # no status frames: nothing through the adapter
    assert bus.bytes_written - sent == 18           # 14 bytes of frame + 2 x (ID, data)
    assert clock.now() - t0 == pytest.approx(18 * BYTE_S, abs=1e-12)


def test_wire_timing_on_the_wall_clock_never_delivers_before_the_adapter_sends():
    with build_emulator(ids=[1], link=LinkSettings(wire_timing=True), adapter_latency_ms=16, timing=Frozen()) as emu:
        with Bus(emu.port, 1_000_000, default_model="xh430-w210", timeout_margin_s=0.5) as bus:
            bus.read(1, Reg.PRESENT_POSITION)
            received = time.monotonic()
        sent = emu.adapter.last_send_s               # monotonic s of the adapter's send
        assert _on_grid(sent, 16 * MS)               # on its timer's 16 ms period from 0
        assert received >= sent


# --- the robot file and the command line ----------------------------------------------------

def _robot_text(line: str | None) -> str:
    text = DEFAULT_PATH.read_text()
    old = "  adapter_latency_ms: 1\n"
    assert old in text
    return text.replace(old, "" if line is None else f"  adapter_latency_ms: {line}\n")


def test_the_shipped_robot_file_states_a_1_ms_adapter():
    assert load_robot_config(DEFAULT_PATH).link.adapter_latency_ms == 1


@pytest.mark.parametrize("line, expected", [("16", 16), ("255", 255), ("null", None), (None, None)])
def test_robot_file_adapter_latency(line, expected):
    cfg = parse_robot_config(parse_yaml_text(_robot_text(line), "robot.yaml"))
    assert cfg.link.adapter_latency_ms == expected


@pytest.mark.parametrize("line, problem", [("0", "0 is outside [1, 255]"), ("256", "256 is outside [1, 255]"),
                                           ("1.5", "expected an integer"), (".nan", "expected an integer"),
                                           ("-3", "-3 is outside [1, 255]")])
def test_robot_file_bad_adapter_latency_names_file_line_and_key(line, problem):
    with pytest.raises(ConfigError) as exc:
        parse_robot_config(parse_yaml_text(_robot_text(line), "robot.yaml"))
    msg = str(exc.value)
    assert msg.startswith("robot.yaml:") and "link.adapter_latency_ms" in msg and problem in msg
    assert "\n" not in msg


@pytest.mark.parametrize("command", [["emulate"], ["run", "--trajectory", "line", "--emulate", "--lockstep"]])
@pytest.mark.parametrize("value", ["nan", "-1", "0", "256", "1e3", "16.5", "", "inf"])
def test_adapter_latency_option_bad_values_one_line_exit_2(command, value, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--adapter-latency-ms", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "--adapter-latency-ms: must be an integer >= 1 and <= 255, got" in err


def test_run_refuses_the_option_without_the_emulator(capsys):
    assert main(["run", "--trajectory", "line", "--adapter-latency-ms", "1", "--no-log"]) == 2
    assert "--adapter-latency-ms needs --emulate" in capsys.readouterr().err


def test_emulate_option_reaches_the_emulated_adapter():
    proc = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", "--lockstep", "--frozen",
                             "--ids", "1", "--adapter-latency-ms", "16"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        port, baud, _ = parse_port_line(line)
        with LockstepLoopClock(parse_control(line)) as clock, Bus(port, baud, default_model="xh430-w210",
                                                              timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            assert clock.info()["adapter_latency_ms"] == 16
            t0 = clock.now()
            bus.read(1, Reg.PRESENT_POSITION)
            assert clock.now() - t0 == pytest.approx(16 * MS, abs=1e-12)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
        assert "USB adapter latency timer 16 ms" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_a_lockstep_run_through_a_16_ms_adapter_overruns_every_cycle():
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    s = run_tracking(RunRequest(trajectory="line", emulate=True, lockstep=True, time_scale=None,
                                adapter_latency_ms=16)).summary.to_dict()
    # the read ends 18.2 ms into its 16 ms slot: every cycle runs into the next slot, which is skipped
    assert s["completed"] and s["overruns"] == s["cycles"] == s["missed_slots"] == 1250
    assert s["loop_period_p50_ms"] == pytest.approx(32.0, abs=1e-9)


@given(st.floats(0.0, 100.0), st.lists(st.tuples(st.floats(0.0, 3e-3), st.integers(0, 200)), max_size=10),
       st.sampled_from([BYTE_S, 10 / 57_600, 10 / 4_500_000]), latencies, st.floats(0.0, 100.0))
@example(0.0, [(0.5 * MS, 168)], BYTE_S, 16, 0.0)
@example(12.345, [(50e-6, 21)] * 8, BYTE_S, 1, 12.0)
@settings(max_examples=300, deadline=None)
def test_lazy_arrivals_are_the_listed_ones_and_deliver_the_same(start_s, frames, byte_s, latency_ms, last_s):
    """The arrival times computed per index are those of a byte-by-byte walk, and the delivery
    found by bisection over them is the one a scan of the listed times gives."""
    listed, t = [], start_s
    for gap_s, n in frames:
        t += gap_s
        listed += [t + k * byte_s for k in range(1, n + 1)]
        t += n * byte_s
    lazy = byte_arrivals(start_s, frames, byte_s)
    assert len(lazy) == len(listed) and list(lazy) == listed and lazy[:] == listed
    s = AdapterSettings(latency_ms)
    a, b = deliver(s, lazy, last_s), deliver(s, listed, last_s)
    assert (a.times_s, a.last_send_s, a.end_s) == (b.times_s, b.last_send_s, b.end_s)


@given(st.floats(0.0, 100.0), st.lists(st.tuples(st.floats(0.0, 3e-3), st.integers(0, 70)), max_size=10),
       st.sampled_from([0.0, BYTE_S, 10 / 57_600]), st.data())
@example(12.345, [(50e-6, 21)] * 8, BYTE_S, None)
@settings(max_examples=300, deadline=None)
def test_arrivals_bisect_as_bisect_does_over_their_items(start_s, frames, byte_s, data):
    """``ByteArrivals.bisect_right`` gives :func:`bisect.bisect_right` over the listed times, for
    any time (an item's own, between items, outside them) and index range."""
    lazy = byte_arrivals(start_s, frames, byte_s)
    listed = list(lazy)
    n = len(listed)
    probes = [*listed[:1], *listed[-1:], start_s - 1.0, start_s + 1.0]
    if data is None:
        cases = [(t, 0, n) for t in probes]
    else:
        t = data.draw(st.one_of(st.sampled_from(probes), st.floats(start_s - 1e-3, start_s + 0.05)))
        cases = [(t, data.draw(st.integers(0, n + 2)), data.draw(st.integers(0, n)))]
    for t, lo, hi in cases:
        assert lazy.bisect_right(t, lo, hi) == bisect.bisect_right(listed, t, lo, hi)


def test_arrivals_refuse_a_negative_gap_or_byte_time():
    with pytest.raises(ValueError, match="gap"):
        byte_arrivals(0.0, [(-1e-6, 3)], BYTE_S)
    with pytest.raises(ValueError, match="byte time"):
        byte_arrivals(0.0, [(0.0, 3)], -BYTE_S)
