"""Contact exports: GeoJSON against the RFC 7946 structure, KML 2.2 well-formed with its
placemarks, CSV round trip; reading --contacts-out files; exports from a real node."""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from datetime import datetime, timezone

import pytest
from hypothesis import given, settings as hsettings, strategies as st

from atr_node.errors import AtrError
from atr_node.node import wire
from atr_node.operators.book import ContactBook, read_contacts
from atr_node.operators.export import format_of, to_csv, to_geojson, to_kml, write_export

from .conftest import StreamLines, stop_client, wait_until

KML = "{http://www.opengis.net/kml/2.2}"
GEOJSON_TYPES = {"Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon",
                 "GeometryCollection", "Feature", "FeatureCollection"}


def contact(id=1, *, state="update", lat=44.08, lon=9.85, bel=0.9, pl=None, t=1.7e9, detectors=("mf", "smf"),
            legs=(0, 2), sigma=1.5):
    pl = max(bel, 0.99) if pl is None else pl
    return wire.contact_message(id=id, state=state, t=t, lat_deg=lat, lon_deg=lon, east_m=568000.0 + id,
                                north_m=4881000.0 - id, sigma_m=sigma, bel=bel, pl=pl, m_theta=pl - bel, looks=2,
                                detections=3, detectors=list(detectors), legs=list(legs))


def rfc7946_problems(doc) -> list[str]:
    """Structural checks of RFC 7946 for a FeatureCollection of Point features (sections 1.4,
    3.1.1, 3.1.2, 3.2, 3.3, 4, 5), written from the RFC, independent of the exporter."""
    p = []
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        return ["top level must be an object of type FeatureCollection"]
    if "crs" in doc:
        p.append("'crs' member is not allowed (section 4)")
    if not isinstance(doc.get("features"), list):
        return p + ["'features' must be an array (3.3)"]
    for i, f in enumerate(doc["features"]):
        if not isinstance(f, dict) or f.get("type") != "Feature":
            p.append(f"feature {i}: type must be Feature (3.2)")
            continue
        if "geometry" not in f or "properties" not in f:
            p.append(f"feature {i}: needs 'geometry' and 'properties' members (3.2)")
        if "id" in f and not isinstance(f["id"], (str, int, float)):
            p.append(f"feature {i}: id must be a string or number (3.2)")
        if not (f.get("properties") is None or isinstance(f.get("properties"), dict)):
            p.append(f"feature {i}: properties must be an object or null (3.2)")
        g = f.get("geometry")
        if g is not None:
            if not isinstance(g, dict) or g.get("type") not in GEOJSON_TYPES - {"Feature", "FeatureCollection"}:
                p.append(f"feature {i}: geometry type invalid (3.1)")
            elif g["type"] == "Point":
                c = g.get("coordinates")
                if not (isinstance(c, list) and len(c) in (2, 3) and all(isinstance(v, (int, float)) for v in c)):
                    p.append(f"feature {i}: a Point's coordinates are one position of 2-3 numbers (3.1.1, 3.1.2)")
                elif not (-180 <= c[0] <= 180 and -90 <= c[1] <= 90):
                    p.append(f"feature {i}: position must be [longitude, latitude] in WGS84 (4)")
    if "bbox" in doc:
        b = doc["bbox"]
        if not (isinstance(b, list) and len(b) == 4 and b[1] <= b[3]):
            p.append("bbox must be [west, south, east, north] (5)")
        else:
            for f in doc["features"]:
                lon, lat = f["geometry"]["coordinates"][:2]
                if not (b[0] <= lon <= b[2] and b[1] <= lat <= b[3]):
                    p.append("bbox does not contain every position (5)")
    return p


CONTACTS = [contact(1, bel=0.6, lat=-33.9, lon=-70.5), contact(2, bel=0.999999, detectors=("z",), legs=(5,)),
            contact(3, state="withdrawn", bel=0.3, pl=0.8), contact(4, state="new", bel=0.95, detectors=(), legs=())]


def test_geojson_is_rfc7946_and_carries_every_icd_field():
    doc = json.loads(json.dumps(to_geojson(CONTACTS), allow_nan=False))
    assert rfc7946_problems(doc) == []
    assert [f["id"] for f in doc["features"]] == [2, 4, 1, 3]  # by belief
    for f in doc["features"]:
        src = next(c for c in CONTACTS if c["id"] == f["id"])
        assert f["geometry"]["coordinates"] == [src["lon_deg"], src["lat_deg"]]  # longitude first
        props = dict(f["properties"])
        assert props.pop("time_utc") == datetime.fromtimestamp(src["t"], tz=timezone.utc).strftime(
            "%Y-%m-%dT%H:%M:%S.000Z")
        assert props == src
    assert doc["bbox"] == [-70.5, -33.9, 9.85, 44.08]


def test_the_validator_catches_what_it_should():
    bad = to_geojson(CONTACTS)
    bad["features"][0]["geometry"]["coordinates"] = [44.08, 190.0]
    bad["crs"] = {"type": "name"}
    assert [p.split(":")[0].split(" ")[0] for p in rfc7946_problems(bad)] == ["'crs'", "feature", "bbox"]


def test_kml_is_well_formed_and_carries_the_placemarks():
    root = ET.fromstring(to_kml(CONTACTS).encode("utf-8"))
    assert root.tag == f"{KML}kml"
    doc = root.find(f"{KML}Document")
    styles = {s.get("id") for s in doc.findall(f"{KML}Style")}
    pms = doc.findall(f"{KML}Placemark")
    assert len(pms) == len(CONTACTS)
    order = ["name", "description", "TimeStamp", "styleUrl", "ExtendedData", "Point"]  # KML 2.2 schema order
    for pm in pms:
        assert [child.tag.replace(KML, "") for child in pm] == order
        cid = int(pm.find(f"{KML}name").text.split()[-1])
        src = next(c for c in CONTACTS if c["id"] == cid)
        lon, lat, alt = map(float, pm.find(f"{KML}Point/{KML}coordinates").text.split(","))
        assert (lon, lat, alt) == (src["lon_deg"], src["lat_deg"], 0.0)
        assert pm.find(f"{KML}styleUrl").text.lstrip("#") in styles
        data = {d.get("name"): d.find(f"{KML}value").text or "" for d in pm.iter(f"{KML}Data")}
        for k, v in src.items():
            if isinstance(v, list):
                assert data[k] == ";".join(map(str, v))
            elif isinstance(v, float):
                assert float(data[k]) == v
            else:
                assert data[k] == str(v)
    withdrawn = [pm for pm in pms if pm.find(f"{KML}name").text == "ATR 3"][0]
    assert withdrawn.find(f"{KML}styleUrl").text == "#withdrawn"


def test_csv_round_trip():
    rows = list(csv.DictReader(io.StringIO(to_csv(CONTACTS))))
    assert [int(r["id"]) for r in rows] == [2, 4, 1, 3]
    for r in rows:
        src = next(c for c in CONTACTS if c["id"] == int(r["id"]))
        assert float(r["lat_deg"]) == src["lat_deg"] and float(r["bel"]) == src["bel"]
        assert (r["detectors"].split(";") if r["detectors"] else []) == src["detectors"]
        assert [int(x) for x in r["legs"].split(";") if x] == src["legs"]




@hsettings(max_examples=60, deadline=None)
@given(lat=st.floats(-90, 90), lon=st.floats(-180, 180), bel=st.floats(0, 1), t=st.floats(0, 4e9),
       cid=st.integers(0, 2**40), legs=st.lists(st.integers(0, 10**6), max_size=4))
def test_every_format_keeps_every_value_exactly(lat, lon, bel, t, cid, legs):
    c = contact(cid, lat=lat, lon=lon, bel=bel, pl=1.0, t=t, legs=legs)
    f = json.loads(json.dumps(to_geojson([c])))["features"][0]
    assert {k: v for k, v in f["properties"].items() if k != "time_utc"} == c
    row = next(csv.DictReader(io.StringIO(to_csv([c]))))
    assert (float(row["lat_deg"]), float(row["lon_deg"]), float(row["bel"]), float(row["t"])) == (lat, lon, bel, t)
    pm = ET.fromstring(to_kml([c])).find(f"{KML}Document/{KML}Placemark")
    assert list(map(float, pm.find(f"{KML}Point/{KML}coordinates").text.split(",")))[:2] == [lon, lat]


def test_write_export_by_suffix_and_errors(tmp_path):
    for name in ("a.geojson", "a.json", "a.kml", "a.csv"):
        write_export(tmp_path / name, CONTACTS)
    assert rfc7946_problems(json.loads((tmp_path / "a.json").read_text())) == []
    ET.parse(tmp_path / "a.kml")
    with pytest.raises(AtrError, match=r"a\.txt.*\.geojson"):
        format_of(tmp_path / "a.txt")
    with pytest.raises(AtrError, match="cannot write"):
        write_export(tmp_path / "missing" / "a.csv", CONTACTS)
    assert not list(tmp_path.glob(".*tmp*"))  # atomic writes leave no temporary file


def test_read_contacts_names_the_bad_line_and_changes_nothing(tmp_path):
    good = tmp_path / "c.jsonl"
    good.write_text("\n".join(json.dumps(c) for c in CONTACTS) + "\n\n")
    book = read_contacts(good)
    assert len(book) == 4 and book.n_withdrawn == 1
    assert [c["id"] for c in book.contacts()] == [2, 4, 1]
    bad = tmp_path / "bad.jsonl"
    broken = dict(CONTACTS[0], bel=1.5)
    bad.write_text(json.dumps(CONTACTS[1]) + "\n" + json.dumps(broken) + "\n")
    with pytest.raises(AtrError, match=r"bad\.jsonl, line 2: .*bel"):
        read_contacts(bad, book)
    (tmp_path / "nojson.jsonl").write_text(json.dumps(CONTACTS[1]) + "\n{oops\n")
    with pytest.raises(AtrError, match=r"line 2: not JSON"):
        read_contacts(tmp_path / "nojson.jsonl", book)
    assert book.contacts(include_withdrawn=True) == read_contacts(good).contacts(include_withdrawn=True)


def test_book_keeps_the_latest_state_and_flags_withdrawn():
    book = ContactBook()
    assert book.apply(contact(7, state="new", bel=0.6))
    assert book.apply(contact(7, state="update", bel=0.8))
    assert book.contacts()[0]["bel"] == 0.8
    assert book.apply(contact(7, state="withdrawn", bel=0.2))
    assert book.contacts() == [] and book.contacts(include_withdrawn=True)[0]["state"] == "withdrawn"
    assert not book.apply({"type": "contact", "v": 1})
    assert book.rejected == 1 and len(book) == 1


def _run(cmd, **kw):
    return subprocess.run([sys.executable, "-m", "atr_node", *cmd], capture_output=True, text=True, timeout=120, **kw)


def test_export_from_replay_contacts_out(mission, tmp_path):
    _, cfg, files = mission
    out = tmp_path / "c.jsonl"
    r = _run(["replay", str(files.atrlog), "--config", str(cfg), "--online-calibration", "off", "--publish", "none",
              "--contacts-out", str(out), "--quiet", "--workers", "0"])
    assert r.returncode == 0, r.stderr
    final = [json.loads(x) for x in out.read_text().splitlines()]
    r = _run(["export", "--contacts", str(out), "-o", str(tmp_path / "c.geojson"), "-o", str(tmp_path / "c.kml"),
              "-o", str(tmp_path / "c.csv"), "--include-withdrawn"])
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "c.geojson").read_text())
    assert rfc7946_problems(doc) == [] and final
    got = {f["id"]: {k: v for k, v in f["properties"].items() if k != "time_utc"} for f in doc["features"]}
    assert got == {c["id"]: c for c in final}
    assert len(ET.parse(tmp_path / "c.kml").getroot().findall(f"{KML}Document/{KML}Placemark")) == len(final)
    assert len(list(csv.DictReader(open(tmp_path / "c.csv")))) == len(final)
    r = _run(["export", "--contacts", str(tmp_path / "c.csv"), "-o", str(tmp_path / "x.kml")])
    assert r.returncode == 1 and "line 1: not JSON" in r.stderr


def test_export_from_a_live_node(live_node, tmp_path):
    node = live_node()
    outs = [tmp_path / "live.geojson", tmp_path / "live.kml", tmp_path / "live.csv"]
    # stopped at an event (the file holds every contact the node published), not after seconds
    # of silence: a loaded machine can keep the node quiet that long
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "export", "--from", node.endpoint,
                             "--until-silent", "0", "--refresh", "0.2", "--include-withdrawn",
                             *sum((["-o", str(p)] for p in outs), [])], stderr=subprocess.PIPE, text=True)
    stderr = StreamLines(proc.stderr)

    def written() -> dict:
        try:
            return {f["id"]: {k: v for k, v in f["properties"].items() if k != "time_utc"}
                    for f in json.loads(outs[0].read_text())["features"]}
        except (OSError, ValueError):
            return {}

    try:
        stderr.wait_for(lambda t: "node up" in t)  # printed once the subscription is known to be up
        node.release()
        node.join()
        final = {}
        for m in node.emitted:  # the node's own record of what it published: latest per id
            final[m["id"]] = m
        wait_until(lambda: written() == final, poll_s=0.1)
        returncode = stop_client(proc)  # the files are written once more at the stop
    finally:
        if proc.poll() is None:
            proc.kill()
    err = stderr.close()
    assert returncode == 0, err
    assert final, "the small mission should give contacts"
    doc = json.loads(outs[0].read_text())
    assert rfc7946_problems(doc) == []
    got = {f["id"]: {k: v for k, v in f["properties"].items() if k != "time_utc"} for f in doc["features"]}
    assert got == final
    pms = ET.parse(outs[1]).getroot().findall(f"{KML}Document/{KML}Placemark")
    assert sorted(int(pm.find(f"{KML}name").text.split()[-1]) for pm in pms) == sorted(final)
    rows = list(csv.DictReader(open(outs[2])))
    assert {int(r["id"]): float(r["bel"]) for r in rows} == {k: v["bel"] for k, v in final.items()}


def test_empty_contact_list_gives_valid_empty_files(tmp_path):
    doc = to_geojson([])
    assert rfc7946_problems(doc) == [] and doc["features"] == [] and "bbox" not in doc
    assert ET.fromstring(to_kml([])).findall(f"{KML}Document/{KML}Placemark") == []
    assert to_csv([]).strip().split(",")[:3] == ["type", "v", "id"] and to_csv([]).count("\n") == 1


def test_export_from_a_silent_endpoint_says_so(tmp_path):
    r = _run(["export", "--from", "tcp://127.0.0.1:1", "-o", str(tmp_path / "x.csv"), "--until-silent", "0.5"])
    assert r.returncode == 1 and "nothing received from tcp://127.0.0.1:1" in r.stderr
    assert not (tmp_path / "x.csv").exists()  # no file rather than an empty one that looks like "no contacts"
    r = _run(["export", "--contacts", str(tmp_path / "none.jsonl"), "-o", str(tmp_path / "x.txt")])
    assert r.returncode == 1 and "x.txt" in r.stderr and ".geojson" in r.stderr
