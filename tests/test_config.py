"""arvcas.system.config: one strict loader for parameter, scenario and study files.

The packaged files load to the same SI numbers as their raw TOML values times unit factors written
out here independently; every fault is one line naming the file and the key; units are checked
against each field's dimension (element by element for vectors); sizes are bounded before any work.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from arvcas.system import config, params as ap
from arvcas.system.config import Choices, Count, Equals, Invalid, ge, gt, le, quantity, setting
from arvcas.sim import scenario
from arvcas.sim.scenario import ScenarioError, default_scenario_path, load_scenario, loads_scenario
from arvcas.tuning.study import StudyError, loads_study

# independent of arvcas.system.config.UNITS: the only non-SI units the packaged files use
_FACTOR = {"mm": 1e-3, "deg": math.pi / 180.0}


def _factors(unit: str, n: int) -> list[float]:
    parts = [u.strip() for u in unit.split(",")]
    if len(parts) == 1:
        parts = parts * n
    elif len(parts) == 2 and n == 6:
        parts = [parts[0]] * 3 + [parts[1]] * 3
    assert len(parts) == n
    return [_FACTOR.get(u, 1.0) for u in parts]


def _entries(table: dict, prefix: str = ""):
    for k, v in table.items():
        if isinstance(v, dict) and "value" not in v:
            yield from _entries(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


# --- the packaged files: bit for bit ----------------------------------------------------------------


def test_params_vector_is_raw_values_times_factors(params):
    doc = tomllib.loads(ap.default_path().read_text(encoding="utf-8"))
    assert doc.pop("system") == {"name": "haidou1", "description": params.description}  # not numbers
    assert doc.pop("defaults") == {"scenario": "scenario.toml", "gains": "gains.toml"}
    raw = dict(_entries(doc))
    assert list(raw) == params.names()
    expect = np.array([float(e["value"]) * _factors(e["unit"], 1)[0] for e in raw.values()])
    np.testing.assert_array_equal(params.vector(), expect)  # exact, not approximate
    assert [params.unit(n) for n in raw] == [e["unit"] for e in raw.values()]
    assert [params.source(n) for n in raw] == [e["source"] for e in raw.values()]


def test_scenario_fields_are_raw_values_times_factors():
    cfg = load_scenario()
    raw = dict(_entries(tomllib.loads(default_scenario_path().read_text(encoding="utf-8"))))
    names = [f.name for f in dataclasses.fields(cfg) if f.name not in ("text", "path")]
    assert cfg.arm_waypoint is None and cfg.payload_event is None  # the paper's form of arm motion
    # the optional keys the paper's file leaves out: waypoints, events, per-axis sensors, current, tether
    assert [k.replace(".", "_") for k in raw] == [n for n in names if getattr(cfg, n) is not None]
    for key, e in raw.items():
        got = getattr(cfg, key.replace(".", "_"))
        if isinstance(e["value"], list):
            fac = _factors(e["unit"], len(e["value"]))
            assert got == tuple(float(x) * f for x, f in zip(e["value"], fac)), key
        else:
            assert got == float(e["value"]) * _factors(e["unit"], 1)[0], key
    # the effective config (SI, unit "SI") gives the same values back, bit for bit
    back = loads_scenario(cfg.to_toml())
    assert dataclasses.replace(back, text="", path="") == dataclasses.replace(cfg, text="", path="")


def test_degree_conversion_matches_math_radians():
    """Study phases were math.radians(x): the UNITS factor gives the same doubles."""
    rng = np.random.default_rng(0)
    for x in [0.0, 36.0, 120.0, 90.0, 45.0, -72.0, *rng.uniform(-720, 720, 200)]:
        assert float(x) * config.UNITS["deg"][1] == math.radians(float(x))


def test_units_table():
    for u, (dim, fac) in config.UNITS.items():
        assert dim in config.DIMENSIONS and fac > 0, u
    assert config.UNITS["deg"][1] == math.pi / 180 and config.UNITS["mm"] == ("length", 1e-3)
    assert config.UNITS["deg^2"][1] == (math.pi / 180) ** 2
    assert config.si_unit("angle") == "rad" and config.si_unit("length or angle") == "m or rad"


# --- scenario units (the refused unit edits: BAD_EDITS in test_scenario.py) -------------------------

TEXT = default_scenario_path().read_text(encoding="utf-8")

def test_scenario_other_units_convert():
    """Allowed non-SI units convert: h in ms, the grasp pose per element, A_min in SI."""
    text = (TEXT.replace('h = { value = 0.1, unit = "s"', 'h = { value = 100.0, unit = "ms"')
            .replace('eta0 = { value = [0.02, 0.02, 0.03, 2.0, 2.0, 2.0], unit = "m,m,m,deg,deg,deg"',
                     'eta0 = { value = [20.0, 20.0, 30.0, 2.0, 2.0, 2.0], unit = "mm,mm,mm,deg,deg,deg"')
            .replace('unit = "m or rad"', 'unit = "SI"'))
    a, b = load_scenario(), loads_scenario(text, "s.toml")
    assert b.time_h == 0.1 and b.atd_A_min == a.atd_A_min
    np.testing.assert_allclose(b.initial_eta0, a.initial_eta0, rtol=1e-15)


# --- sizes: refused before any work ------------------------------------------------------------------


@pytest.mark.parametrize("old,new,fragment", [
    ("duration = { value = 100.0,", "duration = { value = 1e9,", "time.duration: value must be <= 1e+06 s, got 1000000000.0"),
    ("h_plant = { value = 0.05,", "h_plant = { value = 1e-9,", "time.h_plant: value must be >= 1e-06 s, got 1e-09"),
    ("h_plant = { value = 0.05,", "h_plant = { value = 0.00001,", "time.h: h / h_plant = 10000 plant steps per sample, at most 1000"),
])
def test_scenario_sizes_bounded(tmp_path, old, new, fragment):
    p = tmp_path / "s.toml"
    p.write_text(TEXT.replace(old, new))
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    assert time.perf_counter() - t0 < 2.0  # an estimate, not an allocation
    msg = str(ei.value)
    assert "\n" not in msg and str(p) in msg and fragment in msg, msg


def test_time_table_estimate_is_the_table():
    cfg = dataclasses.replace(load_scenario(), time_duration=3.0)
    from arvcas.sim import schedule

    assert schedule.table_bytes(load_scenario()) == pytest.approx(8.62e6, rel=0.01)  # 100 s at h_plant = 0.05 s
    tab = schedule.table(cfg, ap.load().vector())
    assert schedule.table_bytes(cfg) == tab.time.nbytes + tab.arm.nbytes


def _scenario_text(system: str) -> str:
    from arvcas.system import resolve

    return Path(resolve(system).params.default("scenario")).read_text(encoding="utf-8")


@pytest.mark.parametrize("system,old,duration,size", [
    ("haidou1", "duration = { value = 100.0,", 30000.0, "2.58 GB"),
    ("bluerov2", "duration = { value = 60.0,", 20000.0, "3.6 GB"),
])
def test_time_table_too_large_refused_before_compile(tmp_path, monkeypatch, system, old, duration, size):
    """A scenario whose time table for the run's system exceeds the cap is refused by Run.compile, one line
    naming the file and time.duration, before anything is built."""
    from arvcas.build import codegen
    from arvcas.sim.run import Run

    monkeypatch.setattr(codegen, "build_described", lambda *a, **k: pytest.fail("built before the check"))
    p = tmp_path / "s.toml"
    text = _scenario_text(system)
    assert old in text
    p.write_text(text.replace(old, f"duration = {{ value = {duration},"))
    with pytest.raises(ScenarioError) as ei:
        Run("proposed", str(p), system).compile()
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"{p}: time.duration: the run's time table (") and size in msg, msg


def test_time_table_check_uses_the_systems_record():
    """The estimate is the system's record size: 8000 s of the BlueROV2's scenario (107 doubles a record, no
    arm) is 1.44 GB and passes; the same with Haidou-1's record (215 doubles, six joints) would be refused."""
    from arvcas.sim import schedule
    from arvcas.system import resolve

    bluerov2, haidou1 = resolve("bluerov2").params.layout, resolve("haidou1").params.layout
    cfg = dataclasses.replace(load_scenario(resolve("bluerov2").params.default("scenario")), time_duration=8000.0)
    assert (schedule.records(bluerov2).size, schedule.records(haidou1).size) == (107, 215)
    assert schedule.table_bytes(cfg, bluerov2) == scenario.n_samples(cfg) * 21 * 107 * 8
    schedule.check_table_memory(cfg, bluerov2)
    with pytest.raises(ScenarioError, match="time.duration: the run's time table"):
        schedule.check_table_memory(cfg, haidou1)


def test_with_h_checks_the_field_rule():
    cfg = load_scenario()
    with pytest.raises(ScenarioError, match=r"^ScenarioConfig.with_h: time.h: value must be > 0, got 0.0$"):
        cfg.with_h(0.0)
    with pytest.raises(ScenarioError, match=r"ScenarioConfig.with_h: time.h: value must be a number"):
        cfg.with_h("0.1")
    assert cfg.with_h(0.05).substeps == 1 and cfg.with_h(0.2).substeps == 4  # the scenario's plant step where it divides h
    c = cfg.with_h(0.02)  # it does not: the largest step below it that does
    assert c.time_h_plant == pytest.approx(0.02) and c.substeps == 1
    c = cfg.with_h(0.12)
    assert c.time_h_plant == pytest.approx(0.04) and c.substeps == 3
    assert dataclasses.replace(cfg, time_h_plant=0.01).with_h(0.05).substeps == 5


STUDY = """\
[study]
name = "s"
controllers = "agsta"
seed = 1
[variables]
scale = 2.0
[algorithm]
population = 8
[termination]
max_generations = 3
[objectives]
names = ["chat", "rmse"]
reference_point = [300.0, 4.0]
[evaluation]
{draws}
"""


@pytest.mark.parametrize("edit,fragment", [
    (("population = 8", "population = 1000000"), "algorithm.population: must be <= 100000, got 1000000"),
    (("population = 8", "population = 8\noffspring = 0"), "algorithm.offspring: must be >= 1, got 0"),
    (("max_generations = 3", "max_generations = 100000000"), "termination.max_generations: must be <= 1e+06"),
    (("max_generations = 3", "max_evaluations = 100000000000"), "termination.max_evaluations: must be <= 1e+10"),
    (("population = 8", "population = 100000\noffspring = 100000"),
     "algorithm.population: the per-draw metrics of one generation (100 draws x 200000 candidates) would need about 2.24 GB"),
    (("[evaluation]", "[engine]\nthreads = 1000000\n[evaluation]"), "engine.threads: must be <= 4096"),
])
def test_study_sizes_bounded(edit, fragment):
    draws = "\n".join(f"[[evaluation.draws]]\nnoise_seed = {i}" for i in range(100))
    text = STUDY.format(draws=draws).replace(*edit)
    t0 = time.perf_counter()
    with pytest.raises(StudyError) as ei:
        loads_study(text, "big.toml")
    assert time.perf_counter() - t0 < 5.0
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("big.toml: ") and fragment in msg, msg


def test_study_phase_in_degrees_is_converted():
    text = STUDY.format(draws="[[evaluation.draws]]\nnoise_seed = 0\nphase_deg = [36, 120, 90, 0, 45, 90]")
    d = loads_study(text, "s.toml").draws[0]
    assert d.phase == tuple(math.radians(x) for x in (36, 120, 90, 0, 45, 90))
    with pytest.raises(StudyError, match=r"unknown key 'evaluation.draws.phase' \(in evaluation.draws\[1\]\) "
                                         r"\(did you mean 'evaluation.draws.phase_deg'\?\)"):
        loads_study(text.replace("phase_deg", "phase"), "s.toml")


# --- the loader on a schema of its own ---------------------------------------------------------------


@dataclass(frozen=True)
class _Item:
    n: int = setting(ge(0))
    w: float = quantity("angle", unit="deg", default=0.0)


@dataclass(frozen=True)
class _Inner:
    length: float = quantity("length", gt(0), le(10))
    mode: str = setting(Choices(("fast", "slow"), "mode"), default="fast")
    fixed: tuple[str, ...] = setting(Equals(("a", "b")), default=("a", "b"))

    def _config_check(self, given):
        if self.mode == "slow" and "length" in given and self.length > 5:
            raise Invalid("length", "must be <= 5 in slow mode")


@dataclass(frozen=True)
class _Root:
    inner: _Inner = setting()
    items: tuple[_Item, ...] = setting(Count(1, 3))
    flag: bool = setting(default=False)
    pair: tuple[float, float] = quantity("1", default=(1.0, 2.0))
    opt: int | None = setting(default=None)


def _load(text: str):
    return config.load_text(_Root, text, "f.toml", ValueError).value


@pytest.mark.parametrize("text,fragment", [
    ("[inner]\nlength = 1\n[[items]]\nn = 1\n[extra]\n", "unknown section 'extra' (allowed: inner)"),
    ("[inner]\nlenght = 1\n[[items]]\nn = 1\n", "unknown key 'inner.lenght' (did you mean 'inner.length'?)"),
    ("[inner]\nmode = 'fast'\n[[items]]\nn = 1\n", "missing key 'inner.length'"),
    ("[[items]]\nn = 1\n", "missing section [inner]"),
    ("[inner]\nlength = 1\n", "missing key 'items'"),
    ("inner = 3\n[[items]]\nn = 1\n", "'inner' must be a table ([inner]), got integer 3"),
    ("[inner]\nlength = 0\n[[items]]\nn = 1\n", "f.toml: inner.length: must be > 0, got 0.0"),
    ("[inner]\nlength = 11\n[[items]]\nn = 1\n", "inner.length: must be <= 10 m, got 11.0"),
    ("[inner]\nlength = true\n[[items]]\nn = 1\n", "inner.length: must be a number, got boolean True"),
    ("[inner]\nlength = 1\nmode = 'fats'\n[[items]]\nn = 1\n",
     "inner.mode: unknown mode 'fats' (did you mean 'fast'?) (allowed: fast, slow)"),
    ("[inner]\nlength = 1\nfixed = ['b', 'a']\n[[items]]\nn = 1\n", "inner.fixed: must be ['a', 'b'], got ['b', 'a']"),
    ("[inner]\nlength = 6\nmode = 'slow'\n[[items]]\nn = 1\n", "f.toml: inner.length: must be <= 5 in slow mode"),
    ("[inner]\nlength = 1\n[[items]]\nn = 1.5\n", "items[1].n: must be an integer, got number 1.5"),
    ("[inner]\nlength = 1\n[[items]]\nn = 1\n[[items]]\nnn = 1\n",
     "unknown key 'items.nn' (in items[2]) (did you mean 'items.n'?)"),
    ("[inner]\nlength = 1\n" + "[[items]]\nn = 1\n" * 4, "items: must list at most 3, got 4"),
    ("[inner]\nlength = 1\n[[items]]\nn = 1\nw = inf\n", "items[1].w: must be finite, got inf"),
    ("pair = [1.0]\n[inner]\nlength = 1\n[[items]]\nn = 1\n", "pair: must be a list of 2 numbers, got an array of 1"),
    ("flag = 1\n[inner]\nlength = 1\n[[items]]\nn = 1\n", "flag: must be true or false, got integer 1"),
])
def test_loader_faults_are_one_line(text, fragment):
    with pytest.raises(ValueError) as ei:
        _load(text)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("f.toml: ") and fragment in msg, msg


def test_loader_values_and_defaults():
    r = _load("[inner]\nlength = 2\n[[items]]\nn = 1\nw = 90\n[[items]]\nn = 2\n")
    assert r.inner == _Inner(length=2.0) and r.flag is False and r.pair == (1.0, 2.0) and r.opt is None
    assert r.items[0].w == math.pi / 2 and r.items[1] == _Item(n=2)
    assert [k for k, _ in config.flatten(r)][:3] == ["inner.length", "inner.mode", "inner.fixed"]


def test_entry_style_checks_the_entry():
    @dataclass(frozen=True)
    class E:
        x: float = quantity("length")

    load = lambda t: config.load_text(E, t, "e.toml", ValueError, entries=True)  # noqa: E731
    got = load('x = { value = 5.0, unit = "mm", source = "here" }')
    assert got.value.x == 5.0 * 1e-3 and got.entries == {"x": ("mm", "here")}
    for text, fragment in [
        ("x = 5.0", "x: expected a table { value, unit, source }, got number 5.0"),
        ('x = { value = 5.0, unit = "mm" }', "missing field 'source'"),
        ('x = { value = 5.0, unit = "mm", source = "" }', "x: 'source' must be a non-empty string"),
        ('x = { value = 5.0, unit = 3, source = "s" }', "x: 'unit' must be a string, got integer 3"),
        ('x = { value = 5.0, unit = "mm", source = "s", note = 1 }', "not the field 'note'"),
        ('x = { value = "5", unit = "mm", source = "s" }', "x: value must be a number, got string '5'"),
    ]:
        with pytest.raises(ValueError, match=re.escape(fragment)):
            load(text)


def test_schema_declarations_are_checked():
    with pytest.raises(ValueError, match="unknown dimension 'lenght'"):
        quantity("lenght")
    with pytest.raises(ValueError, match="unit 'deg' is not a length"):
        quantity("length", unit="deg")

    @dataclass(frozen=True)
    class NoDim:
        x: float = setting()

    with pytest.raises(TypeError, match="needs its dimension"):
        config.load_doc(NoDim, {"x": 1.0}, "w", ValueError)
