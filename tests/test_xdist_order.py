"""The heavy-files-first order of README's `-n 2 --dist loadfile` run (tests/conftest.py) names
files that exist: a renamed or split file must be renamed in ``HEAVY_FILES`` too, or it silently
goes back to xdist's by-test-count order."""

from __future__ import annotations

from pathlib import Path

from conftest import HEAVY_FILES


def test_every_heavy_file_listed_is_a_test_file_here():
    here = Path(__file__).parent
    missing = [f for f in HEAVY_FILES if not (here / f).is_file()]
    assert not missing, missing
    assert all(f.startswith("test_") and f.endswith(".py") for f in HEAVY_FILES)
