"""INS records of a simulated mission: NMEA 0183 and CAN frames (ICD sections 2 and 4).

The vehicle's navigation, as its INS would report it (truth plus the leg's error), is encoded
with the links' own codecs (``hw.nmea`` and ``hw.can_nav``, the DBC of ``config/``), so a
generated ``.atrlog`` replays through exactly the decoders the node runs aboard:

    every fix (NAV_RATE_HZ):  $GPGGA (position, -depth as height), $HEHDT (heading),
                              $SDDPT (altitude), CAN ATR_NavPosition, ATR_NavAttitude,
                              ATR_NavAltitude
    once a second:            $GPZDA (date for GGA), CAN ATR_Time, ATR_MissionLeg

Each record is ``(t_arrival, link, msg)`` with the ``msg`` of ICD section 4.
"""

from __future__ import annotations

from typing import Any

import numpy as np

NAV_RATE_HZ = 5.0

Record = tuple[float, str, Any]


def _can(frame: tuple[int, bytes, bool], t: float) -> Record:
    cid, data, ext = frame
    return (t, "can", {"id": int(cid), "data": bytes(data), "ext": bool(ext)})


def ins_records(times: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray, heading_deg: np.ndarray, *,
                altitude_m: np.ndarray, depth_m: np.ndarray, leg: int, survey: np.ndarray) -> list[Record]:
    """NMEA and CAN records for navigation samples.

    Parameters
    ----------
    times : ndarray, shape (n,)
        UNIX seconds of the samples (NAV_RATE_HZ apart; every NAV_RATE_HZ-th one also gets
        the once-a-second records).
    lat_deg, lon_deg, heading_deg, altitude_m, depth_m : ndarray, shape (n,)
        Reported navigation (true heading, altitude above the seabed, depth below the surface).
    leg
        Survey leg number for ``ATR_MissionLeg``.
    survey : ndarray, shape (n,), bool
        On a survey line (True) or turning (False).

    Returns
    -------
    list of (t, link, msg)
        Arrival times a few milliseconds after each sample, in no particular order.
    """
    from hw import can_nav, nmea  # the links' codecs

    out: list[Record] = []
    per_second = max(int(round(NAV_RATE_HZ)), 1)
    for i, t in enumerate(np.asarray(times, dtype=np.float64)):
        t = float(t)
        lat, lon, hdg = float(lat_deg[i]), float(lon_deg[i]), float(heading_deg[i])
        alt, dep = float(altitude_m[i]), float(depth_m[i])
        out.append((t, "nmea", nmea.encode_gga(t, lat, lon, height_m=-dep)))
        out.append((t + 0.002, "nmea", nmea.encode_hdt(hdg)))
        out.append((t + 0.004, "nmea", nmea.encode_dpt(alt)))
        if i % per_second == 0:
            out.append((t + 0.006, "nmea", nmea.encode_zda(t)))
            out.append(_can(can_nav.encode_time(t), t + 0.001))
            out.append(_can(can_nav.encode_leg(leg, survey=bool(survey[i])), t + 0.001))
        out.append(_can(can_nav.encode_position(lat, lon), t + 0.003))
        out.append(_can(can_nav.encode_attitude(hdg), t + 0.003))
        out.append(_can(can_nav.encode_altitude(alt, depth_m=dep), t + 0.003))
    return out
