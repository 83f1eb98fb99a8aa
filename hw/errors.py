"""The exception tree of the link drivers (package ``hw``).

Every error a driver raises on purpose is a :class:`LinkError`, itself an
:class:`atr_node.errors.AtrError`; its message says which link, what was wrong and what form
was expected::

    AtrError
     +-- NmeaError              a sentence that cannot be encoded (atr_node.io.nmea_encode; decoding
     |                          never raises: it counts)
     +-- LinkError              a link driver (names the link or URL)
          +-- LinkSpecError     a link spec, URL or option that cannot be opened as given
          +-- LinkClosedError   recv() on a link after shutdown()
          +-- CanCodecError     a CAN frame that cannot be encoded from the given values

Bad *input* on a live link (garbage, bad checksums, unknown frames) never raises: decoders
count and drop it, so a noisy bus cannot stop the node (ICD section 2).
"""

from __future__ import annotations

from atr_node.errors import AtrError


class LinkError(AtrError):
    """Base of every error a link driver raises on purpose."""


class LinkSpecError(LinkError, ValueError):
    """A link spec, URL or option is unknown or malformed (the message shows the expected form)."""


class LinkClosedError(LinkError):
    """The link was shut down."""


from atr_node.io.nmea_encode import NmeaError  # noqa: E402,F401  (defined with the encoders, in atr_node.io)


class CanCodecError(LinkError, ValueError):
    """A CAN frame cannot be encoded from the given values."""
