"""Shared test fixtures: repository paths and a quiet open3d."""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
# Real photographs handed to the project (never copied into the repository):
# ../shared/data/real beside
# the checkout, or wherever PHOTOSURF_REAL_DATA points.
REAL_DATA = Path(os.environ.get("PHOTOSURF_REAL_DATA",
                               ROOT.parent / "shared" / "data" / "real"))


@pytest.fixture(scope="session")
def fixtures_dir() -> Path:
    return FIXTURES


@pytest.fixture(scope="session")
def real_data_dir() -> Path:
    """The real data folder (temple_sparse_ring/, graffiti/); skipped if it is absent."""
    if not (REAL_DATA / "README.md").is_file():
        pytest.skip(f"real data not found at {REAL_DATA} (set PHOTOSURF_REAL_DATA)")
    return REAL_DATA


@pytest.fixture(autouse=True, scope="session")
def _quiet_open3d():
    try:
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    except ImportError:
        pass
    yield
