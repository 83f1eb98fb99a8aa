"""Operators' tools: the contact list where the people around the vehicle already work.

- :mod:`.book`: :class:`ContactBook`, the latest state per contact id, from a live node or a
  ``--contacts-out`` file (withdrawn contacts kept, flagged by ``state``).
- :mod:`.stream`: :class:`NodeFollower`, a node's PUB stream (ICD section 3) into a book.
- :mod:`.export`: GeoJSON (RFC 7946), KML 2.2 and CSV files of the contacts.
- :mod:`.monitor`: the live terminal monitor; :mod:`.beliefmap`: its belief-map PNG.
- :mod:`.exwpt`: new and updated contacts over serial as SonarWiz ``$EXWPT`` sentences.

Commands: ``atr-node export``, ``atr-node monitor``, ``atr-node exwpt`` (docs/operators.md).
"""

from .book import ICD_FIELDS, ContactBook, book_of, read_contacts
from .export import FORMATS, to_csv, to_geojson, to_kml, write_export
from .stream import NodeFollower

__all__ = ["FORMATS", "ICD_FIELDS", "ContactBook", "NodeFollower", "book_of", "read_contacts", "to_csv",
           "to_geojson", "to_kml", "write_export"]
