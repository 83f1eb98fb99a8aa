"""The operators' contact list: the latest state of every contact id (ICD section 3).

A :class:`ContactBook` is filled from either source the operators have:

- a live node: every ``contact`` message of its PUB stream, applied in arrival order (ZeroMQ
  keeps a publisher's order on one connection, so the last message of an id is its state);
- a ``--contacts-out`` file of ``atr-node replay``: JSON lines, one final contact state per
  line (:func:`atr_node.node.service.write_contacts`), read by :func:`read_contacts`.

Withdrawn contacts are **kept and flagged**: their last message (``state == "withdrawn"``)
stays in the book, so a monitor can show that a contact went away and a later message of the
same id brings it back. Views (:meth:`ContactBook.contacts`) drop them unless asked, and so do
the exports by default.

Every message is checked with :func:`atr_node.node.wire.validate_contact` first. A bad
message never changes the book: from the stream it is counted and logged, from a file it is an
:class:`~atr_node.errors.AtrError` naming the file, the line and what was wrong.
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from pathlib import Path
from typing import Any, Iterable, Mapping

from ..errors import AtrError
from ..node import wire

log = logging.getLogger(__name__)

ICD_FIELDS: tuple[str, ...] = tuple(wire.CONTACT_FIELDS)
"""The ICD section 3 contact keys, in the ICD's order (the column order of every export)."""


class ContactBook:
    """Latest state per contact id.

    Attributes
    ----------
    accepted : Counter[str]
        Messages applied, by ``state``.
    rejected : int
        Messages refused (not an ICD v1 contact); the book was left unchanged by each.
    last_problem : str
        Why the last refused message was refused.
    """

    def __init__(self) -> None:
        self._by_id: dict[int, dict[str, Any]] = {}
        self.accepted: Counter[str] = Counter()
        self.rejected = 0
        self.last_problem = ""

    def __len__(self) -> int:
        return len(self._by_id)

    def __contains__(self, contact_id: object) -> bool:
        return contact_id in self._by_id

    def get(self, contact_id: int) -> dict[str, Any] | None:
        return self._by_id.get(contact_id)

    def apply(self, message: Mapping[str, Any], *, where: str = "stream") -> bool:
        """Apply one contact message; False (and counted, logged) when it is not a valid one."""
        problems = wire.validate_contact(message)
        if problems:
            self.rejected += 1
            self.last_problem = f"{where}: {'; '.join(problems)}"
            log.warning("contact message refused (%s)", self.last_problem)
            return False
        self._by_id[int(message["id"])] = dict(message)
        self.accepted[message["state"]] += 1
        return True

    def contacts(self, *, include_withdrawn: bool = False) -> list[dict[str, Any]]:
        """Contacts by decreasing belief (then id): copies of their last messages."""
        chosen = [c for c in self._by_id.values() if include_withdrawn or c["state"] != "withdrawn"]
        return [dict(c) for c in sorted(chosen, key=lambda c: (-c["bel"], c["id"]))]

    @property
    def n_live(self) -> int:
        return sum(1 for c in self._by_id.values() if c["state"] != "withdrawn")

    @property
    def n_withdrawn(self) -> int:
        return len(self._by_id) - self.n_live


def read_contacts(path: str | Path, book: ContactBook | None = None) -> ContactBook:
    """Read a ``--contacts-out`` JSON-lines file into ``book`` (a new one by default).

    Blank lines are skipped; a later line of the same id replaces an earlier one.

    Raises
    ------
    AtrError
        The file cannot be read, or a line is not JSON or not an ICD v1 contact (the message
        names the file and line). ``book`` is then left as it was before the call.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise AtrError(f"contacts file {p}: cannot read it ({type(exc).__name__}: {exc})") from None
    messages: list[tuple[int, dict[str, Any]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            m = json.loads(line)
        except json.JSONDecodeError as exc:
            raise AtrError(f"contacts file {p}, line {lineno}: not JSON ({exc.msg} at column {exc.colno}); "
                           f"expected one contact object per line (atr-node replay --contacts-out)") from None
        problems = wire.validate_contact(m)
        if problems:
            raise AtrError(f"contacts file {p}, line {lineno}: not an ICD v1 contact: {'; '.join(problems)}")
        messages.append((lineno, m))
    book = book if book is not None else ContactBook()
    for lineno, m in messages:  # all lines checked first: a bad file leaves the book unchanged
        book.apply(m, where=f"{p}:{lineno}")
    return book


def book_of(messages: Iterable[Mapping[str, Any]]) -> ContactBook:
    """A book holding ``messages`` applied in order (invalid ones counted in ``rejected``)."""
    book = ContactBook()
    for m in messages:
        book.apply(m)
    return book
