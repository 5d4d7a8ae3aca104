"""Every committed front stays valid: its knee replays bit for bit on today's code (objectives and per-DOF
CHAT and RMSE, through the study's own evaluation) and the run digest it records is today's. A change that
alters a committed front's run fails here; re-run the study or, if its numbers still replay, re-stamp it
(``arvcas front restamp``, docs/provenance.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from arvcas.tuning import checkpoint as ck
from arvcas.tuning import front as front_mod

ROOT = Path(__file__).resolve().parents[1]
FRONTS = sorted(p.relative_to(ROOT).as_posix() for p in ROOT.glob("results/**/front.h5"))


def test_the_committed_fronts_are_found():
    assert len(FRONTS) >= 15, FRONTS


@pytest.mark.slow  # a compile of each front's run on a cold cache (15 runs, about 20-70 s each here)
@pytest.mark.parametrize("rel", FRONTS)
def test_committed_front_knee_replays_bit_for_bit(rel):
    path = ROOT / rel
    c = ck.read_checkpoint(path)
    assert len(c.run_digest) == 64, f"{rel}: no run digest; arvcas front restamp {rel}"
    r = front_mod.replay_all(path, "knee")
    assert r.bitwise, r.describe()
    assert r.run_digest == c.run_digest, f"{rel}: run digest {c.run_digest[:12]} in the file, {r.run_digest[:12]} now"
    assert r.system_variant == c.system_variant, (rel, r.system_variant, c.system_variant)
    assert front_mod.check_provenance(path, front_mod.system_params(c), False, "test") == ""
