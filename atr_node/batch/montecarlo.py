"""Calibration Monte Carlo on the batch engine (SPEC section 5, issue 11).

The responses of each calibration image are one task: ``collect_image`` with the random
stream ``(seed, k)`` of image k, exactly as :func:`atr_node.calibration.collect_responses`
draws them in one process. The pooled responses are therefore identical, array for array,
whatever the number of workers, and the model estimated from them is the same.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence


from ..calibration.responses import (CalibrationImage, Responses, _room_for_targets, _settings_provenance,
                                     collect_one)
from ..errors import AtrError
from .engine import Engine, Progress, TaskOutcome


def image_responses(image: CalibrationImage, settings: Any, iterations: int, targets_per_image: int, seed: int,
                    k: int, pooled: int) -> Responses:
    """Responses of image ``k`` of ``pooled`` usable images (one task), as ``collect_parts``
    collects it (:func:`~atr_node.calibration.responses.collect_one`)."""
    return collect_one(image, k, pooled, settings=settings, iterations=iterations,
                       targets_per_image=targets_per_image, seed=seed)


def run_calibration(images: Sequence[CalibrationImage], settings: Any, engine: Engine, *, iterations: int,
                    targets_per_image: int, seed: int,
                    progress: Progress | None = None) -> tuple[Responses, list[TaskOutcome]]:
    """Pooled responses of every usable image (as ``collect_responses``) and the task outcomes.

    Raises
    ------
    AtrError
        No usable image, or a task that failed after its retries (the pool would be biased).
    """
    usable = [im for im in images if _room_for_targets(im, settings)]
    skipped = [im.name for im in images if not _room_for_targets(im, settings)]
    if not usable:
        raise AtrError(f"calibration: no image has room for a target and its context window ({len(images)} image(s))")
    items = [(im.name, (im, settings, iterations, targets_per_image, seed, k, len(usable)))
             for k, im in enumerate(usable)]
    outcomes = engine.map(image_responses, items, progress=progress)
    bad = [o for o in outcomes if not o.ok]
    if bad:
        raise AtrError("calibration Monte Carlo: " + "; ".join(f"{o.name} failed {o.attempts} times: {o.errors[-1]}"
                                                                 for o in bad))
    parts = [o.result for o in outcomes]
    out = Responses.concat(parts)
    prov = dict(out.provenance)
    prov.update({"images": [n for p in parts for n in p.provenance["images"]], "iterations": iterations,
                 "targets_per_image": targets_per_image, "seed": seed, "skipped_images": skipped,
                 "engine": engine.describe()})
    prov.update(_settings_provenance(settings))
    prov["population"]["n_nominal"] = int(out.nominal.sum())
    return dataclasses.replace(out, provenance=prov), outcomes
