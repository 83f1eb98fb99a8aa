"""Contact exports for the tools the people around the vehicle already use.

Three formats, each carrying every ICD section 3 contact field:

- **GeoJSON** (RFC 7946): a ``FeatureCollection`` of ``Point`` features, coordinates
  ``[lon_deg, lat_deg]`` (WGS84, longitude first, no ``crs`` member: RFC 7946 section 4),
  the feature ``id`` = contact id, ``properties`` = the ICD fields plus ``time_utc``;
  a ``bbox`` [west, south, east, north] when there is at least one contact. Opens in QGIS,
  geojson.io, ArcGIS, Leaflet.
- **KML 2.2** (OGC 07-147r2): a ``Document`` with one ``Placemark`` per contact (name
  ``ATR <id>``, description, ``TimeStamp``, a style by belief class, every ICD field in
  ``ExtendedData``, ``Point`` ``lon,lat,0``), elements in the schema's order. Opens in
  Google Earth and the usual mission planners (SeeTrack, QGIS, OpenCPN via GPX/KML import).
- **CSV** (RFC 4180): a header of the ICD fields in ICD order, the optional extent
  (``length_m``, ``width_m``, ``heading_deg``: empty for a contact without one), the v1.1 ``seq``
  (empty from a v1 node) and ``time_utc``; list fields
  (``detectors``, ``legs``) joined with ``;``. Carries ``lat_deg`` and ``lon_deg``, so the
  evaluation tools read it like a truth file (ICD section 5).

Rows are ordered by decreasing belief, then id. Files are written atomically (temporary file,
then ``os.replace``), so a viewer re-reading a refreshed file never sees half of it.
"""

from __future__ import annotations

import csv
import io
import json
import os
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from ..errors import AtrError
from ..node.wire import CONTACT_OPTIONAL_FIELDS, CONTACT_SEQ_FIELDS
from .book import ICD_FIELDS

FORMATS = ("geojson", "kml", "csv")
SUFFIXES = {".geojson": "geojson", ".json": "geojson", ".kml": "kml", ".csv": "csv"}
KML_NS = "http://www.opengis.net/kml/2.2"

# Belief classes for the KML styles (aabbggrr colours): strong, probable, weak, withdrawn.
_KML_STYLES = (("bel-high", 0.9, "ff0000ff", 1.2), ("bel-mid", 0.7, "ff0080ff", 1.0),
               ("bel-low", 0.0, "ff00ffff", 0.8))
_KML_WITHDRAWN = ("withdrawn", "ff808080", 0.7)
_KML_ICON = "http://maps.google.com/mapfiles/kml/shapes/target.png"


def time_utc(t: float) -> str:
    """ISO 8601 UTC time with milliseconds and a ``Z`` (KML ``when``, CSV ``time_utc``)."""
    ms = round(t * 1000.0)
    base = datetime.fromtimestamp(ms // 1000, tz=timezone.utc)
    return base.strftime("%Y-%m-%dT%H:%M:%S") + f".{ms % 1000:03d}Z"


def _ordered(contacts: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return sorted(contacts, key=lambda c: (-c["bel"], c["id"]))


EXTENT_FIELDS: tuple[str, ...] = tuple(CONTACT_OPTIONAL_FIELDS)
"""(ICD v1.1) An extended object's ``length_m``, ``width_m``, ``heading_deg``: in GeoJSON and
KML when the contact has them; CSV columns always (empty when it has none)."""
SEQ_FIELDS: tuple[str, ...] = tuple(CONTACT_SEQ_FIELDS)
"""(ICD v1.1) The ``seq`` of the contact's last message, handled like the extent (absent from
a v1 node's contacts)."""


def _properties(c: Mapping[str, Any]) -> dict[str, Any]:
    props = {k: c[k] for k in ICD_FIELDS}
    props.update({k: c[k] for k in (*EXTENT_FIELDS, *SEQ_FIELDS) if c.get(k) is not None})
    props["detectors"] = list(props["detectors"])
    props["legs"] = list(props["legs"])
    props["time_utc"] = time_utc(c["t"])
    return props


# ------------------------------------------------------------------------------- GeoJSON
def to_geojson(contacts: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """RFC 7946 ``FeatureCollection`` of the contacts (a dict ready for ``json.dump``)."""
    rows = _ordered(contacts)
    features = [{"type": "Feature", "id": int(c["id"]),
                 "geometry": {"type": "Point", "coordinates": [float(c["lon_deg"]), float(c["lat_deg"])]},
                 "properties": _properties(c)} for c in rows]
    fc: dict[str, Any] = {"type": "FeatureCollection", "features": features}
    if rows:
        lons = [c["lon_deg"] for c in rows]
        lats = [c["lat_deg"] for c in rows]
        fc["bbox"] = [min(lons), min(lats), max(lons), max(lats)]
    return fc


# ------------------------------------------------------------------------------- KML
def _style_id(c: Mapping[str, Any]) -> str:
    if c["state"] == "withdrawn":
        return _KML_WITHDRAWN[0]
    return next(name for name, lo, _, _ in _KML_STYLES if c["bel"] >= lo)


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    e = ET.SubElement(parent, f"{{{KML_NS}}}{tag}", attrib)
    if text is not None:
        e.text = text
    return e


def to_kml(contacts: Iterable[Mapping[str, Any]], *, name: str = "atr-node contacts") -> str:
    """KML 2.2 document of the contacts (UTF-8 text with its XML declaration)."""
    ET.register_namespace("", KML_NS)
    root = ET.Element(f"{{{KML_NS}}}kml")
    doc = _sub(root, "Document")
    _sub(doc, "name", name)
    for sid, _, colour, scale in (*_KML_STYLES, (_KML_WITHDRAWN[0], 0.0, *_KML_WITHDRAWN[1:])):
        style = _sub(doc, "Style", id=sid)
        icon_style = _sub(style, "IconStyle")
        _sub(icon_style, "color", colour)
        _sub(icon_style, "scale", f"{scale:g}")
        _sub(_sub(icon_style, "Icon"), "href", _KML_ICON)
    for c in _ordered(contacts):
        pm = _sub(doc, "Placemark", id=f"contact-{int(c['id'])}")
        _sub(pm, "name", f"ATR {int(c['id'])}")
        _sub(pm, "description",
             f"{c['state']}: Bel(T) {c['bel']:.4f}, Pl(T) {c['pl']:.4f}, sigma {c['sigma_m']:.1f} m, "
             f"{c['looks']} looks, {c['detections']} detections by {', '.join(c['detectors']) or '-'} "
             f"on legs {', '.join(map(str, c['legs'])) or '-'}")
        _sub(_sub(pm, "TimeStamp"), "when", time_utc(c["t"]))
        _sub(pm, "styleUrl", f"#{_style_id(c)}")
        ext = _sub(pm, "ExtendedData")
        for k, v in _properties(c).items():
            text = ";".join(map(str, v)) if isinstance(v, list) else (repr(v) if isinstance(v, float) else str(v))
            _sub(_sub(ext, "Data", name=k), "value", text)
        _sub(_sub(pm, "Point"), "coordinates", f"{c['lon_deg']!r},{c['lat_deg']!r},0")
    ET.indent(root, space=" ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


# ------------------------------------------------------------------------------- CSV
def csv_columns() -> list[str]:
    return [*ICD_FIELDS, *EXTENT_FIELDS, *SEQ_FIELDS, "time_utc"]


def to_csv(contacts: Iterable[Mapping[str, Any]]) -> str:
    """CSV text: header of :func:`csv_columns`, one row per contact, lists joined with ``;``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\r\n")
    w.writerow(csv_columns())
    for c in _ordered(contacts):
        props = _properties(c)
        w.writerow([";".join(map(str, v)) if isinstance(v, list) else (repr(v) if isinstance(v, float) else v)
                    for v in (props.get(k, "") for k in csv_columns())])
    return buf.getvalue()


# ------------------------------------------------------------------------------- files
def format_of(path: str | Path, fmt: str | None = None) -> str:
    """The export format of ``path``: ``fmt`` if given, else from its suffix."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise AtrError(f"export format {fmt!r}: expected one of {', '.join(FORMATS)}")
        return fmt
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise AtrError(f"export file {path}: cannot tell the format from {suffix or 'no suffix'!r}; "
                       f"use one of {', '.join(SUFFIXES)} or --format {{{','.join(FORMATS)}}}")
    return SUFFIXES[suffix]


def render(contacts: Sequence[Mapping[str, Any]], fmt: str) -> str:
    """The text of an export of ``contacts`` in format ``fmt``."""
    if fmt == "geojson":
        return json.dumps(to_geojson(contacts), indent=1, allow_nan=False) + "\n"
    if fmt == "kml":
        return to_kml(contacts)
    if fmt == "csv":
        return to_csv(contacts)
    raise AtrError(f"export format {fmt!r}: expected one of {', '.join(FORMATS)}")


def write_export(path: str | Path, contacts: Sequence[Mapping[str, Any]], *, fmt: str | None = None) -> Path:
    """Write ``contacts`` to ``path`` atomically, in ``fmt`` or the format its suffix says."""
    p = Path(path)
    text = render(contacts, format_of(p, fmt))
    tmp = p.with_name(f".{p.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise AtrError(f"export file {p}: cannot write it ({exc.strerror or exc})") from None
    return p
