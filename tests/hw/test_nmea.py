"""NMEA 0183 codec: encoder against independent references, decoder rules, never-raising input."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from functools import reduce

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw.errors import NmeaError
from hw.nmea import (KNOT_M_S, NmeaReject, encode_dpt, encode_gga, encode_hdt, encode_rmc,
                     encode_ths, encode_vtg, encode_zda, format_sentence, parse_sentence)
from hw.nmea_decoder import NmeaDecoder

T0 = datetime(2014, 8, 1, tzinfo=timezone.utc).timestamp()


def ref_checksum(line: bytes) -> int:
    """Independent checksum: XOR of the characters between '$' and '*'."""
    body = line[1:line.index(b"*")]
    return reduce(lambda a, b: a ^ b, body, 0)


def test_encoder_reproduces_real_sentence_exactly():
    # $GPZDA,000000.70,01,08,2014,,*6F recorded on R/V Palmer (NBP1406 seap log)
    assert encode_zda(T0 + 0.70) == b"$GPZDA,000000.70,01,08,2014,,*6F\r\n"
    assert encode_hdt(218.53) == b"$HEHDT,218.53,T*12\r\n"


@pytest.mark.parametrize("line", [encode_gga(T0 + 12.34, -22.5, 170.25, height_m=-7.5), encode_rmc(T0, 1, -2),
                                  encode_hdt(359.996), encode_ths(1.0), encode_vtg(10, 2), encode_dpt(3.75),
                                  format_sentence("PSXN", ["20", "1"])])
def test_checksum_and_framing_match_reference(line):
    assert line.startswith(b"$") and line.endswith(b"\r\n") and len(line) <= 82
    star = line.index(b"*")
    assert int(line[star + 1:star + 3], 16) == ref_checksum(line)


def test_encoder_rounds_without_carry_errors():
    # 59.995 s rounds to the next minute, 59.9999999' to the next degree: no "60.00" fields
    assert b",000100.00," in encode_gga(T0 + 59.999, 0.0, 0.0)
    assert b",1000.000000,N," in encode_gga(T0, 9.99999999999, 0.0)
    assert encode_hdt(359.996).startswith(b"$HEHDT,0.00,T")
    assert b",010814," in encode_rmc(T0 + 0.001, 0, 0) and b",020814," in encode_rmc(T0 + 86399.999, 0, 0)


@pytest.mark.parametrize("address, fields", [("GPGG", []), ("gpgga", []), ("GPGGA", ["a*b"]), ("GPGGA", ["x,y"]),
                                             ("GPGGA", ["é"]), ("GPGGA", ["9" * 80])])
def test_encoder_refuses_what_is_not_a_sentence(address, fields):
    with pytest.raises(NmeaError):
        format_sentence(address, fields)


def test_encoder_refuses_non_finite_and_out_of_range():
    for call in (lambda: encode_gga(math.nan, 0, 0), lambda: encode_gga(T0, 91, 0), lambda: encode_gga(T0, 0, 181),
                 lambda: encode_hdt(math.inf), lambda: encode_dpt(-1.0)):
        with pytest.raises(NmeaError):
            call()


@settings(max_examples=200, deadline=None)
@given(t=st.floats(1e9, 2e9), lat=st.floats(-89.9, 89.9), lon=st.floats(-179.9, 179.9),
       hdg=st.floats(0, 359.99), alt=st.floats(0, 600), sog=st.floats(0, 20))
def test_round_trip_si_values(t, lat, lon, hdg, alt, sog):
    d = NmeaDecoder()
    assert d.feed(encode_zda(t), t) == []
    (gga,) = d.feed(encode_gga(t, lat, lon), t)
    (rmc,) = d.feed(encode_rmc(t, lat, lon, speed_m_s=sog), t)
    (hdt,) = d.feed(encode_hdt(hdg), t + 0.1)
    (dpt,) = d.feed(encode_dpt(alt), t + 0.2)
    # time to 0.005 s (hundredths), angles to 5e-7 arcmin, heading 0.005 deg, altitude 0.005 m
    for fix in (gga, rmc):
        assert abs(fix.t - t) <= 0.005 + 1e-6
        assert abs(fix.lat_deg - lat) <= 1e-8 + 1e-12 and abs(fix.lon_deg - lon) <= 1e-8 + 1e-12
    assert abs(rmc.speed_m_s - sog) <= 0.005 * KNOT_M_S + 1e-9
    assert abs(((hdt.heading_deg - hdg + 180) % 360) - 180) <= 0.005 + 1e-9
    assert abs(dpt.altitude_m - alt) <= 0.005 + 1e-9
    # untimed sentences take the sentence clock: arrival + (sentence time - arrival time)
    assert abs(hdt.t - (rmc.t + 0.1)) < 1e-6 and abs(dpt.t - (rmc.t + 0.2)) < 1e-6
    assert d.counts["accepted"] == 5 and d.rejected == 0


def test_any_talker_id_and_lower_case_checksum():
    d = NmeaDecoder()
    line = format_sentence("INHDT", ["12.5", "T"]).rstrip()
    lower = line[:-2] + line[-2:].lower()
    assert d.feed(lower, 0.0)[0].heading_deg == 12.5
    for talker in ("GP", "GN", "IN", "HE", "II", "SD", "YX"):
        assert d.feed(format_sentence(talker + "HDT", ["1.0", "T"]), 0.0)[0].source == "nmea:HDT"


def test_decoder_counts_and_drops_each_kind_of_bad_line():
    d = NmeaDecoder()
    good = encode_hdt(10.0)
    bad = {
        "too_long": b"$GPGGA," + b"1" * 80 + b"*00",
        "bad_checksum": good.replace(b"*", b"*F"),
        "garbage": b"\x00\xff$$",
        "unsupported": format_sentence("GPGSV", ["1", "1", "08"]),
        "bad_field": format_sentence("GPHDT", ["north", "T"]),
        "invalid": format_sentence("GPGGA", ["120000.00", "", "", "", "", "0", "00", "", "", "M", "", "M", "", ""]),
    }
    for reason, line in bad.items():
        assert d.feed(line, 0.0) == []
        assert d.counts[reason] == 1, (reason, d.last_reject)
    assert d.feed(good, 0.0)[0].heading_deg == 10.0  # nothing lost by what came before
    assert d.counts["accepted"] == 1 and d.rejected == len(bad)


def test_checksum_flip_is_detected():
    line = bytearray(encode_gga(T0, 45.0, 9.0).rstrip())
    line[20] ^= 0x01
    with pytest.raises(NmeaReject) as exc:
        parse_sentence(bytes(line))
    assert exc.value.reason == "bad_checksum"


def test_gga_crossing_midnight_keeps_increasing():
    d = NmeaDecoder()
    d.feed(encode_zda(T0 - 0.5), T0 - 0.5)  # 23:59:59.50 on 31 July
    (a,) = d.feed(encode_gga(T0 - 0.2, 1, 1), T0 - 0.2)
    (b,) = d.feed(encode_gga(T0 + 0.3, 1, 1), T0 + 0.3)  # 00:00:00.30, before the next ZDA
    assert a.t == pytest.approx(T0 - 0.2, abs=1e-6) and b.t == pytest.approx(T0 + 0.3, abs=1e-6)


def test_no_date_policy():
    strict = NmeaDecoder(date_from_arrival=False)
    assert strict.feed(encode_gga(T0 + 5, 1, 1), T0 + 5) == [] and strict.counts["no_date"] == 1
    lenient = NmeaDecoder()
    (fix,) = lenient.feed(encode_gga(T0 + 5, 1, 1), T0 + 5.3)
    assert fix.t == pytest.approx(T0 + 5, abs=1e-6)  # arrival date, sentence time of day


def test_rmc_void_still_sets_date_but_gives_no_fix():
    d = NmeaDecoder(date_from_arrival=False)
    void = encode_rmc(T0 + 60, 1, 1).replace(b",A,", b",V,", 1)
    void = format_sentence("GPRMC", void[7:void.index(b"*")].decode().split(","))
    assert d.feed(void, 0.0) == [] and d.counts["invalid"] == 1
    (fix,) = d.feed(encode_gga(T0 + 61, 1, 1), 0.0)
    assert fix.t == pytest.approx(T0 + 61, abs=1e-6)


def test_vtg_and_ths_modes():
    d = NmeaDecoder()
    (v,) = d.feed(encode_vtg(90.0, 3.0), 0.0)
    assert v.speed_m_s == pytest.approx(3.0, abs=0.005 * KNOT_M_S)
    assert d.feed(encode_ths(5.0, mode="V"), 0.0) == [] and d.counts["invalid"] == 1
    (h,) = d.feed(encode_ths(5.0, mode="E"), 0.0)
    assert h.heading_deg == 5.0


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=120))
def test_decoder_never_raises_on_arbitrary_bytes(data):
    d = NmeaDecoder()
    fixes = d.feed(data, 1e9)
    assert d.counts["accepted"] + d.rejected == 1
    assert all(math.isfinite(f.t) for f in fixes)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.text(alphabet="0123456789.,-ANSEWTVM", max_size=12), max_size=16),
       st.sampled_from(["GGA", "RMC", "HDT", "THS", "VTG", "ZDA", "DPT"]))
def test_decoder_never_raises_on_valid_checksum_with_random_fields(fields, kind):
    try:
        line = format_sentence("GP" + kind, fields)
    except NmeaError:
        return  # too long to be a sentence
    d = NmeaDecoder()
    d.feed(line, 1e9)
    assert d.counts["accepted"] + d.rejected == 1


def test_extremes_poles_antimeridian_leap_second():
    d = NmeaDecoder()
    d.feed(encode_zda(T0), T0)
    for lat, lon in ((90.0, 180.0), (-90.0, -180.0), (0.0, 179.99999999), (-0.0, -0.000000001)):
        (fix,) = d.feed(encode_gga(T0 + 1, lat, lon), T0 + 1)
        assert fix.lat_deg == pytest.approx(lat, abs=1e-8) and fix.lon_deg == pytest.approx(lon, abs=1e-8)
    leap = format_sentence("GPGGA", ["235960.50", "4400.0", "N", "00900.0", "E", "1", "08", "1.0", "0.0", "M",
                                     "", "M", "", ""])
    d = NmeaDecoder()
    d.feed(encode_zda(T0 - 1.0), T0 - 1.0)  # 23:59:59.00 on 31 July
    (fix,) = d.feed(leap, T0)  # 23:59:60.5, a leap second: POSIX time has no such second, 0.5 s after midnight
    assert fix.t == pytest.approx(T0 + 0.5)


def test_real_gga_through_nav_track_matches_direct_parse(real_data):
    """Real Seapath GGA -> decoder -> NavTrack, interpolated at the GGA times, against a direct parse."""
    from atr_node.records.nav import NavTrack
    from hw.replay import StampedNmeaLink

    d = NmeaDecoder()
    track = NavTrack(max_gap_s=2.0, default_altitude_m=10.0)  # a ship: no altitude source
    ref = []
    with StampedNmeaLink(real_data / "nmea" / "NBP1406_seap-2014-08-01") as src:
        for rec in src:
            for fix in d.feed(rec.msg, rec.t):
                track.add(fix)
            f = rec.msg.decode().split(",")
            if f[0].endswith("GGA"):  # reference: ddmm.mmmmmm by hand, float64
                lat = (int(f[2][:2]) + float(f[2][2:]) / 60) * (-1 if f[3] == "S" else 1)
                lon = (int(f[4][:3]) + float(f[4][3:]) / 60) * (-1 if f[5] == "W" else 1)
                hh, mm, ss = int(f[1][:2]), int(f[1][2:4]), float(f[1][4:])
                ref.append((T0 + hh * 3600 + mm * 60 + ss, lat, lon))
    t, lat, lon = map(np.array, zip(*ref))
    assert len(t) == 715 and d.counts["bad_checksum"] == 0
    sample = track.interpolate(t)
    assert sample.valid.all()
    assert np.abs(sample.nav.lat_deg - lat).max() < 1e-9 and np.abs(sample.nav.lon_deg - lon).max() < 1e-9
