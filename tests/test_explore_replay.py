"""front explore when a member's replay does not reproduce its stored CHAT/RMSE although the model is the
study's (a front whose numbers are not its run's): refused in one line naming --allow-model-change, and
with that flag the page is written and records the difference (the hint's promise)."""

from __future__ import annotations

import json
import re

from trust_helpers import run, synthetic_front


def test_allow_model_change_writes_the_page_a_replay_does_not_reproduce(tmp_path, capsys):
    d = tmp_path / "study" / "agsta"
    d.mkdir(parents=True)
    synthetic_front(d / "front.h5")  # today's model hash; its stored CHAT/RMSE are ones, not the run's
    page = tmp_path / "p.html"
    rc, err = run(["front", "explore", d, "--out", page, "--members", "knee"], capsys)
    last = err.strip().splitlines()[-1]  # after the run's compile (its progress line on a cold cache)
    assert rc == 2 and last.startswith("arvcas: error: ") and "Traceback" not in err, err
    assert "replay does not reproduce" in last and "--allow-model-change" in last
    assert not page.exists()
    rc, err = run(["front", "explore", d, "--out", page, "--members", "knee", "--allow-model-change"], capsys)
    assert rc == 0, err
    text = page.read_text(encoding="utf-8")
    data = re.search(r'<script type="application/json" id="data">(.*?)</script>', text, re.S).group(1)
    replay = json.loads(data)["fronts"][0]["replay"]
    assert replay["reproduced"] is False and replay["max_difference"] > 0, replay
