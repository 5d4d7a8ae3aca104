"""Writes hinsdale_bluerov2_alpha5_identified_t200.toml beside this script: the identified Hinsdale
BlueROV2 + Alpha 5 (results/validation/hinsdale_bluerov2_alpha5_identified.toml, every number unchanged) with
the T200 thruster dynamics of the shipped BlueROV2 Heavy (arvcas/data/bluerov2_heavy_alpha5.toml: its
command map, the 16 V table, and each thruster's time constant, taken line for line by thruster name).

Why: ArduSub's law (`ardusub`, docs/ardusub.md) sends PWM, so it needs thrusters with a PWM command map;
the identified file's thrusters are instantaneous (the Hinsdale trials ran with the thrusters off, and its
eight thrusters are the file's stand-in BlueROV2 Heavy retrofit of T200s, not the vehicle as tested).

    python studies/systems/hinsdale_t200.py          # (re)write the file
    python studies/systems/hinsdale_t200.py --check  # exit 1 if the committed file differs

Used by studies/ardusub_identified.toml (results in results/ardusub/identified/).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
IDENTIFIED = ROOT / "results/validation/hinsdale_bluerov2_alpha5_identified.toml"
HEAVY = ROOT / "arvcas/data/bluerov2_heavy_alpha5.toml"
OUT = HERE / "hinsdale_bluerov2_alpha5_identified_t200.toml"
NAME = "hinsdale_bluerov2_alpha5_identified_t200"
# a thruster's dynamics keys (docs/system-file.md, "Thruster dynamics")
DYNAMICS = ("map", "time_constant", "time_constant_up", "time_constant_down", "rate_limit")


def _units(text: str) -> list[tuple[str, list[str]]]:
    """Each ``[[thrusters.unit]]`` block's name and lines (up to the next table header)."""
    out = []
    for block in re.split(r"^\[\[thrusters\.unit\]\]\n", text, flags=re.M)[1:]:
        lines = block.split("\n[")[0].splitlines()
        name = re.search(r'^name = "([^"]+)"', block, flags=re.M).group(1)
        out.append((name, lines))
    return out


def render() -> str:
    heavy, ident = HEAVY.read_text(encoding="utf-8"), IDENTIFIED.read_text(encoding="utf-8")
    maps = re.findall(r"^\[thrusters\.map\.[a-z0-9_]+\]\n(?:[^\[\n].*\n)*", heavy, flags=re.M)
    dyn = {n: [ln for ln in lines if ln.split(" = ")[0] in DYNAMICS] for n, lines in _units(heavy)}
    names = [n for n, _ in _units(ident)]
    if sorted(names) != sorted(dyn) or not maps:
        raise SystemExit(f"{IDENTIFIED.name}: thrusters {names} do not match {HEAVY.name}'s {sorted(dyn)}")
    head = (f"# Written by studies/systems/hinsdale_t200.py (do not edit; re-run it): {IDENTIFIED.relative_to(ROOT)}\n"
            f"# with the T200 thruster dynamics of {HEAVY.relative_to(ROOT)} (its command map and each thruster's\n"
            "# time constant, by thruster name). Every other number is the identified file's.\n#\n")
    text = ident.replace('name = "hinsdale_bluerov2_alpha5_identified"', f'name = "{NAME}"', 1)
    text = re.sub(r'^(description = ".*)(")$', r"\1; T200 dynamics of bluerov2_heavy_alpha5\2", text, count=1,
                  flags=re.M)
    first = text.index("[[thrusters.unit]]\n")
    text = text[:first] + "".join(m + "\n" for m in maps) + text[first:]

    def add(m: re.Match) -> str:
        block = m.group(0)
        name = re.search(r'^name = "([^"]+)"', block, flags=re.M).group(1)
        return block.rstrip("\n") + "\n" + "\n".join(dyn[name]) + "\n" + ("\n" if block.endswith("\n\n") else "")

    text = re.sub(r"^\[\[thrusters\.unit\]\]\n(?:[^\[\n].*\n|\n)*?(?=\n*\[|\Z)", add, text, flags=re.M)
    return head + text


def main(argv: list[str]) -> int:
    text = render()
    if "--check" in argv:
        same = OUT.is_file() and OUT.read_text(encoding="utf-8") == text
        print(f"{OUT.relative_to(ROOT)}: {'up to date' if same else 'differs from the script; re-run it'}")
        return 0 if same else 1
    OUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
