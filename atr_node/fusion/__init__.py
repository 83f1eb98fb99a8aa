"""Dempster-Shafer fusion and the georeferenced evidence grid (SPEC sections 6-7).

- :mod:`.mass`: pure mass algebra: the general Dempster rule (reference) and the {T, notT}
  closed form on log accumulators, vectorised.
- :mod:`.observation`: what the node passes per tile core and leg, validated.
- :mod:`.chunks`: chunk storage and the per-leg evidence layer.
- :mod:`.grid`: :class:`EvidenceGrid`, sparse chunks of accumulators, one piece of evidence
  per (leg, detector) per cell.
- :mod:`.merge`: exact merge of grids by adding accumulators.
- :mod:`.contacts`: :class:`Contact` (ICD section 3) and :class:`ContactTracker` (stable ids).
- :mod:`.baselines`: logical AND / OR over the same detections.
- :mod:`.snapshot`: atomic snapshot and restore.
"""

from .baselines import LogicalContact, and_contacts, or_contacts
from .contacts import Contact, ContactTracker
from .grid import DetectionRecord, EvidenceGrid, association_gate_m
from .mass import FRAME_TN, NOT_T, T, TNMasses, closed_form, combine, combine_all
from .observation import DetectionEvidence, DetectorObservation, Observation

__all__ = ["Contact", "ContactTracker", "DetectionEvidence", "DetectionRecord", "DetectorObservation",
           "EvidenceGrid", "FRAME_TN", "LogicalContact", "NOT_T", "Observation", "T", "TNMasses",
           "and_contacts", "association_gate_m", "closed_form", "combine", "combine_all", "or_contacts"]
