"""The ArduSub study on the identified Hinsdale vehicle (studies/ardusub_identified.toml,
results/ardusub/identified/): its system file is what studies/systems/hinsdale_t200.py writes from the identified
file and the Heavy's T200 dynamics (so neither can change without it), ArduSub's motors map onto its eight
thrusters with the right signs (tests/test_ardusub.py::test_motor_mapping_on_the_bluerov2_heavy), and a front
of a system file outside arvcas records that file relative to itself
(the committed front replays from any checkout; the replay itself is tests/test_committed_fronts.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py

import arvcas
from arvcas.tuning import checkpoint as ck
from script_helpers import load_script

ROOT = Path(__file__).resolve().parents[1]
SYSTEM = ROOT / "studies" / "systems" / "hinsdale_bluerov2_alpha5_identified_t200.toml"
IDENTIFIED = ROOT / "results" / "validation" / "hinsdale_bluerov2_alpha5_identified.toml"


def _generator():
    return load_script(SYSTEM.parent / "hinsdale_t200.py")


def test_system_file_is_the_generators_output():
    assert SYSTEM.read_text(encoding="utf-8") == _generator().render(), "re-run studies/systems/hinsdale_t200.py"


def test_system_is_the_identified_one_with_t200_dynamics():
    """Every parameter of the identified file is unchanged; the added ones are the thrusters' map and lags."""
    ident, t200 = arvcas.load_system(IDENTIFIED).params, arvcas.load_system(SYSTEM).params
    a = dict(zip(ident.names(), ident.vector()))
    b = dict(zip(t200.names(), t200.vector()))
    assert set(a) < set(b)
    assert all(a[n] == b[n] for n in a), [n for n in a if a[n] != b[n]]
    extra = set(b) - set(a)
    assert {f"thrusters.T{i}.time_constant" for i in range(1, 9)} <= extra
    assert all(n.startswith("thrusters.") for n in extra), extra
    assert t200.instantaneous().vector().tolist() == ident.vector().tolist()


def test_front_records_a_system_file_relative_to_itself(tmp_path):
    """A system file outside arvcas is stored relative to the front's folder and read back as an absolute path:
    the front and its system file can move together (a clone elsewhere) and still name it."""
    from trust_helpers import synthetic_front

    a = tmp_path / "a"
    (a / "systems").mkdir(parents=True)
    (a / "out").mkdir()
    shutil.copy(SYSTEM, a / "systems" / SYSTEM.name)
    path = synthetic_front(a / "out" / "front.h5")
    c = ck.read_checkpoint(path)
    c.system = str(a / "systems" / SYSTEM.name)
    ck.write_checkpoint(c, path)
    with h5py.File(path, "r") as f:
        assert f.attrs["system"] == f"../systems/{SYSTEM.name}"
    shutil.move(a, tmp_path / "b")
    moved = ck.read_checkpoint(tmp_path / "b" / "out" / "front.h5")
    assert moved.system == str((tmp_path / "b" / "systems" / SYSTEM.name).resolve())
    assert arvcas.load_system(moved.system).params.structure.name == "hinsdale_bluerov2_alpha5_identified_t200"
    # a shipped name is stored as it is
    c.system = "bluerov2_heavy"
    ck.write_checkpoint(c, tmp_path / "b" / "out" / "front.h5")
    assert ck.read_checkpoint(tmp_path / "b" / "out" / "front.h5").system == "bluerov2_heavy"
