"""The committed ArduSub studies (studies/ardusub.toml, results/ardusub/; studies/ardusub_identified.toml,
results/ardusub/identified/): each knee's ``.param`` file parses as
ArduPilot's parameter format (``NAME value`` per line, ``#`` comments), every name is in ArduSub's parameter list
shipped in arvcas/data/ardusub_params.toml with its value inside ArduSub's range and equal to the knee's gain, and
the committed ardusub knee replays bit for bit (slow: the run's cold build takes minutes)."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import arvcas
from arvcas.controllers import ardusub
from arvcas.tuning.front import _norm_label, read_front, replay

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "ardusub"
PARAM = RESULTS / "knee" / "bluerov2_heavy_ardusub.param"
FRONT = RESULTS / "ardusub" / "front.h5"
# (the knee's .param file, its front, its system): the BlueROV2 Heavy's study and the identified Hinsdale vehicle's
STUDIES = [(PARAM, FRONT, "bluerov2_heavy"),
           (RESULTS / "identified" / "knee" / "hinsdale_bluerov2_alpha5_identified_t200_ardusub.param",
            RESULTS / "identified" / "front.h5", "hinsdale_bluerov2_alpha5_identified_t200")]
# ArduPilot's parameter files: a name of capitals, digits and underscores (at most 16 characters, AP_Param's
# limit), a separator (space, comma or tab) and a number; '#' starts a comment
LINE = re.compile(r"^([A-Z][A-Z0-9_]{0,15})[ ,\t]+([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)$")


def parse(text: str) -> dict[str, float]:
    out = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = LINE.match(line)
        assert m, f"line {n} is not 'NAME value': {line!r}"
        assert m[1] not in out, f"line {n}: {m[1]} given twice"
        out[m[1]] = float(m[2])
    return out


@pytest.mark.parametrize("param, front, system", STUDIES, ids=["heavy", "identified"])
def test_knee_param_file_parses_and_names_are_ardusubs(param, front, system):
    text = param.read_text()
    values = parse(text)
    table = tomllib.loads((Path(arvcas.__file__).parent / "data" / "ardusub_params.toml").read_text())["param"]
    assert values and set(values) <= set(table), set(values) - set(table)
    for name, v in values.items():
        lo, hi = table[name]["range"]
        assert lo <= v <= hi, (name, v, lo, hi)
    # the twelve tuned parameters, each the knee's gain in its slot
    fr = read_front(front)
    g = fr.gains[fr.knee()]
    slots = ardusub.slot_names()
    tuned = {n: float(v) for n, v in zip(slots, g) if n is not None}
    assert set(values) == set(tuned) == {n for n, p in table.items() if p["tuned"]}
    for n, v in tuned.items():
        assert values[n] == pytest.approx(v, rel=1e-6), n  # written with 7 significant digits
    header = [ln for ln in text.splitlines() if ln.startswith("#")]
    for key in ("system", "front", "member", "objectives"):
        assert any(ln.startswith(f"# {key}:") for ln in header), key
    assert f"# system: {system}\n" in text and "# member: knee\n" in text


def test_parse_refuses_what_ardupilot_would_not_read():
    with pytest.raises(AssertionError):
        parse("ATC_RAT_RLL_P = 0.1\n")
    with pytest.raises(AssertionError):
        parse("atc_rat_rll_p 0.1\n")
    with pytest.raises(AssertionError):
        parse("ATC_RAT_RLL_P 0.1\nATC_RAT_RLL_P 0.2\n")
    assert parse("# c\nATC_RAT_RLL_P 0.1\nPSC_POSZ_P,3\n") == {"ATC_RAT_RLL_P": 0.1, "PSC_POSZ_P": 3.0}


@pytest.mark.slow
def test_committed_ardusub_knee_replays_bit_for_bit():
    fr = read_front(FRONT)
    i = fr.knee()
    ev = replay(FRONT, i)
    np.testing.assert_array_equal(ev.F[0], fr.F[i])
    np.testing.assert_array_equal(ev.chat[:, 0], fr.chat[:, i])
    np.testing.assert_array_equal(ev.rmse[:, 0], fr.rmse[:, i])


def test_front_axes_name_the_study_normalisation():
    """The fronts record a normalisation given in the study: the plot's axes say so, not 'AGSTA at its defaults'."""
    fronts = [read_front(RESULTS / c / "front.h5") for c in ("ardusub", "pid")]
    assert _norm_label(fronts) == "the study's reference values"
    fr = fronts[1]
    law = dataclasses.replace(fr, normalisation="pid's value at the default gains of bluerov2_heavy on draw 1")
    assert _norm_label([law]) == "pid at its defaults"
    assert _norm_label([dataclasses.replace(fr, normalisation="")]) == "AGSTA at its defaults"
