"""A CSV log that would be read wrong is refused in one line, and what a log costs is bounded: a quaternion
in the other component order (found by the accelerometer's gravity direction), a
row with more or fewer fields than the header (a decimal comma shifts every column), a corrupt or truncated
gzip file; the CSV reader streams blocks of lines (its memory is the columns it keeps, not the file) and
any block size reads the same numbers (Hypothesis over CSV contents)."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from arvcas.ident import logs, streams
from arvcas.ident.logs import LogError, load_log

from trust_helpers import pose_log


@pytest.mark.parametrize("file_order, said", [("wxyz", "xyzw"), ("xyzw", "wxyz")])
def test_a_quaternion_in_the_other_order_is_found_by_the_accelerometer(tmp_path, file_order, said):
    # heading 2.3 rad: the other order is 37 deg off the accelerometer (median), a tilt the tilt check alone passes
    with pytest.raises(LogError, match=rf'pose.csv: .*trial.log.toml stream\[1\].quaternion_order = "{said}" looks '
                                       rf"wrong: the accelerometer's gravity direction is \d+ deg from the attitude's "
                                       rf'\(median\); with "{file_order}" it is \d deg$'):
        load_log(pose_log(tmp_path, 2.3, file_order, said, accel=True))
    assert load_log(pose_log(tmp_path, 2.3, file_order, file_order, accel=True)).duration == pytest.approx(20.0)


def test_without_an_accelerometer_nothing_is_guessed(tmp_path):
    """The tilt alone is no evidence (a wrong body frame tilts the vehicle too): the frame check speaks."""
    with pytest.raises(LogError, match=r"the attitude's frame does not match: median roll"):
        load_log(pose_log(tmp_path, 0.4, "wxyz", "xyzw", accel=False))


def _stream(tmp_path, text: bytes, name="s.csv") -> Path:
    p = tmp_path / name
    p.write_bytes(text)
    return p


@pytest.mark.parametrize("row, fields", [(b"0.02,1,2,3\n", 4), (b"0.02,1\n", 2), (b"0.02,1,2,5,\n", 5)])
def test_a_row_with_another_number_of_fields_than_the_header_is_refused_naming_it(tmp_path, row, fields):
    p = _stream(tmp_path, b"t,a,b\n0,1,2\n\n0.01,1,2\n" + row + b"0.03,1,2\n")  # row 5 of the file
    why = r" \(a decimal comma\?" if fields > 3 else "$"
    with pytest.raises(LogError, match=rf"^{p}: row 5: {fields} fields, the header has 3{why}"):
        streams.read_csv(p, ["a"], "t", "m.log.toml")  # even where the column read is before the extra fields


def test_a_decimal_comma_row_is_named_in_a_large_file(tmp_path, monkeypatch):
    monkeypatch.setattr(streams, "CSV_BLOCK_BYTES", 64)  # many blocks: the row number counts across them
    rows = [f"{0.01 * k:.2f},{k},{2 * k}" for k in range(200)]
    rows[150] = "1,50,3,5"  # 3,5 written with a decimal comma
    p = _stream(tmp_path, ("t,a,b\n" + "\n".join(rows) + "\n").encode())
    with pytest.raises(LogError, match=rf"^{p}: row 152: 4 fields, the header has 3 \(a decimal comma\? fields are "
                                       rf"separated by commas and decimals take a point\)$"):
        streams.read_csv(p, ["a", "b"], "t", "m.log.toml")


@pytest.mark.parametrize("damage", ["truncated", "flipped", "not gzip"])
def test_a_corrupt_gzip_log_is_one_line(tmp_path, damage):
    raw = gzip.compress(("t,a\n" + "".join(f"{k * 0.01},{k}\n" for k in range(5000))).encode())
    if damage == "truncated":
        raw = raw[: len(raw) // 2]
    elif damage == "flipped":
        raw = raw[:200] + bytes([raw[200] ^ 0xFF]) + raw[201:]
    else:
        raw = b"t,a\n0,1\n"
    p = _stream(tmp_path, raw, "s.csv.gz")
    with pytest.raises(LogError, match=rf"^{p}: not a readable gzip file \(.+\)$") as e:
        streams.read_csv(p, ["a"], "t", "m.log.toml")
    assert "\n" not in str(e.value)


def test_a_log_is_bounded_by_the_values_it_keeps(tmp_path, monkeypatch):
    p = _stream(tmp_path, ("t,a,b,c\n" + "".join(f"{k},{k},{k},{k}\n" for k in range(1000))).encode())
    monkeypatch.setattr(streams, "CSV_BLOCK_BYTES", 256)
    budget = streams.Budget("m.log.toml", max_mb=2500 * 8 / 1e6)  # 2,500 values
    assert streams.read_csv(p, ["a"], "t", "m", budget).time.size == 1000  # 2 columns kept: 2000 values
    assert budget.used == 2000
    with pytest.raises(LogError, match=rf"^{p}: [\d,]+ rows \(by row \d+\) of the 3 columns read would keep 0.02 MB of "
                                       r"values \(float64\) with the streams before it, more than \[log\] "
                                       r"max_memory_mb = 0.02 in m.log.toml: raise it"):
        streams.read_csv(p, ["a", "b"], "t", "m", streams.Budget("m.log.toml", max_mb=2500 * 8 / 1e6))


_floats = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 40), st.integers(1, 5), st.integers(16, 400), st.booleans(), st.booleans(), st.data())
def test_any_block_size_reads_the_numbers_written(tmp_path_factory, n, m, block, gz, crlf, data):
    """Property: a CSV of n rows and m columns (any finite floats, as repr writes them; blank and comment
    lines between rows; CRLF or LF) reads back exactly, whatever the block size."""
    a = np.array(data.draw(st.lists(st.lists(_floats, min_size=m + 1, max_size=m + 1), min_size=n, max_size=n)))
    nl = "\r\n" if crlf else "\n"
    lines = [",".join(["t"] + [f"c{j}" for j in range(m)])]
    for k, row in enumerate(a):
        lines.append(",".join(repr(float(v)) for v in row))
        if k % 7 == 3:
            lines.append("# a comment" if k % 2 else "")
    text = (nl.join(lines) + nl).encode()
    d = tmp_path_factory.mktemp("csv")
    p = d / ("s.csv.gz" if gz else "s.csv")
    p.write_bytes(gzip.compress(text) if gz else text)
    old = streams.CSV_BLOCK_BYTES
    streams.CSV_BLOCK_BYTES = block
    try:
        tab = streams.read_csv(p, [f"c{j}" for j in range(m)], "t", "m")
    finally:
        streams.CSV_BLOCK_BYTES = old
    np.testing.assert_array_equal(tab.time, a[:, 0])
    for j in range(m):
        np.testing.assert_array_equal(tab.cols[f"c{j}"], a[:, j + 1])
