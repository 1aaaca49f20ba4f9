"""Fixtures for the run-log tests: one synthetic 500-cycle run, written once per session."""
import pytest

from . import synthetic


@pytest.fixture(scope="session")
def run_records():
    return synthetic.records(500)


@pytest.fixture(scope="session")
def run_bag(tmp_path_factory, run_records):
    path = tmp_path_factory.mktemp("logs") / "circle_run"
    synthetic.write(path, run_records)
    return path
