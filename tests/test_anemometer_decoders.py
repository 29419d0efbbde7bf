"""Protocol decoders: split streams, junk between messages, random bytes, status and counters."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.anemometer.base import WindSample
from drivers.anemometer.campbell import CampbellCSAT3BDecoder, campbell_signature, format_csat3b
from drivers.anemometer.gill import GillDecoder, format_gill_polar, format_gill_uvw, xor_checksum
from drivers.anemometer.metek import MetekDecoder, format_metek
from drivers.anemometer.registry import PROTOCOLS, make_decoder
from drivers.anemometer.young import Young81000Decoder, format_young

SETTINGS = settings(
    max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

speed = st.floats(-30, 30, allow_nan=False)


def gill_msg(draw: st.DrawFn) -> bytes:
    return format_gill_uvw(
        draw(speed),
        draw(speed),
        draw(speed),
        draw(st.floats(320, 360)),
        draw(st.floats(-20, 40)),
        draw(st.sampled_from([0x00, 0x0B, 0x60, 0x01])),
    )


def csat_msg(draw: st.DrawFn) -> bytes:
    return format_csat3b(
        draw(speed),
        draw(speed),
        draw(speed),
        draw(st.floats(-20, 40)),
        draw(st.sampled_from([0, 0, 4])),
        draw(st.integers(0, 255)),
    )


def young_msg(draw: st.DrawFn) -> bytes:
    return format_young(
        draw(st.floats(0, 30)),
        draw(st.floats(0, 359.9)),
        draw(st.floats(-60, 60)),
        draw(st.floats(320, 360)),
        draw(st.floats(-20, 40)),
    )


def metek_msg(draw: st.DrawFn) -> bytes:
    return format_metek(
        draw(st.integers(-3000, 3000)),
        draw(st.integers(-3000, 3000)),
        draw(st.integers(-3000, 3000)),
        draw(st.integers(-2000, 4000)),
        draw(st.sampled_from(["M", "H", "D"])),
    )


# protocol -> (decoder factory, message generator, junk must end with a line terminator)
CASES = {
    "gill": (GillDecoder, gill_msg, False),
    "campbell_csat3b": (CampbellCSAT3BDecoder, csat_msg, False),
    "young_81000": (Young81000Decoder, young_msg, True),
    "metek_usonic3": (MetekDecoder, metek_msg, False),
}


def _alone(factory, msg: bytes, ns: int) -> WindSample:
    """The sample a fresh decoder makes of one message on its own (the oracle)."""
    (sample,) = factory().decode_all(msg, ns)
    return sample


def _same(a: WindSample, b: WindSample) -> bool:
    ta, tb = a.as_dict(), b.as_dict()
    ta.pop("counter"), tb.pop("counter")
    for k in ta:
        x, y = ta[k], tb[k]
        if isinstance(x, float) and math.isnan(x) and isinstance(y, float) and math.isnan(y):
            continue
        if x != y:
            return False
    return True


def _stream(draw: st.DrawFn, protocol: str, junk: bool):
    factory, make, junk_needs_eol = CASES[protocol]
    msgs = [make(draw) for _ in range(draw(st.integers(1, 8)))]
    parts: list[bytes] = []
    starts: list[int] = []
    pos = 0
    for m in msgs:
        if junk and draw(st.booleans()):
            g = draw(st.binary(min_size=1, max_size=40))
            if junk_needs_eol:
                g += b"\r\n"
            parts.append(g)
            pos += len(g)
        starts.append(pos)
        parts.append(m)
        pos += len(m)
    data = b"".join(parts)
    cuts = sorted(set(draw(st.lists(st.integers(1, max(1, len(data) - 1)), max_size=12))))
    return factory, msgs, starts, data, cuts


def _feed(decoder, data: bytes, cuts: list[int]) -> list[WindSample]:
    out: list[WindSample] = []
    bounds = [0, *cuts, len(data)]
    for k in range(len(bounds) - 1):
        out.extend(decoder.feed(data[bounds[k] : bounds[k + 1]], 1000 * k))
    out.extend(decoder.flush())
    return out


def _chunk_of(offset: int, cuts: list[int]) -> int:
    return sum(1 for c in cuts if c <= offset)


@pytest.mark.parametrize("protocol", sorted(CASES))
@SETTINGS
@given(data=st.data())
def test_split_stream_recovers_every_message_with_first_byte_stamp(protocol: str, data) -> None:
    factory, msgs, starts, stream, cuts = _stream(data.draw, protocol, junk=False)
    decoder = factory()
    got = _feed(decoder, stream, cuts)
    want = [
        _alone(factory, m, 1000 * _chunk_of(s, cuts)) for m, s in zip(msgs, starts, strict=True)
    ]
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert _same(g, w), (g, w)
    assert decoder.counts.checksum_failures == 0
    assert decoder.counts.malformed == 0


@pytest.mark.parametrize("protocol", sorted(CASES))
@SETTINGS
@given(data=st.data())
def test_junk_between_messages_loses_no_message(protocol: str, data) -> None:
    factory, msgs, starts, stream, cuts = _stream(data.draw, protocol, junk=True)
    got = _feed(factory(), stream, cuts)
    want = [
        _alone(factory, m, 1000 * _chunk_of(s, cuts)) for m, s in zip(msgs, starts, strict=True)
    ]
    # Every sent message comes out, in order, with its first byte's stamp; junk may add
    # nothing else for the checksummed protocols.
    it = iter(got)
    for w in want:
        assert any(_same(g, w) for g in it), f"lost {w}"
    if protocol in ("gill", "campbell_csat3b"):
        assert len(got) == len(want)


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
@settings(max_examples=80, deadline=None, derandomize=True)
@given(chunks=st.lists(st.binary(max_size=200), max_size=10))
def test_random_bytes_never_raise(protocol: str, chunks: list[bytes]) -> None:
    decoder = make_decoder(protocol)
    for i, c in enumerate(chunks):
        for s in decoder.feed(c, i):
            assert isinstance(s, WindSample)
    decoder.flush()
    counts = decoder.counts
    assert 0 <= counts.valid <= counts.messages


def test_gill_checksum_is_xor_between_stx_and_etx() -> None:
    frame = format_gill_uvw(1.5, -2.25, 0.125, 343.2, 21.9, 0)
    payload = frame[1 : frame.index(b"\x03")]
    x = 0
    for b in payload:
        x ^= b
    assert xor_checksum(payload) == x
    assert frame.endswith(b"\x03%02X\r\n" % x)
    (s,) = GillDecoder().decode_all(frame)
    assert (s.u, s.v, s.w) == (1.5, -2.25, 0.125)
    assert (s.speed_of_sound, s.sonic_temperature) == (343.2, 21.9)
    assert s.valid and s.status_text == "OK"


def test_gill_bad_checksum_counted_not_emitted() -> None:
    frame = bytearray(format_gill_uvw(1.0, 2.0, 3.0, 340.0, 20.0))
    frame[5] ^= 0x01  # one flipped bit inside the payload
    d = GillDecoder()
    assert d.decode_all(bytes(frame)) == []
    assert d.counts.checksum_failures == 1 and d.counts.messages == 0


def test_gill_units_status_and_short_form() -> None:
    payload = b"Q,+010.00,-002.00,+000.50,N,00,"
    frame = b"\x02" + payload + b"\x03%02X\r\n" % xor_checksum(payload)
    (s,) = GillDecoder().decode_all(frame)
    assert s.u == pytest.approx(10 * 1852 / 3600) and math.isnan(s.speed_of_sound)
    d = GillDecoder()
    (bad,) = d.decode_all(format_gill_uvw(0, 0, 0, 340, 20, status=0x01))
    assert not bad.valid and bad.status_text == "axis 1 failed"
    (warn,) = d.decode_all(format_gill_uvw(0, 0, 0, 340, 20, status=0x0B))
    assert warn.valid and d.counts.status_errors == 2 and d.counts.valid == 1


def test_gill_polar_direction_is_where_wind_comes_from() -> None:
    # Wind from the north mark (0 deg) blows toward -U; from 90 deg (right of the mark,
    # clockwise) it blows toward +V (left).
    (n,) = GillDecoder().decode_all(format_gill_polar(0, 5.0, 344.0, 20.0, 0x60))
    assert n.u == pytest.approx(-5.0) and n.v == pytest.approx(0.0, abs=1e-12)
    (e,) = GillDecoder().decode_all(format_gill_polar(90, 5.0, 344.0, 20.0, 0x60))
    assert e.v == pytest.approx(5.0) and math.isnan(e.w) and e.valid


def test_gill_new_stx_abandons_cut_frame() -> None:
    good = format_gill_uvw(1, 2, 3, 340, 20)
    d = GillDecoder()
    out = d.decode_all(good[:20] + good)
    assert len(out) == 1 and d.counts.resyncs == 1


def test_campbell_signature_known_line() -> None:
    body = b"-2.17605,-4.00771,0.14649,30.70251,0,11"
    assert campbell_signature(body) == 0x3C57


def test_campbell_counter_gap_and_diag() -> None:
    d = CampbellCSAT3BDecoder()
    stream = b"".join(format_csat3b(1, 2, 3, 20, 0, c) for c in (254, 255, 0, 3))
    stream += format_csat3b(1, 2, 3, 20, 8, 4)
    out = d.decode_all(stream)
    assert [s.counter for s in out] == [254, 255, 0, 3, 4]
    assert d.counts.counter_gaps == 1 and d.counts.missed_records == 2
    assert not out[-1].valid and d.counts.status_errors == 1 and "bits 3" in out[-1].status_text


def test_campbell_bad_signature_counted() -> None:
    line = bytearray(format_csat3b(1, 2, 3, 20, 0, 5))
    line[0:1] = b"7"
    d = CampbellCSAT3BDecoder()
    assert d.decode_all(bytes(line)) == []
    assert d.counts.checksum_failures == 1


def test_campbell_timestamp_prefix_is_skipped() -> None:
    d = CampbellCSAT3BDecoder()
    line = b"2023-07-31T04:01:00.029633Z\t-2.17605,-4.00771,0.14649,30.70251,0,11,3c57\r\n"
    out = d.decode_all(line)
    assert len(out) == 1 and out[0].u == -2.17605
    assert d.counts.skipped_bytes == 28 and d.counts.resyncs == 0


def test_young_polar_and_uvw() -> None:
    (s,) = Young81000Decoder().decode_all(format_young(10.0, 90.0, 0.0, 343.0, 20.0))
    # From 90 deg (east of the mark) the wind blows toward -U (west).
    assert s.u == pytest.approx(-10.0) and s.v == pytest.approx(0.0, abs=1e-9)
    (s,) = Young81000Decoder().decode_all(format_young(10.0, 0.0, 30.0, 343.0, 20.0))
    assert s.w == pytest.approx(5.0) and s.v == pytest.approx(-10 * math.cos(math.radians(30)))
    uvw = format_young(1.0, -2.0, 0.5, 343.0, 20.0, uvw=True)
    (s,) = make_decoder("young_81000_uvw").decode_all(uvw)
    assert (s.u, s.v, s.w) == (1.0, -2.0, 0.5)
    d = Young81000Decoder()
    (bad,) = d.decode_all(format_young(99.0, 10.0, 0.0, 343.0, 20.0))
    assert not bad.valid and d.counts.status_errors == 1


def test_metek_units_and_prefixes() -> None:
    d = MetekDecoder()
    out = d.decode_all(
        format_metek(-123, 456, -78, 2345)
        + format_metek(1, 1, 1, 1, "H")
        + format_metek(1, 1, 1, 1, "D")
        + b"M:x = garbage\r\n"
    )
    assert (out[0].u, out[0].v, out[0].w, out[0].sonic_temperature) == (-1.23, 4.56, -0.78, 23.45)
    assert out[1].valid and not out[2].valid
    assert d.counts.status_errors == 1 and d.counts.malformed == 1


def test_registry_rejects_unknown_names() -> None:
    from drivers.anemometer.base import AnemometerConfigError
    from drivers.anemometer.registry import make_anemometer

    with pytest.raises(AnemometerConfigError, match="unknown anemometer protocol 'nope'"):
        make_decoder("nope")
    with pytest.raises(AnemometerConfigError, match="bad options"):
        make_decoder("gill", colour="red")
    with pytest.raises(AnemometerConfigError, match="unknown anemometer back end"):
        make_anemometer("usb-magic")


def test_gill_stray_etx_cannot_swallow_next_frame() -> None:
    good = format_gill_uvw(1, 2, 3, 340, 20)
    d = GillDecoder()
    out = d.decode_all(b"\x02junk\x03" + good)
    assert len(out) == 1 and d.counts.malformed == 1


TOKENS = [
    b"\x02",
    b"\x03",
    b",",
    b"\r",
    b"\n",
    b"M:x =",
    b" y = ",
    b"1",
    b"-",
    b".",
    b"A",
    b"nan",
    b" ",
    b"3c57",
    b"FF",
    b"\x00",
    b"\xff",
    b"+344.54",
    b"60",
]


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
@settings(max_examples=80, deadline=None, derandomize=True)
@given(
    tokens=st.lists(st.sampled_from(TOKENS), max_size=120),
    cuts=st.lists(st.integers(0, 400), max_size=8),
)
def test_protocol_like_noise_never_raises(protocol: str, tokens: list[bytes], cuts) -> None:
    data = b"".join(tokens)
    decoder = make_decoder(protocol)
    out = _feed(decoder, data, sorted(c for c in set(cuts) if 0 < c < len(data)))
    assert all(isinstance(s, WindSample) for s in out)
    assert decoder.counts.messages == len(out)
