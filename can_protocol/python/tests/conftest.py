from __future__ import annotations

import pytest
from cantools.database import Database

import alacs_can


@pytest.fixture(scope="session")
def db() -> Database:
    return alacs_can.load_database(alacs_can.DEFAULT_NODE_ID)
