"""Bounded by construction: graph walks detect loops and missing links, XML is parsed without a DTD (no
entity is ever expanded), every loop whose count a user controls is bounded before any work (FMU RK4
steps per fmi2DoStep, the memory of Run.many / Run.batch)."""

from __future__ import annotations

import numpy as np
import pytest

from arvcas.system.params import ParamsError
from arvcas.system import load_system

from trust_helpers import assert_refused, bounded

import urdf_arms as ua


LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE robot [\n <!ENTITY a "aaaaaaaaaa">\n'
          + "".join(f' <!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">\n' for i in range(9))
          + ']>\n<robot name="&j;"><link name="base_link"/></robot>\n')


@pytest.mark.parametrize("fault, message", [
    ("loop", "link 'tool_link' is not below 'base_link'"),  # the walk goes down from the base: a loop is never reached
    ("no_parent", "joint 'joint2' has no <parent> or <child>"),
    ("no_child", "joint 'joint1' has no <parent> or <child>"),
    ("two_parents", "link 'link2' is reached twice (joint 'joint2'): not a tree"),
    ("laughs", "has a document type declaration"),
    ("external", "has a document type declaration"),
])
def test_urdf_graph_and_xml_faults_refused_in_one_line(tmp_path, fault, message):
    arm = ua.random_arm(np.random.default_rng(7), 2)
    path = arm.write(tmp_path)
    urdf = tmp_path / arm.urdf_name
    text = urdf.read_text()
    if fault == "loop":  # link1 <- joint1 <- link2 <- joint2 <- link1: the walk up from the tool never ends
        text = text.replace('<parent link="base_link"/>\n    <child link="link1"/>',
                            '<parent link="link2"/>\n    <child link="link1"/>')
    elif fault == "no_parent":
        text = text.replace('<parent link="link1"/>\n    <child link="link2"/>', '<child link="link2"/>')
    elif fault == "no_child":
        text = text.replace('<parent link="base_link"/>\n    <child link="link1"/>', '<parent link="base_link"/>')
    elif fault == "two_parents":
        text = text.replace("</robot>", '  <joint name="extra" type="fixed"><parent link="base_link"/>'
                                        '<child link="link2"/></joint>\n</robot>')
    elif fault == "laughs":  # a billion laughs: 10^10 characters if expanded
        text = LAUGHS
    elif fault == "external":
        text = text.replace('<?xml version="1.0"?>\n', '<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY x SYSTEM '
                                                        '"file:///etc/passwd">]>\n').replace('name="link1"', 'name="&x;"')
    assert text != urdf.read_text()
    urdf.write_text(text)
    e = bounded(lambda: load_system(path), timeout=60)
    assert isinstance(e, ParamsError), repr(e)
    assert message in str(e) and "\n" not in str(e), str(e)
    assert str(e).startswith(str(urdf)), str(e)


def test_urdf_loop_refused_by_the_command_line(tmp_path, capsys):
    arm = ua.random_arm(np.random.default_rng(8), 3)
    path = arm.write(tmp_path)
    urdf = tmp_path / arm.urdf_name
    urdf.write_text(urdf.read_text().replace('<parent link="link2"/>\n    <child link="link3"/>',
                                             '<parent link="link3"/>\n    <child link="link3"/>'))
    assert_refused(["export-c", "--system", path, tmp_path / "out"], capsys, tmp_path, "is not below 'base_link'",
                   timeout=60)


def test_many_bounds_its_memory_before_allocating(monkeypatch):
    """Run.many with a million seeds built every noise block (96 GB) before its bound was checked: now the
    count and the memory of the draws are checked first (here on a 64 MiB machine: 1,000 draws need 90 MiB)."""
    import arvcas
    from arvcas.build import calls
    from arvcas.sim.run import SimulationError

    run = arvcas.Run("agsta").compile()
    g = run.default_gains()
    monkeypatch.setattr(calls, "total_memory", lambda: 64 * 2**20)
    for seeds, message in ((range(1000), "many: 1000 runs: would need about"),
                           (range(10**12), "seeds: 1000000000000 values, more than the 10000000 allowed")):
        e = bounded(lambda: run.many(g, seeds=seeds), timeout=60)
        assert isinstance(e, SimulationError) and message in str(e), repr(e)


def test_batch_bounds_its_memory_before_compiling_or_allocating(monkeypatch):
    """Run.batch (and Run.outputs, its every-output sibling) estimate the memory of n gain sets' runs (the
    outputs and their copies, the accumulators' rows, the gains as float64) and refuse, in one line naming
    ``gains``, before the run is compiled or any output allocated (here on a 64 MiB machine: 32 MiB allowed)."""
    import arvcas
    from arvcas.build import calls
    from arvcas.metrics import objectives as O
    from arvcas.sim.run import _OUT_BYTES, SimulationError

    plain = arvcas.Run("agsta").compile()  # compiles nothing yet: the C is built on the first evaluation
    acc = arvcas.Run("agsta", accumulators=O.accumulators_of([O.get("peak_thrust")])).compile()
    monkeypatch.setattr(calls, "total_memory", lambda: 64 * 2**20)

    def never(*_a, **_k):
        raise AssertionError("compiled or evaluated before the memory bound")

    for run in (plain, acc):
        monkeypatch.setattr(run, "function", never)
        monkeypatch.setattr(run, "lockstep", never)
    monkeypatch.setattr(calls, "call_named", never)
    g = plain.default_gains()
    per_run = _OUT_BYTES + 8 * g.size  # the outputs and their copies, the gains as float64
    assert [a.width for a in acc.accumulators] == ["thrusters", "thrusters"]  # peak_thrust: forward, reverse
    acc_rows = 2 * acc.params.structure.n_thrusters  # 12 with Haidou-1's 6 thrust units
    # 80,000 runs: their outputs alone (80,000 x 320 B = 24 MiB) fit in 32 MiB, with the gains they do not;
    # 42,000 runs fit without accumulators, not with their 12 rows (and copies)
    assert 80_000 * _OUT_BYTES < 32 * 2**20 < 80_000 * per_run
    assert 42_000 * per_run < 32 * 2**20 < 42_000 * (per_run + 16 * acc_rows)
    G = np.tile(g, (80_000, 1))
    for run, n, method in ((plain, 80_000, "batch"), (plain, 80_000, "outputs"), (acc, 42_000, "batch"),
                           (acc, 42_000, "outputs")):
        e = bounded(lambda: getattr(run, method)(G[:n]), timeout=60)
        assert isinstance(e, SimulationError), repr(e)
        msg = str(e)
        assert msg.startswith(f"gains: {n} gain sets ({method}: one run each): would need about ") and \
            "\n" not in msg, msg
    # below the bound the same calls go on to compile (here: the stub that stands for it)
    for run, method in ((plain, "batch"), (plain, "outputs"), (acc, "batch")):
        e = bounded(lambda: getattr(run, method)(G[:1000]), timeout=60)
        assert isinstance(e, AssertionError) and "before the memory bound" in str(e), repr(e)


def test_xacro_files_and_their_includes_are_read_without_a_dtd(tmp_path):
    """xacro (``arvcas import-system uuv``) parses the file and every include through the same refusal."""
    pytest.importorskip("xacro")
    from arvcas.system import uuv

    inc = tmp_path / "inc.xacro"
    inc.write_text(LAUGHS.replace('<robot name="&j;">', '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" '
                                                       'name="&j;">'))
    top = tmp_path / "top.xacro"
    top.write_text('<?xml version="1.0"?>\n<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="r">\n'
                   '  <xacro:include filename="inc.xacro"/>\n</robot>\n')
    for path in (inc, top):
        e = bounded(lambda: uuv.expand(path, {}, {}, error=ParamsError), timeout=60)
        assert isinstance(e, ParamsError) and "has a document type declaration" in str(e), repr(e)
