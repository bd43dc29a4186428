"""Fixtures of the rig tests."""
import pytest


@pytest.fixture
def new_run_engine():
    """Make bluesky RunEngines for a test (``new_run_engine()``); each is stopped, its event-loop
    thread joined, when the test ends."""
    from bluesky import RunEngine

    from rig.run import stop_run_engine

    made = []

    def make():
        made.append(RunEngine({}, context_managers=[]))
        return made[-1]

    yield make
    for engine in made:
        stop_run_engine(engine)
