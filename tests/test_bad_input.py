"""Bad lens files on the command line: exit status 2 and one line on stderr that names the
file and the field and says what was expected. Rays that miss a surface off the chief
ray are vignetted, not errors."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cli_runner import run_cli

COOKE = yaml.safe_load(
    (Path(__file__).resolve().parents[1] / "lensim" / "assets" / "lenses" / "cooke_triplet.yaml").read_text()
)


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    return lines[0]


def cooke(**changes) -> dict:
    d = copy.deepcopy(COOKE)
    d.update(changes)
    return d


def steep_lens(fields: list[float]) -> dict:
    """A plano-convex lens (R = 5 mm, n = 1.5) 20 mm behind a 12 mm stop: rays above 5 mm
    miss its front surface; the chief ray misses it beyond about 14 degrees."""
    return {
        "name": "steep",
        "aperture": {"type": "epd", "value": 12.0},
        "fields": {"type": "angle", "values": fields},
        "wavelengths": {"nm": [550.0]},
        "surfaces": [
            {"thickness": 20.0, "stop": True},
            {"radius": 5.0, "thickness": 3.0, "material": {"n": 1.5}},
            {"thickness": 8.0},
        ],
    }


def tir_lens() -> dict:
    """A glass block (n = 1.9) whose curved exit face reflects the 40 degree chief ray
    totally (the axial field passes)."""
    return {
        "name": "tir",
        "aperture": {"type": "epd", "value": 2.0},
        "fields": {"type": "angle", "values": [0.0, 40.0]},
        "wavelengths": {"nm": [550.0]},
        "surfaces": [
            {"thickness": 5.0, "stop": True},
            {"thickness": 10.0, "material": {"n": 1.9}},
            {"radius": 12.0, "thickness": 30.0},
        ],
    }


def _set(d: dict, path: tuple, value) -> dict:
    node = d
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return d


def _surface(i: int, **kv) -> dict:
    d = cooke()
    d["surfaces"][i].update(kv)
    return d


def _no_stop() -> dict:
    d = cooke()
    d["surfaces"][3].pop("stop")
    return d


def _mirror(thickness: float) -> dict:
    return {
        "name": "mirror",
        "aperture": {"type": "epd", "value": 20.0},
        "wavelengths": {"nm": [550.0]},
        "surfaces": [{"radius": -200.0, "thickness": thickness, "mirror": True, "stop": True}],
    }


# (case id, file name, lens data (dict) or raw text, command, strings the one line must hold)
CASES = [
    (
        "negative-thickness-in-glass",
        "neg.yaml",
        _surface(0, thickness=-3.0),
        "info",
        [
            "surfaces[0].thickness",
            "expected a positive thickness inside J-SK16, got -3",
            "a ray cannot travel backwards inside glass",
        ],
    ),
    (
        "overlapping-lens-surfaces",
        "overlap.yaml",
        _surface(1, thickness=-6.0),
        "info",
        [
            "surfaces[1].thickness",
            "expected a positive thickness, got -6",
            "surfaces[2] would lie behind surfaces[1]",
            "only a stop or dummy surface may",
        ],
    ),
    (
        "positive-thickness-after-mirror",
        "mirror.json",
        _mirror(100.0),
        "info",
        ["surfaces[0].thickness", "expected a negative", "after a mirror"],
    ),
    (
        "zero-thickness-in-glass",
        "zero.yaml",
        _surface(0, thickness=0.0),
        "info",
        ["surfaces[0].thickness", "expected a non-zero thickness inside J-SK16"],
    ),
    (
        "obscuration-beyond-clear-aperture",
        "obsc.yaml",
        _surface(0, clear_semi_diameter=4.0, obscuration=5.0),
        "info",
        [
            "surfaces[0].obscuration",
            "expected a central obscuration radius >= 0 mm below the clear semi-diameter 4",
            "got 5",
        ],
    ),
    ("missing-stop", "nostop.yaml", _no_stop(), "info", ["surfaces", "expected exactly one stop", "found 0"]),
    (
        "two-stops",
        "twostops.yaml",
        _surface(0, stop=True),
        "info",
        ["surfaces", "expected exactly one stop", "found 2"],
    ),
    (
        "unknown-glass",
        "glass.yaml",
        _surface(2, material="N-BKK7"),
        "info",
        ["surfaces[2].material", "unknown glass 'N-BKK7'", "close names", "N-BK7 (Schott)"],
    ),
    (
        "malformed-number",
        "abc.json",
        _surface(1, radius="abc"),
        "info",
        ["surfaces[1].radius", "expected a number", "'abc'"],
    ),
    (
        "unknown-surface-key",
        "key.yaml",
        _surface(4, thicknes=1.0),
        "info",
        ["surfaces[4]", "unknown key(s) thicknes", "expected some of", "thickness"],
    ),
    (
        "unknown-top-level-key",
        "top.yaml",
        cooke(focal_length=50.0),
        "info",
        ["lens", "unknown key(s) focal_length", "expected some of"],
    ),
    (
        "invalid-yaml",
        "syntax.yaml",
        "name: x\nsurfaces:\n  - {radius: 20, thickness: 3\n  - {radius: -20}\n",
        "info",
        ["syntax", "not valid YAML"],
    ),
    (
        "invalid-json",
        "syntax.json",
        '{"name": "x", "surfaces": [{"radius": 20,, "thickness": 3}]}',
        "info",
        ["syntax", "not valid JSON", "line 1 column 42"],
    ),
    (
        "wavelength-out-of-range",
        "wl.yaml",
        _set(cooke(), ("wavelengths", "nm"), [100.0, 550.0, 650.0]),
        "info",
        ["wavelengths.nm[0]", "expected a wavelength between 200 and 15000 nm", "got 100 nm"],
    ),
    (
        "chief-ray-misses-a-surface-spot",
        "steep.yaml",
        steep_lens([0.0, 30.0]),
        "spot",
        ["fields", "chief ray at field 30 deg", "misses the surface", "expected a field inside the lens's coverage"],
    ),
    (
        "chief-ray-misses-a-surface-plot",
        "steep.yaml",
        steep_lens([0.0, 30.0]),
        "plot",
        ["fields", "chief ray at field 30 deg", "misses the surface", "expected a field inside the lens's coverage"],
    ),
    (
        "total-internal-reflection",
        "tir.yaml",
        tir_lens(),
        "spot",
        ["fields", "chief ray at field 40 deg", "totally internally reflected", "expected a field inside"],
    ),
    (
        "field-beyond-coverage-spot",
        "wide.yaml",
        _set(cooke(), ("fields", "values"), [0.0, 60.0]),
        "spot",
        ["fields", "chief ray at field 60 deg", "expected a field inside the lens's coverage"],
    ),
    (
        "field-beyond-coverage-info",
        "wide.yaml",
        _set(cooke(), ("fields", "values"), [0.0, 60.0]),
        "info",
        ["fields", "chief ray at field 60 deg"],
    ),
]


def _write(tmp_path: Path, name: str, content) -> Path:
    path = tmp_path / name
    if isinstance(content, str):
        path.write_text(content)
    elif name.endswith(".json"):
        path.write_text(json.dumps(content))
    else:
        path.write_text(yaml.safe_dump(content, sort_keys=False))
    return path


def _args(command: str, path: Path, tmp_path: Path) -> list[str]:
    if command == "info":
        return ["lens", "info", str(path)]
    if command == "spot":
        return ["lens", "spot", str(path), "--json"]
    return ["lens", "plot", str(path), "-o", str(tmp_path / "layout.png")]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_lens_file_gives_one_line_and_status_2(case, tmp_path, capsys, monkeypatch):
    _, name, content, command, expected = case
    path = _write(tmp_path, name, content)
    code, out, err = run_cli(_args(command, path, tmp_path), capsys, monkeypatch)
    assert code == 2, (out, err)
    line = one_error_line(err)
    assert str(path) in line
    for text in expected:
        assert text in line, f"{text!r} not in {line!r}"
    assert not (tmp_path / "layout.png").exists()


def test_invalid_yaml_names_the_line(tmp_path, capsys, monkeypatch):
    path = _write(tmp_path, "syntax.yaml", "name: x\nsurfaces:\n  - {radius: 20, thickness: 3\n  - {radius: -20}\n")
    code, _, err = run_cli(["lens", "info", str(path)], capsys, monkeypatch)
    assert code == 2
    assert "line 4" in one_error_line(err)


def test_marginal_rays_missing_a_surface_are_vignetted(tmp_path, capsys, monkeypatch):
    path = _write(tmp_path, "steep.yaml", steep_lens([0.0, 5.0]))
    code, out, err = run_cli(
        ["lens", "spot", str(path), "--json", "-o", str(tmp_path / "spot.png")], capsys, monkeypatch
    )
    assert code == 0, err
    fields = json.loads(out)["fields"]
    for f in fields:
        w = f["wavelengths"][0]
        assert 0 < w["rays_reaching_image"] < w["rays"]  # the outer rings miss the R = 5 mm surface
        assert f["rms_radius_um"] is not None and f["rms_radius_um"] > 0
    # on axis, exactly the rays beyond 5 mm of the 6 mm pupil radius are lost: hexapolar
    # rings 7 and 8 of 8 (r = 5.25, 6 mm), 42 + 48 rays
    assert fields[0]["wavelengths"][0]["rays_reaching_image"] == 217 - 90
    assert (tmp_path / "spot.png").stat().st_size > 10_000
    code, _, err = run_cli(["lens", "plot", str(path), "-o", str(tmp_path / "layout.png")], capsys, monkeypatch)
    assert code == 0, err
    assert (tmp_path / "layout.png").stat().st_size > 10_000


def test_bad_file_in_a_real_process(tmp_path):
    path = _write(tmp_path, "mirror.yaml", _mirror(100.0))
    r = subprocess.run(
        [sys.executable, "-m", "lensim", "lens", "spot", str(path), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2
    assert r.stdout == ""
    line = one_error_line(r.stderr)
    assert f"{path}: surfaces[0].thickness: expected a negative" in line
