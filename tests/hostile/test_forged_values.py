"""A checkpoint whose checksum was recomputed around impossible values is refused."""
from __future__ import annotations

import json
import re

import pytest

from straylight.checkpoints import PointStore, point_checksum


@pytest.mark.parametrize("values, message", [
    ({"values": {"pst": -1.0}}, "values.pst = -1.0 is impossible"),
    ({"values": {"pst": 1e-3}, "rays": -5}, "rays = -5 is impossible"),
    ({"values": {"dhr": 3.14}}, "values.dhr = 3.14 is impossible (must be in [0.0, 1.0])"),
])
def test_forged_checkpoint_values_refused(tmp_path, values, message):
    store = PointStore(tmp_path / "pts", {"x": 1})
    doc = {"index": 0, "run_sha256": store.digest, "values": values,
           "sha256": point_checksum(store.digest, 0, values)}  # a forger recomputes the checksum
    (tmp_path / "pts" / "point_000000.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=re.escape(message)):
        PointStore(tmp_path / "pts", {"x": 1}, resume=True).get(0)


def test_possible_values_pass(tmp_path):
    store = PointStore(tmp_path / "pts", {"x": 1})
    store.put(0, {"values": {"pst": 2e-6, "pst_stderr": 1e-8}, "rays": 1000, "seconds": 0.5})
    assert PointStore(tmp_path / "pts", {"x": 1}, resume=True).get(0)["rays"] == 1000
