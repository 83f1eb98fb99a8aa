"""Batch runs on Dask (issue 11): many recordings to one evidence grid, calibration Monte Carlo.

- :mod:`.engine`: where tasks run (local Dask cluster, a scheduler address, or serial), with
  retries, progress and failure reports.
- :mod:`.grids`: recording -> evidence deltas (the node's pipeline), exact reduction, contacts.
- :mod:`.montecarlo`: calibration responses per image on the engine, pooled.
"""

from .engine import Engine, TaskOutcome, engine
from .grids import BatchResult, RecordingDeltas, recording_deltas, reduce_recordings, run_recordings
from .montecarlo import image_responses, run_calibration

__all__ = ["BatchResult", "Engine", "RecordingDeltas", "TaskOutcome", "engine", "image_responses",
           "recording_deltas", "reduce_recordings", "run_calibration", "run_recordings"]
