"""straylight.cli.long_lived: no automatic collection inside the block, its objects frozen after it
(once per stage and process), the collector's state restored even when the block raises."""
import gc

import pytest

from straylight.cli.long_lived import long_lived_objects


@pytest.fixture(autouse=True)
def _unfrozen():
    yield
    gc.unfreeze()  # give the test process its objects back to the collector


def test_collections_off_in_the_block_and_its_objects_frozen_after():
    gc.unfreeze()
    assert gc.isenabled()
    with long_lived_objects("test-stage-a"):
        assert not gc.isenabled()
        made = [[] for _ in range(1000)]
    assert gc.isenabled()
    assert gc.get_freeze_count() >= len(made)
    young = {id(x) for x in gc.get_objects(generation=0)}
    assert not any(id(x) in young for x in made)  # frozen: in no generation the collector scans


def test_each_stage_freezes_once_per_process():
    with long_lived_objects("test-stage-b"):
        pass
    gc.unfreeze()
    with long_lived_objects("test-stage-b"):  # the second time: collections stay on, nothing frozen
        assert gc.isenabled()
        made = [[] for _ in range(10)]
    assert gc.get_freeze_count() == 0 and gc.is_tracked(made[0])


def test_the_collector_is_restored_when_the_block_raises_and_a_disabled_one_stays_disabled():
    with pytest.raises(RuntimeError), long_lived_objects("test-stage-c"):
        raise RuntimeError("boom")
    assert gc.isenabled()
    gc.disable()
    try:
        with long_lived_objects("test-stage-d"):
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()
