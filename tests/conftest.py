"""Test-wide settings: hypothesis runs derandomised, so every run draws the same examples."""

from hypothesis import settings

settings.register_profile("markergraph", derandomize=True, database=None, print_blob=True)
settings.load_profile("markergraph")
