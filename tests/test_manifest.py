"""The one pairs-manifest and split reader: every defect is one InputError line naming the
file and the field, before any work starts."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lensim.data.manifest import read_held_out, read_pairs_manifest
from lensim.errors import InputError

GOOD = {
    "format": "lensim-pairs",
    "sensor": {"name": "s", "resolution": [64, 48]},
    "records": [
        {"source": "a.png", "crops": [{"input": "i.png", "target": "t.png", "sensor_top": 0, "sensor_left": 2}]}
    ],
}


def _write(folder: Path, name: str, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)
    return folder


def _one_line_error(call, *args) -> str:
    with pytest.raises(InputError) as err:
        call(*args)
    text = str(err.value)
    assert "\n" not in text
    return text


def test_a_good_manifest_is_returned_as_written(tmp_path: Path):
    assert read_pairs_manifest(_write(tmp_path, "manifest.json", json.dumps(GOOD))) == GOOD


@pytest.mark.parametrize(
    "text, field",
    [
        ("{not json", None),
        ("[1, 2]", None),
        (json.dumps({**GOOD, "format": "lensim-psf-bank"}), "format"),
        (json.dumps({**GOOD, "sensor": {"resolution": [64]}}), "sensor.resolution"),
        (json.dumps({**GOOD, "sensor": "apsc"}), "sensor.resolution"),
        (json.dumps({**GOOD, "records": []}), "records"),
        (json.dumps({**GOOD, "records": [{"source": "a.png", "crops": []}]}), "records[0].crops"),
        (json.dumps({**GOOD, "records": [{"crops": [{"input": "i.png"}]}]}), "records[0].crops[0]"),
    ],
)
def test_defective_manifests_name_the_file_and_field(tmp_path: Path, text: str, field: str | None):
    folder = _write(tmp_path / "pairs", "manifest.json", text)
    message = _one_line_error(read_pairs_manifest, folder)
    prefix = str(folder / "manifest.json") + (f": {field}:" if field else ":")
    assert message.startswith(prefix), message


def test_missing_folder_or_manifest(tmp_path: Path):
    assert "no such folder" in _one_line_error(read_pairs_manifest, tmp_path / "nowhere")
    message = _one_line_error(read_pairs_manifest, tmp_path)
    assert message.startswith(str(tmp_path / "manifest.json")) and "no such file" in message


def test_held_out_photos_of_a_run(tmp_path: Path):
    run = _write(tmp_path / "run", "split.json", json.dumps({"train": ["a.png"], "val": ["b.png"]}))
    assert read_held_out(run) == ["b.png"]
    assert "missing" in _one_line_error(read_held_out, tmp_path)
    for text, expected in (
        ("{", "could not parse"),
        ('{"val": "b.png"}', "val: expected"),
        ('{"val": []}', "val: is empty"),
    ):
        _write(run, "split.json", text)
        message = _one_line_error(read_held_out, run)
        assert message.startswith(str(run / "split.json")) and expected in message, message
