"""Hypothesis draws the same examples on every run, so a test run (and CI) is reproducible;
``HYPOTHESIS_PROFILE=explore pytest`` draws new ones, to search further."""

import os

from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))
