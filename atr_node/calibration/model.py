"""The detector performance model and its versioned, self-describing file (SPEC section 5).

A :class:`PerformanceModel` holds, per detector, the threshold tau, the confidence table
c(gamma; tau) and the P(y) table Pd(r; tau) with its Wilson interval, plus where it came from.
The node calls ``model.confidence(d, gamma)``, ``model.pd(d, range_m)`` and reads
``model.tau[d]``.

File format (JSON, UTF-8), format version 1::

    {"format": "atr-node-performance-model", "format_version": 1,
     "provenance": {"created_utc", "atr_node_version", "source", "sensor": {...},
                    "seabed", "n_images", "targets_per_image", "iterations", "seed",
                    "n_target_responses", "n_nontarget_responses",
                    "population": {calibration.population settings, "n_nominal"}, ...},
     "estimation": {"prior_target", "pd_target", "range_bin_m", "smoothing",
                    "threshold_on", "n_threshold_targets"},
     "detectors": {"mf": {"tau", "tau_source", "pd_at_tau",
                          "confidence": {"gamma": [...], "c": [...],
                                         "isotonic_adjusted", "max_adjustment"},
                          "pyr": {"edges_m", "injected", "detected", "pd", "low", "high"}},
                   ...},
     "sha256": hex digest of the canonical JSON of everything above}

A file of another format version, or one that fails its checksum or any check of shape and
range, is refused with :class:`~atr_node.errors.ModelFileError` naming the file and the key.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import ModelFileError
from .stats import ConfidenceCurve, PdCurve, pd_at

FORMAT_NAME = "atr-node-performance-model"
FORMAT_VERSION = 1
SHIPPED_MODEL = Path(__file__).resolve().parent.parent / "data" / "performance_model.json"


def look_detects(z: np.ndarray | float, tau: float, tau_source: str) -> np.ndarray:
    """Where a look that fired, with score ``z``, is a detection under a look table's rule: every
    fired look with a score for ``tau_source = "look"`` (a look below every calibration score
    still detects), else ``z > tau`` (``look_pd``, ``look_z``, and a source this code does not know,
    whose P(y) most likely counted weaker looks as misses). The calibration's P(y) and the
    node's evidence both ask this."""
    z = np.asarray(z, dtype=np.float64)
    return ~np.isnan(z) if tau_source == "look" else z > tau


@dataclass(frozen=True)
class DetectorPerformance:
    """One detector's estimates at its threshold ``tau``.

    ``tau_source`` is ``"dobeck"`` (from the synthetic targets at the Pd target) or
    ``"config"``; for a look table (SPEC 6.1) ``"look"`` (every fired look detects; tau is
    below every fired calibration score), ``"look_pd"`` (a look detects where its score z >
    tau, ``calibration.look_pd``) or ``"look_z"`` (z > tau = ``calibration.look_z_min``, the
    higher of the two); ``pd_at_tau`` the fraction of synthetic targets detected.
    """

    tau: float
    confidence: ConfidenceCurve
    pyr: PdCurve
    tau_source: str = "dobeck"
    pd_at_tau: float = float("nan")

    def confidence_at(self, gamma: np.ndarray | float) -> np.ndarray:
        """c(gamma; tau): linear in the table, its end values outside it; NaN stays NaN."""
        g = np.asarray(gamma, dtype=np.float64)
        c = np.interp(g, self.confidence.gamma, self.confidence.confidence)
        return np.where(np.isnan(g), np.nan, c)

    def pd_at(self, range_m: np.ndarray | float) -> np.ndarray:
        """Pd(r; tau), 0 outside the calibrated span."""
        return pd_at(self.pyr.edges_m, self.pyr.pd, range_m)

    def detects(self, z: np.ndarray | float) -> np.ndarray:
        """For a look table: :func:`look_detects` under this table's tau and source."""
        return look_detects(z, self.tau, self.tau_source)


@dataclass(frozen=True)
class PerformanceModel:
    """Per detector tau, confidence and P(y) tables, and their provenance."""

    detectors: Mapping[str, DetectorPerformance]
    provenance: Mapping[str, Any] = field(default_factory=dict)
    estimation: Mapping[str, Any] = field(default_factory=dict)
    looks: Any = None
    """:class:`~atr_node.calibration.looks.LookModel` (SPEC 6.1), None in older files."""

    def __post_init__(self) -> None:
        # A private copy (a plain dict, so the model pickles for worker processes).
        object.__setattr__(self, "detectors", dict(self.detectors))

    # -- what the node calls ----------------------------------------------------------------
    @property
    def tau(self) -> dict[str, float]:
        """Threshold per detector."""
        return {d: p.tau for d, p in self.detectors.items()}

    def _get(self, detector: str) -> DetectorPerformance:
        try:
            return self.detectors[detector]
        except KeyError:
            raise KeyError(f"detector {detector!r} not in this model (has {sorted(self.detectors)})") from None

    def confidence(self, detector: str, gamma: np.ndarray | float) -> np.ndarray:
        """c_d(gamma; tau_d), strictly in (0, 1) and non-decreasing in gamma (NaN -> NaN)."""
        return self._get(detector).confidence_at(gamma)

    def pd(self, detector: str, range_m: np.ndarray | float) -> np.ndarray:
        """Pd_d(r; tau_d) at ground ranges, 0 outside the calibrated span."""
        return self._get(detector).pd_at(range_m)

    def look(self, detectors) -> DetectorPerformance | None:
        """The look-level table (SPEC 6.1) of a detector set, None when the model has none."""
        return None if self.looks is None else self.looks.table(detectors)

    def look_score(self, responses, detectors, *, headroom_db: float = math.inf) -> np.ndarray:
        """The look score z of joint responses (``responses[d]`` per detector) at a place with
        this headroom under the recording's full scale (:meth:`LookModel.score`)."""
        return self.looks.score(responses, detectors, headroom_db=headroom_db)

    @property
    def prior_target(self) -> float:
        """P(T) per cell the confidence tables were made with."""
        return float(self.estimation.get("prior_target", 0.1))

    def with_prior(self, prior_target: float) -> "PerformanceModel":
        """This model with every confidence table (detectors and looks) read under another
        P(T) per cell (:func:`~atr_node.calibration.looks.with_prior`): e.g. the paper's 0.1
        for a comparison, without calibrating again."""
        import dataclasses

        from .looks import with_prior

        old = self.prior_target

        def conv(p: DetectorPerformance) -> DetectorPerformance:
            c = p.confidence
            nc = dataclasses.replace(c, confidence=np.clip(with_prior(c.confidence, old, prior_target), 1e-15,
                                                           1.0 - 1e-15),
                                     raw=None if c.raw is None else with_prior(c.raw, old, prior_target))
            return dataclasses.replace(p, confidence=nc)

        looks = None if self.looks is None else dataclasses.replace(
            self.looks, tables={k: conv(p) for k, p in self.looks.tables.items()})
        est = dict(self.estimation)
        est.update({"prior_target": float(prior_target), "prior": "fixed", "prior_from": old})
        return PerformanceModel({d: conv(p) for d, p in self.detectors.items()}, self.provenance, est, looks)

    def thresholds(self):
        """The thresholds as :class:`~atr_node.config.ThresholdSettings` (config values for
        detectors this model lacks)."""
        from ..config import ThresholdSettings

        base = ThresholdSettings()
        return ThresholdSettings(**{d: self.detectors[d].tau if d in self.detectors else getattr(base, d)
                                    for d in ("mf", "lac", "smf", "z")})

    # -- file --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The file's content, checksum included (plain JSON types); :meth:`from_dict`
        reads it back."""
        body = self._content()
        body["sha256"] = _digest(body)
        return body

    def _content(self) -> dict[str, Any]:
        body = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION,
                "provenance": _jsonable(dict(self.provenance)),
                "estimation": _jsonable(dict(self.estimation)),
                "detectors": {name: _detector_dict(p) for name, p in self.detectors.items()}}
        if self.looks is not None:
            from .looks import looks_to_dict

            body["looks"] = _jsonable(looks_to_dict(self.looks, _detector_dict))
        return body

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model file (atomically: a temporary file renamed over ``path``)."""
        body = self.to_dict()
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.name + ".tmp")
        tmp.write_text(json.dumps(body, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        os.replace(tmp, p)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "PerformanceModel":
        """Read and check a model file.

        Raises
        ------
        ModelFileError
            Missing or unreadable file, not JSON, another format or format version, checksum
            mismatch, missing key, wrong shape or out-of-range value; names the file and key.
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ModelFileError(f"{p}: cannot read the performance model: {exc}") from None
        try:
            body = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ModelFileError(f"{p}: corrupted performance model, not valid JSON ({exc})") from None
        return cls.from_dict(body, where=str(p))

    @classmethod
    def from_dict(cls, body: Any, *, where: str = "<dict>") -> "PerformanceModel":
        """Build from a parsed file body, with every check of :meth:`load`."""
        if not isinstance(body, dict) or body.get("format") != FORMAT_NAME:
            raise ModelFileError(f"{where}: not an atr-node performance model (key 'format' is not {FORMAT_NAME!r})")
        version = body.get("format_version")
        if version != FORMAT_VERSION:
            raise ModelFileError(
                f"{where}: performance model format version {version!r}; this atr-node reads version "
                f"{FORMAT_VERSION} only: regenerate the model with 'atr-node calibrate'")
        digest = body.get("sha256")
        content = {k: v for k, v in body.items() if k != "sha256"}
        try:
            ok = digest == _digest(content)
        except (TypeError, ValueError):  # NaN or Infinity tokens (json.loads takes them) cannot be hashed
            raise ModelFileError(f"{where}: corrupted performance model: a value is NaN or infinite") from None
        if not ok:
            raise ModelFileError(f"{where}: corrupted performance model: the checksum (key 'sha256') does not match "
                                 f"the content")
        dets_raw = _req(body, "detectors", dict, where)
        if not dets_raw:
            raise _err(where, "detectors", "no detector in the model")
        dets = {name: _detector_from(raw, where, name) for name, raw in dets_raw.items()}
        looks = None
        if "looks" in body:
            from .looks import looks_from_dict

            looks = looks_from_dict(body["looks"], where, lambda raw, w, key: _detector_from(raw, w, key, pre=key + "."))
        return cls(detectors=dets, provenance=_req(body, "provenance", dict, where),
                   estimation=_req(body, "estimation", dict, where), looks=looks)

    @classmethod
    def shipped(cls) -> "PerformanceModel":
        """The model shipped with the package (``atr_node/data/performance_model.json``)."""
        return cls.load(SHIPPED_MODEL)


# ----------------------------------------------------------------------------------------


def _num(x: float) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num(float(obj))
    return obj


def _digest(content: dict[str, Any]) -> str:
    canon = json.dumps(content, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(canon.encode("utf-8")).hexdigest()


def _err(where: str, key: str, message: str) -> ModelFileError:
    return ModelFileError(f"{where}, key '{key}': {message}" if key else f"{where}: {message}")


def _req(obj: dict[str, Any], key: str, tp: type, where: str, prefix: str = "") -> Any:
    """``obj[key]`` of type ``tp``; errors name the file and the dotted key ``prefix + key``."""
    if key not in obj:
        raise _err(where, prefix + key, "missing")
    v = obj[key]
    if tp is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, tp) or (tp is int and isinstance(v, bool)):
        raise _err(where, prefix + key, f"should be {tp.__name__}, got {type(v).__name__}")
    return v


def _arr(obj: dict[str, Any], key: str, where: str, prefix: str, n: int | None = None) -> np.ndarray:
    v = _req(obj, key, list, where, prefix)
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise _err(where, prefix + key, "not a list of numbers") from None
    if a.ndim != 1 or (n is not None and a.size != n) or not np.all(np.isfinite(a)):
        raise _err(where, prefix + key, f"expected {n if n is not None else 'some'} finite numbers, got shape {a.shape}")
    return a


def _detector_dict(p: DetectorPerformance) -> dict[str, Any]:
    c, y = p.confidence, p.pyr
    return {
        "tau": float(p.tau), "tau_source": p.tau_source, "pd_at_tau": _num(p.pd_at_tau),
        "confidence": {"gamma": c.gamma.tolist(), "c": c.confidence.tolist(),
                       "isotonic_adjusted": bool(c.isotonic_adjusted),
                       "max_adjustment": float(c.max_adjustment),
                       "n_target_above": int(c.n_target_above),
                       "n_nontarget_above": int(c.n_nontarget_above)},
        "pyr": {"edges_m": y.edges_m.tolist(), "injected": y.injected.tolist(),
                "detected": y.detected.tolist(), "pd": y.pd.tolist(),
                "low": y.low.tolist(), "high": y.high.tolist()},
    }


def _detector_from(raw: Any, where: str, name: str, pre: str | None = None) -> DetectorPerformance:
    pre = pre or f"detectors.{name}."
    if not isinstance(raw, dict):
        raise _err(where, pre[:-1], "expected a map")
    tau = _req(raw, "tau", float, where, pre)
    cr = _req(raw, "confidence", dict, where, pre)
    cp = pre + "confidence."
    g = _arr(cr, "gamma", where, cp)
    c = _arr(cr, "c", where, cp, g.size)
    if g.size < 2 or np.any(np.diff(g) <= 0):
        raise _err(where, cp + "gamma", "must be increasing, at least 2 values")
    if np.any(c <= 0) or np.any(c >= 1) or np.any(np.diff(c) < 0):
        raise _err(where, cp + "c", "must be strictly inside (0, 1) and non-decreasing")
    yr = _req(raw, "pyr", dict, where, pre)
    yp = pre + "pyr."
    edges = _arr(yr, "edges_m", where, yp)
    if edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise _err(where, yp + "edges_m", "must be increasing, at least 2 values")
    nb = edges.size - 1
    tabs = {k: _arr(yr, k, where, yp, nb) for k in ("injected", "detected", "pd", "low", "high")}
    for k in ("pd", "low", "high"):
        if np.any(tabs[k] < 0) or np.any(tabs[k] > 1):
            raise _err(where, yp + k, "must be in [0, 1]")
    if np.any(tabs["detected"] > tabs["injected"]) or np.any(tabs["detected"] < 0):
        raise _err(where, yp + "detected", "must be in [0, injected]")
    for k in ("injected", "detected"):  # counts: whole numbers an int64 holds (found by fuzzing)
        if np.any(tabs[k] > 2.0**53) or np.any(tabs[k] != np.round(tabs[k])):
            raise _err(where, yp + k, "must be whole counts below 2^53")
    try:
        conf = ConfidenceCurve(tau=tau, gamma=g, confidence=c,
                               isotonic_adjusted=bool(cr.get("isotonic_adjusted", False)),
                               max_adjustment=float(cr.get("max_adjustment", 0.0)),
                               n_target_above=int(cr.get("n_target_above", 0)),
                               n_nontarget_above=int(cr.get("n_nontarget_above", 0)))
    except (TypeError, ValueError, OverflowError) as exc:  # e.g. a count given as a list or as 1e400
        raise _err(where, pre + "confidence", f"optional counts and flags: {exc}") from None
    pyr = PdCurve(tau=tau, edges_m=edges, injected=tabs["injected"].astype(np.int64),
                  detected=tabs["detected"].astype(np.int64), pd=tabs["pd"], low=tabs["low"], high=tabs["high"])
    pat = raw.get("pd_at_tau")
    if pat is not None and (isinstance(pat, bool) or not isinstance(pat, (int, float))):
        raise _err(where, pre + "pd_at_tau", f"should be a number or null, got {type(pat).__name__}")
    return DetectorPerformance(tau=tau, confidence=conf, pyr=pyr, tau_source=str(raw.get("tau_source", "dobeck")),
                               pd_at_tau=float("nan") if pat is None else float(pat))
