"""Scoring contacts against ground truth (ICD section 5).

Truth files are CSV with a header ``lat_deg,lon_deg,shape`` (more columns allowed). A contact
matches a truth target within 3 m horizontal distance; each target matches at most one
contact and each contact at most one target (a maximum one-to-one matching, nearest pairs
preferred); contacts that match nothing are false alarms; Pd = matched targets / targets.
ROC curves sweep a threshold on a score (``bel`` for fusion) and match at each threshold.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import AtrError

MATCH_RADIUS_M = 3.0
EARTH_RADIUS_M = 6371008.8


@dataclass(frozen=True)
class TruthTarget:
    lat_deg: float
    lon_deg: float
    shape: str
    extra: dict[str, str] = field(default_factory=dict, compare=False)


def read_truth(path: str | Path, *, what: str = "truth file") -> list[TruthTarget]:
    """Read a truth CSV (ICD section 5); errors name the file (as ``what``), line and column."""
    p = Path(path)
    try:
        fh = open(p, newline="")
    except OSError as exc:
        raise AtrError(f"{what} {p}: {exc.strerror}") from None
    with fh:
        reader = csv.DictReader(fh)
        missing = {"lat_deg", "lon_deg", "shape"} - set(reader.fieldnames or ())
        if missing:
            raise AtrError(f"{what} {p}: header lacks {sorted(missing)}; expected lat_deg,lon_deg,shape[,...]")
        out = []
        for line, row in enumerate(reader, start=2):
            try:
                lat, lon = float(row["lat_deg"]), float(row["lon_deg"])
            except (TypeError, ValueError):
                raise AtrError(f"{what} {p}, line {line}: lat_deg/lon_deg are not numbers") from None
            if not (-90 <= lat <= 90 and -180 <= lon <= 360):
                raise AtrError(f"{what} {p}, line {line}: position {lat}, {lon} out of range")
            out.append(TruthTarget(lat, lon, row["shape"] or "", {k: v for k, v in row.items()
                                                                   if k not in ("lat_deg", "lon_deg", "shape")}))
    return out


TARGET_LIKE_VALUES = {"": False, "0": False, "1": True, "false": False, "true": True, "no": False, "yes": True}
"""Accepted values of a clutter file's optional ``target_like`` column (any case)."""


@dataclass(frozen=True)
class Clutter:
    """Known objects that are not targets (rocks, debris, earlier surveys' non-mine-like
    bottom objects), to say which false alarms lie on them (:func:`fa_anatomy`)."""

    objects: tuple[TruthTarget, ...]
    target_like: np.ndarray
    """(n,) bool: the file's ``target_like`` column (False where it has none)."""


def read_clutter(path: str | Path) -> Clutter:
    """Read a clutter CSV: the truth file's format (``lat_deg,lon_deg,shape[,...]``) with an
    optional ``target_like`` column (1/0, true/false, yes/no; empty = 0). Errors name the file
    and line."""
    objs = read_truth(path, what="clutter file")
    like = []
    for line, o in enumerate(objs, start=2):
        v = str(o.extra.get("target_like") or "").strip().lower()
        if v not in TARGET_LIKE_VALUES:
            raise AtrError(f"clutter file {path}, line {line}: target_like {o.extra.get('target_like')!r}: "
                           "expected 1/0, true/false or yes/no")
        like.append(TARGET_LIKE_VALUES[v])
    return Clutter(tuple(objs), np.array(like, dtype=bool))


FA_KINDS = ("second_on_target", "one_leg_object", "target_like_clutter", "clutter", "seabed")
"""What a false alarm lies on (:func:`fa_anatomy`), the first that applies: within the match
radius of a target (a second contact on it: the matching gives a target one contact), of an
object shown on one leg only (the held-out benchmark's), of a known object marked target-like,
of any other known object; else on no known object: the seabed itself (texture, ripples,
speckle) or an object nobody listed."""


def fa_anatomy(contacts_en: np.ndarray, scores: Sequence[float], truth_en: np.ndarray, *, threshold: float,
               clutter_en: np.ndarray | None = None, clutter_target_like: np.ndarray | None = None,
               one_leg_en: np.ndarray | None = None, radius_m: float = MATCH_RADIUS_M) -> dict[str, Any]:
    """The false alarms among the contacts scored >= ``threshold`` (those the one-to-one
    matching to ``truth_en`` leaves, as :func:`roc` and the operating point count them), by
    what each lies on (:data:`FA_KINDS`, within ``radius_m``). Positions are east/north metres
    in one frame; ``clutter_target_like`` is per clutter object (default all False)."""
    c = np.asarray(contacts_en, dtype=np.float64).reshape(-1, 2)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    if s.size != len(c):
        raise ValueError(f"{len(c)} contacts but {s.size} scores")
    keep = np.flatnonzero(s >= threshold)
    matched = {int(keep[i]) for i, _ in match(c[keep], truth_en, radius_m=radius_m)}
    fa = c[[i for i in keep if int(i) not in matched]].reshape(-1, 2)
    clutter = np.zeros((0, 2)) if clutter_en is None else np.asarray(clutter_en, dtype=np.float64).reshape(-1, 2)
    like = (np.zeros(len(clutter), dtype=bool) if clutter_target_like is None
            else np.asarray(clutter_target_like, dtype=bool).reshape(-1))
    if like.size != len(clutter):
        raise ValueError(f"{len(clutter)} clutter objects but {like.size} target_like flags")
    one_leg = np.zeros((0, 2)) if one_leg_en is None else one_leg_en
    out: dict[str, Any] = {"threshold": float(threshold), "false_alarms": int(len(fa))}
    left = np.ones(len(fa), dtype=bool)
    for kind, places in zip(FA_KINDS[:-1], (truth_en, one_leg, clutter[like], clutter[~like])):
        on = near_any(fa, places, radius_m) & left
        out[kind] = int(on.sum())
        left &= ~on
    out[FA_KINDS[-1]] = int(left.sum())
    return out


def near_any(points: np.ndarray, places: np.ndarray, radius_m: float = MATCH_RADIUS_M) -> np.ndarray:
    """Per point (n, 2), whether one of ``places`` (k, 2) lies within ``radius_m`` (a k-d tree:
    a survey's clutter list may hold thousands)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    q = np.asarray(places, dtype=np.float64).reshape(-1, 2)
    if not len(p) or not len(q):
        return np.zeros(len(p), dtype=bool)
    return cKDTree(q).query(p, distance_upper_bound=radius_m)[0] <= radius_m


def local_en(lat: np.ndarray, lon: np.ndarray, lat0: float, lon0: float) -> tuple[np.ndarray, np.ndarray]:
    """Equirectangular east/north in metres about (lat0, lon0): exact to millimetres over the
    few kilometres of a mission, which is all a 3 m match needs."""
    k = math.radians(1.0) * EARTH_RADIUS_M
    dlon = (np.asarray(lon, dtype=np.float64) - lon0 + 180.0) % 360.0 - 180.0
    return dlon * k * math.cos(math.radians(lat0)), (np.asarray(lat, dtype=np.float64) - lat0) * k


def match(contacts_en: np.ndarray, truth_en: np.ndarray, *, radius_m: float = MATCH_RADIUS_M) -> list[tuple[int, int]]:
    """Maximum one-to-one matching of contacts to targets within ``radius_m``.

    Among matchings of maximum size, the one with the smallest total distance.
    Returns (contact index, target index) pairs.
    """
    c = np.asarray(contacts_en, dtype=np.float64).reshape(-1, 2)
    t = np.asarray(truth_en, dtype=np.float64).reshape(-1, 2)
    if c.size == 0 or t.size == 0:
        return []
    d = np.hypot(c[:, None, 0] - t[None, :, 0], c[:, None, 1] - t[None, :, 1])
    ok = d <= radius_m
    if not ok.any():
        return []
    # a match is worth far more than any distance: maximise matches first, then minimise distance
    cost = np.where(ok, d - 1e6, 0.0)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(k)) for r, k in zip(rows, cols) if ok[r, k]]


@dataclass(frozen=True)
class OperatingPoint:
    threshold: float
    pd: float
    false_alarms: int
    contacts: int
    matched: int


@dataclass(frozen=True)
class RocCurve:
    """Pd and false alarms as a threshold sweeps a score (one point per distinct score)."""

    name: str
    points: tuple[OperatingPoint, ...]
    n_targets: int

    @property
    def pd(self) -> np.ndarray:
        return np.array([p.pd for p in self.points])

    @property
    def false_alarms(self) -> np.ndarray:
        return np.array([p.false_alarms for p in self.points])

    def best_pd(self) -> float:
        return float(self.pd.max(initial=0.0))

    def fa_at_pd(self, pd: float) -> float:
        """Fewest false alarms at which Pd reaches ``pd`` (inf when it never does)."""
        fa = [p.false_alarms for p in self.points if p.pd >= pd - 1e-12]
        return float(min(fa)) if fa else math.inf

    def at_threshold(self, threshold: float) -> OperatingPoint:
        """The operating point of the smallest swept threshold >= ``threshold``."""
        cands = [p for p in self.points if p.threshold >= threshold]
        if not cands:
            return OperatingPoint(threshold, 0.0, 0, 0, 0)
        return min(cands, key=lambda p: p.threshold)


def roc(name: str, contacts_en: np.ndarray, scores: Sequence[float], truth_en: np.ndarray, *,
        radius_m: float = MATCH_RADIUS_M, max_points: int = 400) -> RocCurve:
    """Sweep a threshold over ``scores``: at each, contacts with score >= threshold are matched."""
    c = np.asarray(contacts_en, dtype=np.float64).reshape(-1, 2)
    s = np.asarray(scores, dtype=np.float64).reshape(-1)
    n_t = int(np.asarray(truth_en).reshape(-1, 2).shape[0])
    if s.size == 0:
        return RocCurve(name, (OperatingPoint(math.inf, 0.0, 0, 0, 0),), n_t)
    levels = np.unique(s)[::-1]
    if levels.size > max_points:
        levels = np.unique(np.quantile(s, np.linspace(0, 1, max_points)))[::-1]
    pts = [OperatingPoint(math.inf, 0.0, 0, 0, 0)]
    for thr in levels:
        keep = s >= thr
        m = match(c[keep], truth_en, radius_m=radius_m)
        n = int(keep.sum())
        pts.append(OperatingPoint(float(thr), len(m) / max(n_t, 1), n - len(m), n, len(m)))
    return RocCurve(name, tuple(pts), n_t)


def operating_point(name: str, contacts_en: np.ndarray, truth_en: np.ndarray, *,
                    radius_m: float = MATCH_RADIUS_M) -> RocCurve:
    """A single operating point (logical AND / OR) as a one-point curve."""
    c = np.asarray(contacts_en, dtype=np.float64).reshape(-1, 2)
    n_t = int(np.asarray(truth_en).reshape(-1, 2).shape[0])
    m = match(c, truth_en, radius_m=radius_m)
    n = int(c.shape[0])
    return RocCurve(name, (OperatingPoint(0.0, len(m) / max(n_t, 1), n - len(m), n, len(m)),), n_t)


@dataclass(frozen=True)
class ContactScore:
    """Published contacts scored against truth (:func:`score_contacts`)."""

    curve: RocCurve
    """ROC sweeping Bel(T) over the live contacts (they reach down to ``fusion.withdraw_bel``)."""
    point: OperatingPoint
    """At Bel(T) >= ``threshold_bel``."""
    threshold_bel: float
    targets: int
    contacts: int
    """Live (not withdrawn) contacts, at any Bel(T)."""
    anatomy: dict[str, Any] | None = None
    """With a clutter file: what the false alarms at ``threshold_bel`` lie on (:func:`fa_anatomy`)."""

    def summary(self) -> dict[str, Any]:
        """The fields of ``evaluation.json`` (``atr-node evaluate --contacts``)."""
        best = self.curve.best_pd()
        out = {"targets": self.targets, "contacts": self.contacts, "threshold_bel": self.threshold_bel,
               "pd": self.point.pd, "false_alarms": self.point.false_alarms, "matched": self.point.matched,
               "best_pd": best, "fa_at_best_pd": self.curve.fa_at_pd(best)}
        if self.anatomy is not None:
            out["false_alarm_anatomy"] = {k: self.anatomy[k] for k in FA_KINDS if k != "one_leg_object"}
        return out

    def anatomy_line(self) -> str:
        """One sentence on what the false alarms lie on ('' without a clutter file)."""
        a = self.anatomy
        if a is None:
            return ""
        return (f"of the {a['false_alarms']} false alarms at Bel >= {self.threshold_bel:g}: {a['clutter'] + a['target_like_clutter']} "
                f"on known clutter ({a['target_like_clutter']} of it marked target-like), {a['second_on_target']} second "
                f"contacts on a target, {a['seabed']} on no known object")


def score_contacts(contacts: Sequence[dict[str, Any]], truth: Sequence[TruthTarget], *, bel: float,
                   name: str = "node's contacts", clutter: Clutter | None = None) -> ContactScore:
    """Score contact messages (ICD section 3) against truth (ICD section 5).

    The one scoring of a node's published contacts: ``atr-node evaluate --contacts`` /
    ``--subscribe`` and the demo's node row both call it, so the two cannot disagree.

    Parameters
    ----------
    contacts : sequence of dict
        The final message of each contact (``--contacts-out``, or the latest per id from the
        PUB socket); withdrawn ones are left out.
    truth : sequence of TruthTarget
        The targets (:func:`read_truth`).
    bel : float
        The operating point: contacts with Bel(T) >= ``bel`` are reported.
    name : str
        The ROC curve's name.
    clutter : Clutter, optional
        Known objects that are not targets (:func:`read_clutter`): the score then says what
        the false alarms at ``bel`` lie on (``anatomy``).

    Returns
    -------
    ContactScore
        Pd and false alarms at ``bel``, and the ROC over the live contacts.
    """
    live = [c for c in contacts if c.get("state") != "withdrawn"]
    # positions from lat/lon, the only frame a contact file shares with the truth file
    if truth:
        lat0, lon0 = truth[0].lat_deg, truth[0].lon_deg
    elif clutter is not None and clutter.objects:
        lat0, lon0 = clutter.objects[0].lat_deg, clutter.objects[0].lon_deg
    elif live:
        lat0, lon0 = live[0]["lat_deg"], live[0]["lon_deg"]
    else:
        lat0, lon0 = 0.0, 0.0
    t_en = np.column_stack(local_en(np.array([t.lat_deg for t in truth]), np.array([t.lon_deg for t in truth]),
                                    lat0, lon0)) if truth else np.zeros((0, 2))
    c_en = np.column_stack(local_en(np.array([c["lat_deg"] for c in live]), np.array([c["lon_deg"] for c in live]),
                                    lat0, lon0)) if live else np.zeros((0, 2))
    scores = [float(c["bel"]) for c in live]
    curve = roc(name, c_en, scores, t_en)
    # the operating point matched directly, not read off the curve: exact at any ``bel``, and
    # independent of the curve's decimation on a very long contact list
    keep = np.array(scores, dtype=np.float64) >= bel
    m = match(c_en[keep], t_en)
    n = int(keep.sum())
    point = OperatingPoint(float(bel), len(m) / max(len(truth), 1), n - len(m), n, len(m))
    anatomy = None
    if clutter is not None:
        k_en = (np.column_stack(local_en(np.array([o.lat_deg for o in clutter.objects]),
                                         np.array([o.lon_deg for o in clutter.objects]), lat0, lon0))
                if clutter.objects else np.zeros((0, 2)))
        anatomy = fa_anatomy(c_en, scores, t_en, threshold=float(bel), clutter_en=k_en,
                             clutter_target_like=clutter.target_like)
    return ContactScore(curve, point, float(bel), len(truth), len(live), anatomy)
