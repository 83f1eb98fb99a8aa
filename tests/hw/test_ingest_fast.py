"""The fast ingest paths give exactly what their references give.

* CAN: :class:`hw.can_nav.FastMessage` (direct bit unpacking) against cantools' own decode, on
  every DBC message and random payloads; the decoder's fast path against its cantools path.
* NMEA: the XOR-fold checksum against a byte loop; :func:`hw.nmea.split_sentence` against a
  plain reference parser (the textbook steps: strip, '$', '*hh', byte-loop XOR, split).
* ``make_fix`` against ``NavFix(...)``.
"""

from __future__ import annotations

import dataclasses
import pickle
import random
import re

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.io.atrlog import LogRecord
from atr_node.records.nav import NavFix, make_fix
from hw.can_nav import (CanNavDecoder, compile_message, encode_altitude, encode_attitude, encode_leg,
                        encode_position, encode_time, load_dbc)
from hw.decode import NavDecoder
from hw.nmea import (NmeaReject, _fast_checksum, encode_dpt, encode_gga, encode_hdt, encode_rmc,
                     encode_ths, encode_vtg, encode_zda, parse_sentence, split_sentence)
from hw.nmea_decoder import NmeaDecoder

# --- CAN ---------------------------------------------------------------------------------------


def _special_payloads(message) -> list[bytes]:
    """All zeros, all ones, and each signal at its sign boundary and at all ones (choices such
    as NotAvailable = 65535 live there)."""
    out = [bytes(8), b"\xff" * 8]
    for sg in message.signals:
        for raw in (1 << (sg.length - 1), (1 << (sg.length - 1)) - 1, (1 << sg.length) - 1, 1):
            out.append((raw << sg.start).to_bytes(message.length, "little"))
    return out


@pytest.mark.parametrize("name", [m.name for m in load_dbc().messages])
def test_fast_message_equals_cantools_decode(name):
    message = load_dbc().get_message_by_name(name)
    fm = compile_message(message)
    assert fm is not None, f"{name} should be decodable by the fast path"
    rng = random.Random(7)
    payloads = _special_payloads(message) + [rng.randbytes(message.length) for _ in range(3000)]
    for data in payloads:
        want = message.decode(data, decode_choices=True, scaling=True)
        got = fm.decode(data)
        assert list(got) == list(want), data.hex()  # same keys, same order
        for k in want:
            assert type(got[k]) is type(want[k]) and got[k] == want[k], (name, k, data.hex())
            if not isinstance(want[k], (int, float)):
                assert got[k] is want[k]  # the same NamedSignalValue object


def test_compile_declines_what_it_cannot_reproduce():
    db = cantools.database.load_string('''VERSION ""
NS_ :
BS_:
BU_: A
BO_ 16 BigEndian: 8 A
 SG_ Motorola : 7|16@0+ (0.5,0) [0|100] "" A
BO_ 17 FloatSig: 8 A
 SG_ F : 0|32@1- (1,0) [0|0] "" A
BO_ 18 Muxed: 8 A
 SG_ Mux M : 0|8@1+ (1,0) [0|255] "" A
 SG_ Val m1 : 8|16@1+ (1,0) [0|65535] "" A
BO_ 19 Plain: 8 A
 SG_ X : 3|12@1- (0.25,-1) [-512|511] "" A
SIG_VALTYPE_ 17 F : 1;
''', database_format="dbc")
    assert compile_message(db.get_message_by_name("BigEndian")) is None
    assert compile_message(db.get_message_by_name("FloatSig")) is None
    assert compile_message(db.get_message_by_name("Muxed")) is None
    plain = db.get_message_by_name("Plain")  # an odd start bit, a signed 12-bit signal, an offset
    fm = compile_message(plain)
    rng = random.Random(3)
    for data in [rng.randbytes(8) for _ in range(2000)] + _special_payloads(plain):
        assert fm.decode(data) == plain.decode(data)


def _frames(rng: random.Random) -> list[tuple]:
    """Good frames from the encoders, then the same with broken ids, lengths, flags and types."""
    good = [encode_time(1.7e9 + rng.random() * 1e3), encode_position(rng.uniform(-90, 90), rng.uniform(-180, 180)),
            encode_attitude(rng.uniform(0, 360), speed_m_s=rng.choice([None, 2.5])),
            encode_altitude(rng.choice([None, 12.0]), depth_m=rng.choice([None, 30.0])),
            encode_leg(rng.randrange(4), survey=rng.random() < 0.5)]
    out = []
    for fid, data, ext in good:
        out.append((fid, data, ext))
        out.append((fid, rng.randbytes(8), ext))  # random payloads: invalid values, NotAvailable
        out.append((fid, data[:rng.randrange(8)], ext))  # short: cantools rejects
        out.append((fid, data + rng.randbytes(rng.randrange(1, 4)), ext))  # long: rejected (cantools trims)
        out.append((fid, data, True))  # extended flag on a standard frame
        out.append((fid, bytearray(data), ext))  # not bytes: the cantools path
        out.append((fid + rng.choice([5, 0x700, 0x1FFF_0000]), data, ext))  # not in the DBC
        out.append((float(fid), data, ext))  # a float id: the cantools lookup's behaviour
    return out


def test_decoder_fast_path_equals_cantools_path():
    rng = random.Random(11)
    fast, reference = CanNavDecoder(), CanNavDecoder()
    reference._fast = {}  # every frame through cantools: the reference behaviour
    assert fast._fast, "the shipped DBC compiles"
    for _ in range(150):
        for frame in _frames(rng):
            t = 1.7e9 + rng.random()
            got = _outcome(fast, frame, t)
            want = _outcome(reference, frame, t)
            assert got == want, frame
            assert fast.last_reject == reference.last_reject
    assert fast.counts == reference.counts
    assert set(fast.counts) >= {"accepted", "unknown", "bad_length", "out_of_range"}


def _outcome(decoder: CanNavDecoder, frame: tuple, t: float) -> str:
    try:
        return repr(decoder.feed(*frame, t))  # repr: floats compared bit for bit
    except Exception as exc:  # the same exception, raised the same way, on both paths
        return f"raised {type(exc).__name__}: {exc}"


def test_nav_decoder_record_checks_unchanged():
    d = NavDecoder()
    fid, data, _ = encode_position(44.0, 9.0)
    good = d.feed(LogRecord(1.0, "can", {"id": fid, "data": data, "ext": False}))
    assert len(good) == 1 and good[0].lat_deg == pytest.approx(44.0, abs=1e-7)
    # not exact types: converted as before (bool id -> 1 is not in the DBC, int ext -> bool)
    assert d.feed(LogRecord(1.0, "can", {"id": True, "data": data, "ext": False})) == []
    assert d.feed(LogRecord(1.0, "can", {"id": fid, "data": bytearray(data), "ext": 0}))[0] == good[0]
    for bad in ({"id": fid, "data": 5, "ext": False}, {"id": "x", "data": data, "ext": False}, {"data": data}, None):
        assert d.feed(LogRecord(1.0, "can", bad)) == []
    assert d.can.counts["bad_frame"] == 4 and d.can.counts["unknown"] == 1
    assert d.feed(LogRecord(1.0, "nmea", "not bytes")) == [] and d.nmea.counts["garbage"] == 1
    line = encode_hdt(12.5)
    assert d.feed(LogRecord(2.0, "nmea", bytearray(line))) == d.feed(LogRecord(2.0, "nmea", line))


# --- NMEA --------------------------------------------------------------------------------------


def _loop_xor(body: bytes) -> int:
    c = 0
    for b in body:
        c ^= b
    return c


def test_fold_checksum_equals_byte_loop_for_every_length():
    rng = random.Random(5)
    for n in range(0, 200):
        for _ in range(40):
            body = rng.randbytes(n)
            assert _fast_checksum(body) == _loop_xor(body), n


_REF_ADDRESS = re.compile(r"^(?:[A-Z][A-Z0-9][A-Z]{3}|P[A-Z0-9]{1,8})$")


def _reference_parse(line: bytes):
    """The textbook parse: (talker, type, fields) or the reject reason."""
    body = line.rstrip(b"\r\n")
    if len(body) + 2 > 82:
        return "too_long"
    if not body.startswith(b"$"):
        return "garbage"
    star = body.rfind(b"*")
    if star < 0 or len(body) - star != 3:
        return "bad_checksum"
    try:
        text = body[1:star].decode("ascii")
    except UnicodeDecodeError:
        return "garbage"
    try:
        want = int(body[star + 1:], 16)
    except ValueError:
        return "bad_checksum"
    if _loop_xor(body[1:star]) != want:
        return "bad_checksum"
    address, *fields = text.split(",")
    if not _REF_ADDRESS.match(address):
        return "garbage"
    if address.startswith("P"):
        return "P", address[1:], tuple(fields)
    return address[:2], address[2:], tuple(fields)


def _ours(line):
    try:
        got = split_sentence(line)
    except NmeaReject as exc:
        return exc.reason
    s = parse_sentence(line)
    assert (s.talker, s.type, s.fields) == got
    return got


_GOOD = [encode_gga(1.7e9, 44.1, -9.8, height_m=-30.0), encode_rmc(1.7e9, -12.5, 170.25, speed_m_s=2.0),
         encode_hdt(359.99), encode_ths(1.5), encode_vtg(12.0, 2.0), encode_zda(1.7e9), encode_dpt(14.0),
         b"$PSXN,23,1.2,3.4*00\r\n", b"$GPGGA,,,,,,0,,,,,,,,*66"]


@settings(max_examples=400, deadline=None)
@given(base=st.sampled_from(_GOOD), cut=st.integers(0, 90), junk=st.binary(max_size=6),
       fix_checksum=st.booleans(), lower=st.booleans())
def test_split_sentence_equals_reference(base, cut, junk, fix_checksum, lower):
    line = base[:cut] + junk + base[cut:]
    assert _ours(line) == _reference_parse(line)
    if fix_checksum:  # valid framing around the mutated body: reaches the field split
        body = line.rstrip(b"\r\n")
        star = body.rfind(b"*")
        inner = body[1:star] if body.startswith(b"$") and star > 0 else body
        fixed = b"$" + inner + (b"*%02x" if lower else b"*%02X") % _loop_xor(inner) + b"\r\n"
        assert _ours(fixed) == _reference_parse(fixed)


def test_checksum_digits_in_odd_forms_follow_int():
    """'0F', '0f', ' F' and '+F' are all what int(.., 16) reads as 15: accepted as before."""
    body = next(b for b in (b"HEHDT,%d,T" % d + b"," * k for d in range(1000) for k in range(4))
                if _loop_xor(b) < 16)
    c = _loop_xor(body)
    for digits in (b"%02X" % c, b"%02x" % c, b" %X" % c, b"+%x" % c):
        line = b"$" + body + b"*" + digits
        assert split_sentence(line) == ("HE", "HDT", tuple(body.decode().split(",")[1:])) == _reference_parse(line)[:3]
    with pytest.raises(NmeaReject) as exc:
        split_sentence(b"$" + body + b"*G1")
    assert exc.value.reason == "bad_checksum" and "'G1'" in str(exc.value)


def test_decoder_on_bytearray_lines_as_on_bytes():
    a, b = NmeaDecoder(), NmeaDecoder()
    for line in _GOOD + [b"$GPGGA*00", b"\xff$GPHDT", b"$GPGGA,1*7"]:
        assert repr(a.feed(line, 1.7e9)) == repr(b.feed(bytearray(line), 1.7e9))
    assert a.counts == b.counts


# --- NavFix ------------------------------------------------------------------------------------

_opt = st.none() | st.floats(allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(t=st.floats(allow_nan=False), lat=_opt, lon=_opt, hdg=_opt, alt=_opt, depth=_opt, speed=_opt,
       source=st.sampled_from(["", "nmea:GGA", "can:ATR_NavPosition"]))
def test_make_fix_is_a_navfix_in_every_respect(t, lat, lon, hdg, alt, depth, speed, source):
    ref = NavFix(t=t, lat_deg=lat, lon_deg=lon, heading_deg=hdg, altitude_m=alt, depth_m=depth,
                 speed_m_s=speed, source=source)
    fix = make_fix(t, lat, lon, hdg, alt, depth, speed, source)
    assert type(fix) is NavFix and fix == ref and hash(fix) == hash(ref) and repr(fix) == repr(ref)
    assert dataclasses.asdict(fix) == dataclasses.asdict(ref)
    assert pickle.loads(pickle.dumps(fix)) == ref
    with pytest.raises(dataclasses.FrozenInstanceError):
        fix.t = 0.0  # type: ignore[misc]


# --- the benchmark tool ------------------------------------------------------------------------


def test_bench_ingest_quick_smoke(capsys):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "tools" / "bench" / "ingest.py"
    spec = importlib.util.spec_from_file_location("bench_ingest", path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.main(["nav", "--quick", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    names = [row[0] for row in tool.ROWS]
    assert names == ["atrlog read (nav)", "atrlog read (all)", "nmea decode", "can decode", "nav decode",
                     "read + nav decode", "navtrack add", "pipeline feed (nav)"]
    assert all(n > 0 and cpu > 0 for _, n, cpu in tool.ROWS) and "records/s" in out
