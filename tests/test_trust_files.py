"""Self-describing files: every dataset of front.h5 carries units and description; a damaged attribute is
reported with the file and the attribute named."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import read_front

from trust_helpers import assert_refused, synthetic_front


def test_every_front_dataset_has_units_and_description(tmp_path):
    path = synthetic_front(tmp_path / "front.h5")
    seen = []

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            seen.append(name)
            assert "units" in obj.attrs and "description" in obj.attrs, name
            assert str(obj.attrs["description"]).strip(), name

    with h5py.File(path, "r") as f:
        f.visititems(visit)
        assert "log10" in f["population/X"].attrs["description"]
        assert "constraint" in f["population/G"].attrs["description"]
        assert "f_chat, f_rmse" in f["population/F"].attrs["description"]
        assert f["front/F"].attrs["description"].startswith("front members only")
        assert f.attrs["model_hash"] and len(str(f.attrs["model_hash"])) == 64
    assert {"population/X", "front/X", "table2/F", "history/hv", "draws/phase", "params"} <= set(seen)


@pytest.mark.parametrize("attr, value", [
    ("versions", "not json {"), ("versions", "[1, 2]"), ("seed", "three"), ("n_gen", 1.5),
    ("reference_point", np.array([1.0, 2.0, 3.0, 4.0, 5.0])), ("model_changes", "{}"), ("status", None),
])
def test_damaged_attributes_are_named(tmp_path, capsys, attr, value):
    path = synthetic_front(tmp_path / "front.h5")
    with h5py.File(path, "r+") as f:
        if value is None:
            del f.attrs[attr]
        else:
            f.attrs[attr] = value
    with pytest.raises(ck.CheckpointError, match=f"{path}: damaged arvcas front file \\(attribute '{attr}'"):
        read_front(path)
    assert_refused(["front", "export", path, "--format", "json"], capsys, tmp_path, f"attribute '{attr}'")
