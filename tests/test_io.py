"""lensim.io: atomic writes leave the old file or the new one, never a partial one."""

import os
import stat

import pytest

from lensim.errors import InputError
from lensim.io import atomic_write_json, atomic_write_text, atomic_writer, read_json


def test_atomic_write_replaces_and_has_usual_mode(tmp_path):
    path = tmp_path / "sub" / "a.txt"
    atomic_write_text(path, "one")
    atomic_write_text(path, "two")
    assert path.read_text() == "two"
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
    assert [p.name for p in path.parent.iterdir()] == ["a.txt"]


def test_failure_inside_block_keeps_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_writer(path) as fh:
            fh.write(b"half of the new")
            raise RuntimeError("killed")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]


def test_read_json_round_trip_and_one_line_errors(tmp_path):
    good = tmp_path / "m.json"
    atomic_write_json(good, {"a": [1, 2], "p": tmp_path})
    assert read_json(good) == {"a": [1, 2], "p": str(tmp_path)}
    bad = tmp_path / "bad.json"
    bad.write_bytes(b"\xff\xfe{not json")
    for path, words in (
        (bad, "could not parse"),
        (tmp_path, "found a directory"),
        (tmp_path / "none.json", "found nothing"),
    ):
        with pytest.raises(InputError) as err:
            read_json(path, "manifest")
        assert str(path) in str(err.value) and words in str(err.value) and "\n" not in str(err.value)


def test_strict_json_round_trips_non_finite_numbers_and_leaves_other_strings():
    import json
    import math

    from lensim.jsonable import from_strict, jsonable, strict_json

    data = {"focus_m": math.inf, "shift": -math.inf, "bad": math.nan, "fno": 2.8, "config": "tele", 3: (1.0, 2)}
    text = json.dumps(strict_json(data), allow_nan=False)  # strict JSON: no bare Infinity or NaN
    back = {k: from_strict(v) for k, v in json.loads(text).items()}
    assert back["focus_m"] == math.inf and back["shift"] == -math.inf and math.isnan(back["bad"])
    assert back["fno"] == 2.8 and back["config"] == "tele" and back["3"] == [1.0, 2]
    assert from_strict("infinity") == "infinity"  # only the three strings strict_json writes
    assert jsonable(data)["focus_m"] is None and jsonable(data)["config"] == "tele"
