"""Hypothesis draws the same examples on every run, so a test run (and CI) is reproducible;
``HYPOTHESIS_PROFILE=explore pytest`` draws new ones, to search further."""

import os

import pytest
from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_test_folder(tmp_path_factory):
    """SB3 models made without a log folder would each leave an empty folder in /tmp."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))
