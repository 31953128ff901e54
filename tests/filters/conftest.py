"""Fixtures of the song2016 filter tests (drives from :mod:`song2016_drives`)."""

import pytest
from song2016_drives import make_drive


@pytest.fixture(scope="session")
def small_drive():
    return make_drive()


@pytest.fixture(scope="session")
def noiseless_drive():
    return make_drive(noise=False)
