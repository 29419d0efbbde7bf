"""Serial back end on ptys and loop://: unplug/replug, stale reopen, Gill set-up, replay, reader."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from drivers.anemometer.base import (
    Anemometer,
    AnemometerConfigError,
    DecoderCounts,
    WindSample,
)
from drivers.anemometer.campbell import format_csat3b
from drivers.anemometer.reader import AnemometerReader
from drivers.anemometer.registry import make_anemometer
from drivers.anemometer.replay import ReplayAnemometer
from drivers.anemometer.serial_transport import SerialAnemometer
from drivers.anemometer.simulated import SimulatedSensor, WindModel

DATA = Path(__file__).parent / "data" / "anemometer"
FAST = {"read_timeout_s": 0.02, "backoff_initial_s": 0.02, "backoff_max_s": 0.1}


def wait_for(cond: Callable[[], bool], timeout: float = 5.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise AssertionError("condition not reached in time")
        time.sleep(0.01)


def drain(reader: AnemometerReader) -> list[WindSample]:
    out = []
    while (s := reader.get(timeout=0)) is not None:
        out.append(s)
    return out


def test_unplug_replug_recovers_and_loses_nothing_after_reconnect(tmp_path: Path) -> None:
    link = tmp_path / "ttyGILL"
    sensor = SimulatedSensor(100.0, WindModel("turbulent", seed=3), link_path=str(link)).start()
    anemometer = SerialAnemometer("gill", str(link), reopen_after_s=5.0, **FAST)
    reader = AnemometerReader(anemometer, poll_s=0.05).start()
    try:
        wait_for(lambda: reader.received >= 10)
        sensor.unplug()
        wait_for(lambda: anemometer.stats["disconnects"] >= 1)
        time.sleep(0.1)  # the driver keeps retrying a port that is gone
        assert anemometer.stats["open_failures"] >= 1
        sensor.replug()
        wait_for(lambda: anemometer.stats["connects"] >= 2)
        connected_ns = anemometer.connected_ns
        assert connected_ns is not None
        n_before = len([f for f in sensor.sent() if f.host_ns > connected_ns])
        wait_for(lambda: sum(f.host_ns > connected_ns for f in sensor.sent()) >= n_before + 30)
        sensor.pause()
        sent_after = [(f.u, f.v, f.w) for f in sensor.sent() if f.host_ns > connected_ns]
        got: list[tuple[float, float, float]] = []

        def all_through() -> bool:
            got.extend((s.u, s.v, s.w) for s in drain(reader) if s.host_ns > connected_ns)
            return len(got) >= len(sent_after)

        # Let the last frames through the pty (a loaded CI machine may need a while); a lost
        # frame shows up in the comparison below.
        with contextlib.suppress(AssertionError):
            wait_for(all_through, timeout=5.0)
        time.sleep(0.05)
        all_through()
    finally:
        reader.stop()
        sensor.stop()
    assert len(sent_after) >= 30
    # Every frame written after the reconnect arrived, in order (a frame written between
    # pyserial's input flush on open and our connect stamp may come on top).
    assert got[len(got) - len(sent_after) :] == sent_after
    assert len(got) - len(sent_after) <= 1
    assert anemometer.counts.checksum_failures == 0
    assert reader.dropped == 0


def test_silent_port_is_reopened() -> None:
    anemometer = SerialAnemometer("gill", "loop://", reopen_after_s=0.1, **FAST)
    try:
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            assert anemometer.recv(0.05) is None
        assert anemometer.stats["reopens"] >= 2
        assert "no valid message" in anemometer.last_error
    finally:
        anemometer.close()


def test_loop_reassembles_csat3b_written_in_pieces() -> None:
    anemometer = SerialAnemometer("campbell_csat3b", "loop://", **FAST)
    try:
        assert anemometer.recv(0.05) is None  # opens the port
        stream = b"".join(format_csat3b(0.1 * i, -1, 0.5, 20, 0, i) for i in range(20))
        for k in range(0, len(stream), 7):
            anemometer.transport.write(stream[k : k + 7])
        got = []
        end = time.monotonic() + 3
        while len(got) < 20 and time.monotonic() < end:
            s = anemometer.recv(0.1)
            if s is not None:
                got.append(s)
        assert [s.counter for s in got] == list(range(20))
        assert anemometer.counts.counter_gaps == 0
    finally:
        anemometer.close()


def test_gill_setup_checked_against_sensor_replies(tmp_path: Path) -> None:
    with SimulatedSensor(50.0, link_path=str(tmp_path / "tty")) as sensor:
        ok = SerialAnemometer(
            "gill",
            sensor.link_path,
            gill_setup={"commands": ["M2", "P20"], "reply_timeout_s": 1.0},
            **FAST,
        )
        try:
            assert ok.recv(2.0) is not None
            assert ok.stats["setup_failures"] == 0 and ok.stats["connects"] == 1
        finally:
            ok.close()
        bad = SerialAnemometer(
            "gill",
            sensor.link_path,
            gill_setup={"commands": ["BOGUS"], "reply_timeout_s": 0.3},
            **FAST,
        )
        try:
            assert bad.recv(0.3) is None
            assert bad.stats["setup_failures"] >= 1 and bad.stats["connects"] == 0
            assert "expected 'BOGUS'" in bad.last_error and "INVALID" in bad.last_error
        finally:
            bad.close()


def test_serial_config_errors_name_the_value() -> None:
    with pytest.raises(AnemometerConfigError, match="baudrate"):
        SerialAnemometer("gill", "loop://", baudrate=-5)
    with pytest.raises(AnemometerConfigError, match="parity"):
        SerialAnemometer("gill", "loop://", parity="X")
    with pytest.raises(AnemometerConfigError, match="gill_setup"):
        SerialAnemometer("campbell_csat3b", "loop://", gill_setup={"commands": ["M2"]})


def test_simulated_backend_from_registry_reports_true_wind() -> None:
    anemometer = make_anemometer(
        "simulated", rate_hz=50, wind="constant", mean_wind=(1.5, -0.5, 0.25), **FAST
    )
    try:
        sample = anemometer.recv(10.0)
        assert sample is not None and sample.valid
        assert (sample.u, sample.v, sample.w) == (1.5, -0.5, 0.25)
        truth = anemometer.sensor.true_wind(sample.host_ns)
        assert truth is not None and list(truth) == [1.5, -0.5, 0.25]
    finally:
        anemometer.close()


def test_wind_models_are_seeded() -> None:
    a = [WindModel("turbulent", (3, 0, 0), seed=7).at(0.05 * k) for k in range(5)]
    b = [WindModel("turbulent", (3, 0, 0), seed=7).at(0.05 * k) for k in range(5)]
    assert all((x == y).all() for x, y in zip(a, b, strict=True))
    g = WindModel("gusty", (3, 0, 0), seed=1)
    speeds = [float((g.at(0.1 * k) ** 2).sum() ** 0.5) for k in range(200)]
    assert min(speeds) >= 3.0 - 1e-9 and max(speeds) > 3.5
    with pytest.raises(AnemometerConfigError, match="wind must be one of"):
        WindModel("hurricane")


def test_replay_timestamped_capture_plays_every_message(tmp_path: Path) -> None:
    src = DATA / "campbell_csat3b" / "csat3b_ascii_dsm5_id60_timestamped.tsv"
    capture = tmp_path / "short.tsv"
    capture.write_bytes(b"".join(src.read_bytes().splitlines(keepends=True)[:41]))
    replay = ReplayAnemometer(str(capture), "campbell_csat3b", speed=20.0)
    got = []
    end = time.monotonic() + 5
    while time.monotonic() < end and not (replay.finished and len(got) == 40):
        s = replay.recv(0.1)
        if s is not None:
            got.append(s)
    assert len(got) == 40
    assert got[0].counter == 11 and got[0].u == -2.17605
    assert [s.host_ns for s in got] == sorted(s.host_ns for s in got)
    with pytest.raises(AnemometerConfigError, match="not found"):
        ReplayAnemometer(str(tmp_path / "missing.tsv"), "gill")


def test_replay_raw_capture_at_rate(tmp_path: Path) -> None:
    capture = tmp_path / "raw.txt"
    capture.write_bytes(b"".join(format_csat3b(1, 2, 3, 20, 0, i) for i in range(10)))
    replay = make_anemometer("replay", path=str(capture), protocol="campbell_csat3b",
                             format="raw", rate_hz=500)
    got = []
    while not (replay.finished and len(got) >= 10):
        s = replay.recv(0.1)
        assert s is not None or replay.finished, "replay stalled"
        if s is not None:
            got.append(s)
    assert [s.counter for s in got] == list(range(10)) and replay.finished


class _Burst(Anemometer):
    """A back end that delivers samples as fast as asked (for the reader)."""

    backend = "burst"

    def __init__(self, n: int) -> None:
        super().__init__()
        self.left = n
        self._counts = DecoderCounts()

    @property
    def counts(self) -> DecoderCounts:
        return self._counts

    def _recv_internal(self, timeout: float) -> WindSample | None:
        if self.left == 0:
            time.sleep(timeout)
            return None
        self.left -= 1
        return WindSample(self.left, self.left, 1.0, 0.0, 0.0, 340.0, 20.0, 0, "OK", True)


def test_reader_drops_oldest_instead_of_blocking() -> None:
    calls = []

    def flaky(sample: WindSample) -> None:
        calls.append(sample.counter)
        if sample.counter == 50:
            raise RuntimeError("consumer bug")

    reader = AnemometerReader(_Burst(100), queue_size=10, on_sample=flaky, poll_s=0.01).start()
    try:
        wait_for(lambda: reader.received == 100)
    finally:
        reader.stop()
    assert reader.dropped == 90 and reader.samples.qsize() == 10
    assert [s.counter for s in drain(reader)] == list(range(9, -1, -1))
    assert reader.callback_errors == 1 and isinstance(reader.last_callback_error, RuntimeError)
    assert len(calls) == 100


@pytest.mark.parametrize("protocol", ["campbell_csat3b", "young_81000_uvw", "metek_usonic3"])
def test_simulator_speaks_other_protocols(protocol: str) -> None:
    anemometer = make_anemometer(
        "simulated", protocol=protocol, rate_hz=100, wind="turbulent", seed=2, **FAST
    )
    try:
        got = []
        end = time.monotonic() + 10
        while len(got) < 5 and time.monotonic() < end:
            s = anemometer.recv(0.2)
            if s is not None:
                got.append(s)
        assert len(got) == 5 and all(s.valid for s in got)
        for s in got:
            truth = anemometer.sensor.true_wind(s.host_ns)
            assert truth is not None
        sent = {(f.u, f.v, f.w) for f in anemometer.sensor.sent()}
        assert all((s.u, s.v, s.w) in sent for s in got)
        assert anemometer.counts.checksum_failures == anemometer.counts.malformed == 0
    finally:
        anemometer.close()


def test_replay_of_the_gill_ship_log(tmp_path: Path) -> None:
    src = DATA / "gill_windobserver" / "NBP1406_mwx1-2014-08-01.part1"
    capture = tmp_path / "ship.log"
    capture.write_bytes(b"".join(src.read_bytes().splitlines(keepends=True)[:9]))
    replay = make_anemometer("replay", path=str(capture), protocol="gill", speed=40.0)
    got = []
    end = time.monotonic() + 5
    while time.monotonic() < end and not (replay.finished and len(got) == 6):
        s = replay.recv(0.1)
        if s is not None:
            got.append(s)
    # 9 lines: 3 MET lines of another instrument, 6 Gill frames.
    assert len(got) == 6 and replay.counts.checksum_failures == 0
    assert got[0].speed_of_sound == 344.0 and got[1].speed_of_sound == 344.54
