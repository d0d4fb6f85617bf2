"""Headless Chromium for the browser test."""

from __future__ import annotations

import pytest

from tests.components import INSTALL, chromium_binary, missing


@pytest.fixture(scope="session")
def chromium():
    binary = chromium_binary()
    if binary is None:
        missing(f"Chromium not found; {INSTALL}")
    return binary
