"""Fixtures of the detector tests."""

from __future__ import annotations

import pytest

from atr_node.config import DetectorSettings, TemplateSettings
from tests.detectors.scenes import SMALL


@pytest.fixture
def template() -> TemplateSettings:
    return SMALL


@pytest.fixture
def settings() -> DetectorSettings:
    return DetectorSettings()

