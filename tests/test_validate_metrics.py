"""Validation metrics an engineer knows from the MATLAB System Identification Toolbox: FIT %, the k-step-ahead
prediction of ``compare(data, sys, k)``, the residual tests of ``resid``; the summary per role; the command.

References independent of the code under test: FIT % and the correlations written out as sums, white and
AR(1) signals whose correlations are known in closed form (white noise falls outside the 99 % band at about
the nominal rate, an AR(1) residual does not), the truth a synthetic trial was simulated from, CasADi's J,
and the plant's own open-loop simulation over windows of the log (another code path: 50-sample blocks).
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from ident_helpers import vehicle_only

import arvcas
from arvcas.cli import main
from arvcas.ident import logs, plant, synthetic, validate
from arvcas.model.spatial import J


# ---- FIT % ------------------------------------------------------------------------------------------------


def _fit_by_hand(y, yhat):
    mean = math.fsum(y) / len(y)
    num = math.sqrt(math.fsum((a - b) ** 2 for a, b in zip(y, yhat)))
    den = math.sqrt(math.fsum((a - mean) ** 2 for a in y))
    return 100.0 * (1.0 - num / den)


def test_fit_percent_is_matlabs_definition():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 10, 501)
    y = np.sin(t) + 0.3 * t
    for yhat in (y + rng.normal(0, 0.1, t.size), 0.8 * y, y[::-1].copy()):
        assert validate.fit_percent(y, yhat) == pytest.approx(_fit_by_hand(y, yhat), rel=1e-12, abs=1e-10)
    assert validate.fit_percent(y, y) == 100.0
    assert validate.fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-12)
    ybar = y.mean()
    assert validate.fit_percent(y, ybar + 0.5 * (y - ybar)) == pytest.approx(50.0, abs=1e-10)
    # with R^2 of the same errors: FIT = 100 (1 - sqrt(1 - R^2))
    yhat = y + rng.normal(0, 0.2, t.size)
    m = validate.metrics(y, yhat)
    assert m["fit"] == pytest.approx(100 * (1 - math.sqrt(1 - m["r2"])), rel=1e-12)


# ---- correlations ---------------------------------------------------------------------------------------


def test_correlations_match_the_sums():
    rng = np.random.default_rng(2)
    e, u = rng.normal(size=300) + 1.0, rng.normal(size=300) - 2.0
    L = 7
    ec, uc = e - e.mean(), u - u.mean()
    auto = [sum(ec[t + k] * ec[t] for t in range(300 - k)) / sum(ec * ec) for k in range(L + 1)]
    cross = [sum(ec[t + k] * uc[t] for t in range(max(0, -k), min(300, 300 - k))) / math.sqrt(sum(ec * ec) *
             sum(uc * uc)) for k in range(-L, L + 1)]
    assert np.allclose(validate.correlations(e, None, L), auto, rtol=1e-12, atol=1e-14)
    assert np.allclose(validate.correlations(e, u, L), cross, rtol=1e-12, atol=1e-14)
    # numpy's own full correlation: index N - 1 + k holds lag k
    full = np.correlate(ec, uc, "full") / math.sqrt((ec @ ec) * (uc @ uc))
    assert np.allclose(validate.correlations(e, u, L), full[299 - L:300 + L], rtol=1e-12, atol=1e-14)
    assert np.isnan(validate.correlations(np.ones(50), None, 3)).all()


def _ar1(rng, n, phi):
    w = rng.normal(size=n + 200)
    x = np.empty_like(w)
    x[0] = w[0]
    for i in range(1, len(w)):
        x[i] = phi * x[i - 1] + w[i]
    return x[200:]


def test_white_residual_falls_outside_the_band_at_the_nominal_rate():
    """99 % band: white noise, and its cross-correlation with an independent coloured input, leave about 1 %
    of lags outside (100 series x 25 or 51 lags: 1 % expected, the binomial 99.9 % range is about 0.3-2.1 %)."""
    rng = np.random.default_rng(3)
    auto, cross = [], []
    for _ in range(100):
        e = rng.normal(size=2000)
        u = _ar1(rng, 2000, 0.9)
        t = validate.residual_tests({"e": e}, {"u": u})["e"]
        assert t["band"] == pytest.approx(2.58 / math.sqrt(2000))
        auto.append(t["auto_outside"])
        cross.append(t["cross_outside"]["u"])
    assert 0.003 < np.mean(auto) < 0.021, np.mean(auto)
    assert 0.003 < np.mean(cross) < 0.021, np.mean(cross)


def test_ar1_residual_does_not_pass():
    """An AR(1) residual (phi = 0.8) has autocorrelation 0.8^k: outside the band up to lag 14 for N = 2000."""
    rng = np.random.default_rng(4)
    e = _ar1(rng, 2000, 0.8)
    r = validate.correlations(e)
    assert r[0] == 1.0 and abs(r[1] - 0.8) < 0.05 and abs(r[2] - 0.64) < 0.07
    t = validate.residual_tests({"e": e, "flat": np.zeros(2000)}, {})
    assert t["e"]["auto_outside"] > 0.4 and t["flat"] is None
    # a residual that is the input, delayed by 3 samples, correlates with it at lag +3
    u = rng.normal(size=2000)
    e = np.r_[np.zeros(3), u[:-3]] + 0.1 * rng.normal(size=2000)
    c = validate.correlations(e, u, 5)
    assert np.argmax(np.abs(c)) == 5 + 3 and c[8] > 0.9


# ---- the k-step-ahead predictor -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    """The Hinsdale vehicle without its arm (small compiled code), and a noise-free synthetic trial of it."""
    d = tmp_path_factory.mktemp("vm")
    system = vehicle_only("hinsdale_bluerov2_alpha5", "hinsdale_vehicle", d)
    path = system.path
    quiet = {"position": 1e-9, "attitude": 1e-9, "rate": 1e-9}  # noise-free (a std must be > 0)
    seed, duration = 3, 6.0
    lp = synthetic.write_trial(d, "quiet", system, duration=duration, seed=seed, noise=quiet)
    noisy = synthetic.write_trial(d, "noisy", system, duration=duration, seed=seed)
    rng = np.random.default_rng(10_000 + seed)  # write_trial's own start state
    x0 = np.zeros(12)
    x0[3:6] = rng.uniform(-0.15, 0.15, 3)
    t, X, _ = synthetic.truth(system, duration + 0.5, seed, None, x0)
    lg = logs.load_log(lp, n_joints=0)
    true = np.stack([np.interp(lg.t + lg.t0, t, X[:, i]) for i in range(12)], axis=1)
    return system, lg, true, path, noisy


def test_J_many_is_casadis_J():
    eta = np.random.default_rng(5).uniform(-1, 1, (7, 6))
    got = validate._J_many(eta)
    for i in range(7):
        assert np.allclose(got[i], np.array(J(eta[i]), dtype=float), rtol=0, atol=1e-14)


def test_logged_states_recover_the_unmeasured_velocities(vehicle):
    """u, v, w are not measured: from the pose's rate of change, whatever the simulation said."""
    system, lg, true, _, _ = vehicle
    wrong = true.copy()
    wrong[:, 6:9] = 0.0  # a simulation with no linear velocity at all
    wrong[:, 0:6] += 0.3  # and the wrong pose: the log's measured pose replaces it
    st = validate.logged_states(lg, wrong)
    inner = slice(20, -20)  # the centred fit's ends are one-sided
    assert np.max(np.abs(st[:, 0:6] - true[:, 0:6])) < 1e-3  # the logged pose (interpolated onto the time base)
    assert np.max(np.abs(st[inner, 6:9] - true[inner, 6:9])) < 2e-3, np.max(np.abs(true[:, 6:9]))
    assert np.max(np.abs(st[:, 9:12] - true[:, 9:12])) < 2e-3  # the logged rates
    # x and y not logged (as in the Hinsdale trials): they and the velocities' horizontal part come from the
    # simulation; the measured depth's rate corrects the rest by the smallest change
    sig = {k: v for k, v in lg.signals.items() if k not in ("x", "y")}
    lxy = dataclasses.replace(lg, signals=sig)
    sim = true.copy()
    sim[:, 8] += 0.05  # heave wrong by 5 cm/s
    st = validate.logged_states(lxy, sim)
    assert np.array_equal(st[:, 0:2], sim[:, 0:2])
    Jz = validate._J_many(st[:, :6])[:, 2, :]
    zdot = np.einsum("nj,nj->n", Jz, st[:, 6:])
    assert np.max(np.abs(zdot[inner] - validate._slopes(lg, lg.signals["z"])[inner])) < 1e-12
    change = st[:, 6:9] - sim[:, 6:9]  # the smallest: along the depth row of J (R's third row)
    assert np.max(np.linalg.norm(np.cross(change, Jz[:, 0:3]), axis=1)) < 1e-12
    # the part of the heave error along the depth row is gone; what the tilt puts into u and v stays
    assert np.max(np.abs(st[inner, 8] - true[inner, 8])) < 0.5 * 0.05


def test_prediction_restarts_every_k_samples(vehicle):
    system, lg, true, _, _ = vehicle
    pl = plant.LogPlant(system, m=2)
    p = system.params.vector()
    N = len(lg.t)
    X = plant.simulate(pl, lg, true[0], p)
    # k at least the trial: the open-loop simulation
    assert np.allclose(validate.predict(pl, lg, p, N, true), X, rtol=0, atol=1e-12)
    assert np.allclose(validate.predict(pl, lg, p, 10 * N, true), X, rtol=0, atol=1e-12)
    # any k: each segment is the open-loop simulation of its window of the log from the state at its start
    states = true + np.random.default_rng(6).normal(0, 1e-3, true.shape)  # restart states of our choosing
    for k in (1, 7, 50):
        Xk = validate.predict(pl, lg, p, k, states)
        assert np.array_equal(Xk[0], states[0])
        for s in (0, k, 3 * k, (N - 2) // k * k):
            e = min(s + k, N - 1)
            w = lg.window(lg.t[s], lg.t[e])
            ref = plant.simulate(pl, w, states[s], p)
            assert np.allclose(Xk[s + 1:e + 1], ref[1:], rtol=0, atol=1e-10), (k, s)
    with pytest.raises(ValueError, match="k: the prediction horizon"):
        validate.predict(pl, lg, p, 0, states)
    with pytest.raises(ValueError, match="states: expected"):
        validate.predict(pl, lg, p, 5, states[:-1])


def test_validate_log_k_step(vehicle):
    """On a trial the model explains exactly, the k-step prediction is at least as good as the simulation."""
    system, lg, true, _, _ = vehicle
    r = validate.validate_log(system, lg, k=10)
    assert r.k == 10 and set(r.predicted) == set(r.kstep["fit"]) == {"x", "y", "z", "roll", "pitch", "yaw",
                                                                       "p", "q", "r"}
    for s in ("roll", "pitch", "p", "q"):
        assert r.kstep["fit"][s] > 95 and r.metrics["fit"][s] > 95, s
    r0 = validate.validate_log(system, lg)
    assert r0.k is None and not r0.predicted and r0.metrics == r.metrics


# ---- the command ----------------------------------------------------------------------------------------


def test_validate_command_summary_roles_and_refusals(vehicle, tmp_path, capsys):
    system, lg, _, path, noisy = vehicle
    out = tmp_path / "v"
    assert main(["validate", "--system", str(path), str(noisy), "--out", str(out), "--k", "5"]) == 0
    text = capsys.readouterr().out
    assert "held out  roll" in text and "FIT % (5-step)" in text
    doc = json.loads((out / "validation.json").read_text())
    m = doc["trials"]["noisy"]
    assert doc["format"] == "arvcas-validation-2" and m["role"] == "held out" and m["kstep"]["k"] == 5
    assert set(m["fit"]) == set(m["kstep"]["fit"]) == set(m["resid"])
    assert set(doc["summary"]) == {"held out"} and doc["summary"]["held out"]["trials"] == ["noisy"]
    assert doc["summary"]["held out"]["signals"]["pitch"]["fit"] == m["fit"]["pitch"]  # a median of one
    readme = (out / "README.md").read_text()
    assert "| held out | roll |" in readme and "/work" not in readme and not list(out.glob("*.png"))
    # --fitted names the fit trials; --figures draws
    assert main(["validate", "--system", str(path), str(noisy), "--out", str(out), "--force", "--fitted", "noisy",
                 "--figures", "--format", "svg"]) == 0
    doc = json.loads((out / "validation.json").read_text())
    assert doc["trials"]["noisy"]["role"] == "fit" and (out / "noisy.svg").stat().st_size > 0
    for args, match in ((["--k", "0"], "--k: the prediction horizon must be in"),
                        (["--format", "pdf"], "--format pdf: figures are drawn only with --figures"),
                        (["--fitted", "noisy,nosy"], "--fitted: no trial named 'nosy' among the logs given (noisy)")):
        capsys.readouterr()
        rc = main(["validate", "--system", str(path), str(noisy), "--out", str(tmp_path / "w"), *args])
        err = capsys.readouterr().err
        assert rc == 2 and match in err and err.count("\n") == 1, err
        assert not (tmp_path / "w").exists()


# ---- the parsed-log cache -------------------------------------------------------------------------------


def _same_log(a, b):
    for f in dataclasses.fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if isinstance(va, np.ndarray):
            assert np.array_equal(va, vb), f.name
        elif isinstance(va, dict):
            assert va.keys() == vb.keys() and all(np.array_equal(va[k], vb[k]) for k in va), f.name
        elif f.name != "joints":
            assert va == vb, f.name
    if a.joints is not None:
        tt = np.linspace(-1.0, a.t[-1] + 1.0, 777)
        assert all(np.array_equal(u, v) for u, v in zip(a.joints(tt), b.joints(tt)))


def test_parsed_log_cache(vehicle, tmp_path, monkeypatch):
    from arvcas.ident import logcache

    system, _, _, _, _ = vehicle
    monkeypatch.setenv("ARVCAS_CACHE", str(tmp_path / "cache"))
    full = arvcas.load_system("hinsdale_bluerov2_alpha5")  # with its arm: joint splines in the log
    path = synthetic.write_trial(tmp_path / "logs", "armed", full, duration=3.0, seed=1)
    fresh = logs.load_log(path, 4)
    _same_log(fresh, logcache.load_log(path, 4))
    assert len(list((tmp_path / "cache" / "logs").glob("*.npz"))) == 1

    def no_reading(*a, **k):
        raise AssertionError("read again")

    with monkeypatch.context() as mp:  # unchanged: from the cache, equal bit for bit
        mp.setattr(logs, "load_log", no_reading)
        _same_log(fresh, logcache.load_log(path, 4))
    # a changed stream file, another joint count, a bad mapping: read again (and refused as load_log refuses)
    imu = path.parent / "armed_imu.csv"
    rows = imu.read_text().splitlines()
    cols = rows[1].split(",")
    cols[1] = repr(float(cols[1]) + 0.5)
    imu.write_text("\n".join([rows[0], ",".join(cols), *rows[2:]]) + "\n")
    changed = logcache.load_log(path, 4)
    assert changed.signals["p"][0] != fresh.signals["p"][0]
    _same_log(logs.load_log(path, 4), changed)
    with pytest.raises(logs.LogError, match="joint"):
        logcache.load_log(path, 2)
    # a mapping whose strings name its own directory or one above, or too many files, is read, never cached
    odd = tmp_path / "logs" / "odd.log.toml"
    for value, cached in (("armed_imu.csv", True), (".", False), ("..", False), ("nothing.csv", True)):
        odd.write_text(f'[log]\nname = "odd"\nsource = "{value}"\n')
        assert (logcache._key(odd, 4, None) is not None) == cached, value
    many = tmp_path / "logs" / "many"
    many.mkdir()
    for i in range(logcache.MAX_FILES + 1):
        (many / f"{i}.csv").write_text("t\n")
    odd.write_text('[log]\nname = "odd"\nbag = "many"\n')
    assert logcache._key(odd, 4, None) is None
    twin = path.parent / "twin.log.toml"  # the same [log] name in another mapping file
    twin.write_text(path.read_text())
    with pytest.raises(logs.LogError, match="trial name 'armed' is also the name of"):
        logcache.load_logs([path, twin], 4)
    path.write_text(path.read_text().replace("[log]", "[log]\nbogus = 1", 1))
    with pytest.raises(logs.LogError, match="bogus"):
        logcache.load_log(path, 4)


def test_help_is_printed(capsys):
    """argparse formats help strings with %: the command list and the command's options must print."""
    for args in (["--help"], ["validate", "--help"]):
        assert main(args) == 0
    out = capsys.readouterr().out
    assert "FIT percent" in out and "--k N" in out and "--figures" in out
