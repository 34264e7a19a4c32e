"""Hostile input files, every command that reads them: lens files (.yaml/.json/.zmx/.seq),
sensor profiles, photos, camera raw files, bank folders, pairs folders, run folders and
checkpoints, report.json. Each case must end in exit status 2 with one plain line on
stderr that names the file (and the field), no traceback, and nothing new on disk
(tests/hostile_world.py). The options and output paths are in test_hostile_options.py."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from hostile_world import ASSETS, Case, binary, case, check_case, copy_of, edited, folder, image, text

COOKE_TEXT = (ASSETS / "lenses" / "cooke_triplet.yaml").read_text()
SENSOR_TEXT = (ASSETS / "sensors" / "apsc_mirrorless.yaml").read_text()
COOKE = yaml.safe_load(COOKE_TEXT)
SENSOR = yaml.safe_load(SENSOR_TEXT)
JUNK = bytes(range(256)) * 8


def lens_with(name: str, **surface_changes: object) -> object:
    """The Cooke triplet with surfaces[i] changed: keys like s1_material=..."""
    d = json.loads(json.dumps(COOKE))
    for key, value in surface_changes.items():
        if key.startswith("s") and "_" in key:
            i, attr = key[1:].split("_", 1)
            d["surfaces"][int(i)][attr] = value
        else:
            d[key] = value
    return text(name, yaml.safe_dump(d, sort_keys=False) if not name.endswith(".json") else json.dumps(d))


def sensor_with(name: str, **changes: object) -> object:
    d = dict(SENSOR)
    d.update(changes)
    return text(name, yaml.safe_dump(d, sort_keys=False))


INFO = "lens info {t}/"
BANK_WITH_SENSOR = "psf bank --lens cooke_triplet -o {t}/bank --sensor {t}/"
SIM = "simulate --no-blur -o {t}/out {t}/"

LENS_FILES = [
    case("lens-missing", INFO + "nofile.yaml", "nofile.yaml"),
    case("lens-unknown-builtin", "lens info cooke_tripplet", "cooke_tripplet"),
    case("lens-folder-yaml", INFO + "x.yaml", "x.yaml", "folder", make=folder("x.yaml")),
    case("lens-folder-json", INFO + "x.json", "x.json", "folder", make=folder("x.json")),
    case("lens-folder-zmx", INFO + "x.zmx", "x.zmx", "folder", make=folder("x.zmx")),
    case("lens-folder-seq", INFO + "x.seq", "x.seq", "folder", make=folder("x.seq")),
    case("lens-binary-yaml", INFO + "b.yaml", "b.yaml", make=binary("b.yaml", JUNK)),
    case("lens-binary-json", INFO + "b.json", "b.json", make=binary("b.json", JUNK)),
    case("lens-binary-zmx", INFO + "b.zmx", "b.zmx", make=binary("b.zmx", JUNK)),
    case("lens-binary-seq", INFO + "b.seq", "b.seq", make=binary("b.seq", JUNK)),
    case("lens-utf16-yaml", INFO + "u.yaml", "u.yaml", make=text("u.yaml", COOKE_TEXT, "utf-16")),
    case("lens-utf16-json", INFO + "u.json", "u.json", make=text("u.json", json.dumps(COOKE), "utf-16")),
    case("lens-utf16-seq", INFO + "u.seq", "u.seq", make=text("u.seq", "RDM\nLEN\nEPD 10\nS 20 3 BK7\n", "utf-16")),
    case("lens-empty-yaml", INFO + "e.yaml", "e.yaml", make=text("e.yaml", "")),
    case("lens-empty-zmx", INFO + "e.zmx", "e.zmx", make=text("e.zmx", "")),
    case("lens-empty-seq", INFO + "e.seq", "e.seq", make=text("e.seq", "")),
    case("lens-list-yaml", INFO + "l.yaml", "l.yaml", make=text("l.yaml", "- 1\n- 2\n")),
    case("lens-number-json", INFO + "n.json", "n.json", make=text("n.json", "42")),
    case("lens-unknown-suffix", INFO + "l.txt", "l.txt", make=text("l.txt", COOKE_TEXT)),
    case("lens-bracket-name-missing", INFO + "'bad[bold]name.yaml'", "bad[bold]name.yaml"),
    case("lens-bracket-name-syntax", INFO + "'bad[red]x.yaml'", "bad[red]x.yaml", make=text("bad[red]x.yaml", "a: [")),
    case(
        "lens-material-n-below-1",
        INFO + "n.yaml",
        "n.yaml",
        "surfaces[0].material",
        "0.5",
        make=lens_with("n.yaml", s0_material={"n": 0.5}),
    ),
    case(
        "lens-material-n-nan",
        INFO + "n.yaml",
        "n.yaml",
        "surfaces[0].material",
        make=lens_with("n.yaml", s0_material={"n": float("nan")}),
    ),
    case(
        "lens-huge-thickness",
        INFO + "h.yaml",
        "h.yaml",
        "surfaces[5].thickness",
        make=lens_with("h.yaml", s5_thickness=1e12),
    ),
    case(
        "lens-number-key",
        INFO + "k.yaml",
        "k.yaml",
        "aperture",
        "unknown key(s) 10.0",
        make=text("k.yaml", COOKE_TEXT.replace("value: 10.0}", "10.0}")),
    ),
    case("lens-number-note", INFO + "n.yaml", "n.yaml", "notes", "[1.5]", make=lens_with("n.yaml", notes=[1.5])),
    case("lens-text-notes", INFO + "n.yaml", "n.yaml", "notes", "'a note'", make=lens_with("n.yaml", notes="a note")),
    case(
        "lens-huge-object-distance",
        INFO + "h.yaml",
        "h.yaml",
        "object.distance",
        make=lens_with("h.yaml", object={"distance": 1e15}),
    ),
    case(
        "lens-nan-radius",
        INFO + "r.yaml",
        "r.yaml",
        "surfaces[1].radius",
        make=lens_with("r.yaml", s1_radius=float("nan")),
    ),
    case(
        "lens-inf-thickness",
        INFO + "r.yaml",
        "r.yaml",
        "surfaces[1].thickness",
        make=lens_with("r.yaml", s1_thickness=float("inf")),
    ),
    case(
        "lens-zero-aperture",
        INFO + "a.yaml",
        "a.yaml",
        "aperture",
        make=lens_with("a.yaml", aperture={"type": "epd", "value": 0}),
    ),
    case(
        "lens-unknown-aperture-type",
        INFO + "a.yaml",
        "a.yaml",
        "aperture",
        make=lens_with("a.yaml", aperture={"type": "banana", "value": 5}),
    ),
    case(
        "lens-no-wavelengths",
        INFO + "w.yaml",
        "w.yaml",
        "wavelengths",
        make=lens_with("w.yaml", wavelengths={"nm": []}),
    ),
    case(
        "lens-primary-out-of-range",
        INFO + "w.yaml",
        "w.yaml",
        "primary",
        make=lens_with("w.yaml", wavelengths={"nm": [550.0], "primary": 3}),
    ),
    case(
        "lens-config-negative-glass",
        INFO + "c.yaml",
        "c.yaml",
        "configurations.tele",
        "surfaces[0].thickness",
        make=lens_with(
            "c.yaml", configurations={"wide": {"thicknesses": {0: 3.0}}, "tele": {"thicknesses": {0: -1.0}}}
        ),
    ),
    case(
        "lens-config-index-out-of-range",
        INFO + "c.yaml",
        "c.yaml",
        "configurations.wide.thicknesses",
        "0..5",
        "9",
        make=lens_with("c.yaml", configurations={"wide": {"thicknesses": {9: 1.0}}}),
    ),
    case(
        "lens-config-index-not-a-number",
        INFO + "c.json",
        "c.json",
        "configurations.wide.thicknesses",
        "'s1'",
        make=lens_with("c.json", configurations={"wide": {"thicknesses": {"s1": 1.0}}}),
    ),
    case(
        "lens-config-thickness-text",
        INFO + "c.yaml",
        "c.yaml",
        "configurations.wide.thicknesses.1",
        "'far'",
        make=lens_with("c.yaml", configurations={"wide": {"thicknesses": {1: "far"}}}),
    ),
    case(
        "lens-config-overlap",
        INFO + "c.yaml",
        "c.yaml",
        "configurations.wide",
        "surfaces[1].thickness",
        make=lens_with("c.yaml", configurations={"wide": {"thicknesses": {1: -8.0}}}),
    ),
    case(
        "lens-config-list",
        INFO + "c.yaml",
        "c.yaml",
        "configurations",
        "mapping",
        make=lens_with("c.yaml", configurations=[{"thicknesses": {1: 3.0}}]),
    ),
    case(
        "lens-config-unknown-key",
        INFO + "c.yaml",
        "c.yaml",
        "configurations.wide",
        "thicknesses",
        make=lens_with("c.yaml", configurations={"wide": {"thickness": {1: 3.0}}}),
    ),
    case("lens-surfaces-not-a-list", INFO + "s.yaml", "s.yaml", "surfaces", make=lens_with("s.yaml", surfaces=5)),
    case("lens-convert-bad-input", "lens convert {t}/b.seq -o {t}/out.yaml", "b.seq", make=binary("b.seq", JUNK)),
    case("lens-plot-utf16", "lens plot {t}/u.yaml -o {t}/p.png", "u.yaml", make=text("u.yaml", COOKE_TEXT, "utf-16")),
    case("lens-spot-folder", "lens spot {t}/x.zmx --json", "x.zmx", make=folder("x.zmx")),
    case("psf-compute-binary-lens", "psf compute {t}/b.yaml", "b.yaml", make=binary("b.yaml", JUNK)),
    case("simulate-lens-folder", "simulate {w.photo} -o {t}/out --lens {t}/x.yaml", "x.yaml", make=folder("x.yaml")),
    case(
        "dataset-lens-utf16",
        "dataset make {w.photos} -o {t}/d --bank {w.bank} --lens {t}/u.yaml",
        "u.yaml",
        make=text("u.yaml", COOKE_TEXT, "utf-16"),
    ),
    case("restore-lens-missing", "restore {w.run} {w.photo} -o {t}/out --lens {t}/nofile.zmx", "nofile.zmx"),
]

SENSOR_FILES = [
    case("sensor-missing", BANK_WITH_SENSOR + "nofile.yaml", "nofile.yaml"),
    case(
        "sensor-unknown-builtin", "psf bank --lens cooke_triplet -o {t}/bank --sensor apsc_mirorless", "apsc_mirorless"
    ),
    case("sensor-folder", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=folder("s.yaml")),
    case("sensor-binary", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=binary("s.yaml", JUNK)),
    case("sensor-utf16", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=text("s.yaml", SENSOR_TEXT, "utf-16")),
    case("sensor-empty", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=text("s.yaml", "")),
    case("sensor-list", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=text("s.yaml", "- a\n")),
    case("sensor-syntax", BANK_WITH_SENSOR + "s.yaml", "s.yaml", make=text("s.yaml", "ccm: [[1, 2]\n")),
    case(
        "sensor-ccm-2x2",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "ccm",
        "[[1, 2], [3, 4]]",
        make=sensor_with("s.yaml", ccm=[[1, 2], [3, 4]]),
    ),
    case(
        "sensor-ccm-strings",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "ccm",
        "'a'",
        make=sensor_with("s.yaml", ccm=[["a", "b", "c"]] * 3),
    ),
    case(
        "sensor-unknown-response",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "spectral_response",
        "Banana 9000",
        make=sensor_with("s.yaml", spectral_response="Banana 9000"),
    ),
    case(
        "sensor-pitch-zero",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "pixel_pitch_um",
        make=sensor_with("s.yaml", pixel_pitch_um=0),
    ),
    case(
        "sensor-pitch-negative",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "pixel_pitch_um",
        make=sensor_with("s.yaml", pixel_pitch_um=-3.9),
    ),
    case(
        "sensor-pitch-nan",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "pixel_pitch_um",
        make=sensor_with("s.yaml", pixel_pitch_um=float("nan")),
    ),
    case(
        "sensor-resolution-zero",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "resolution",
        make=sensor_with("s.yaml", resolution=[0, 4000]),
    ),
    case(
        "sensor-bayer-unknown",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "bayer_pattern",
        make=sensor_with("s.yaml", bayer_pattern="RGBW"),
    ),
    case(
        "sensor-white-below-black",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "white_level",
        make=sensor_with("s.yaml", white_level=100),
    ),
    case(
        "sensor-unknown-key",
        BANK_WITH_SENSOR + "s.yaml",
        "s.yaml",
        "pixel_pitch",
        make=sensor_with("s.yaml", pixel_pitch=3.9),
    ),
    case(
        "sensor-bracket-name",
        BANK_WITH_SENSOR + "'cam[bold]x.yaml'",
        "cam[bold]x.yaml",
        make=sensor_with("cam[bold]x.yaml", ccm=[[1, 2], [3, 4]]),
    ),
    case(
        "simulate-sensor-utf16",
        "simulate {w.photo} -o {t}/out --sensor {t}/s.yaml",
        "s.yaml",
        make=text("s.yaml", SENSOR_TEXT, "utf-16"),
    ),
    case(
        "dataset-sensor-folder",
        "dataset make {w.photos} -o {t}/d --bank {w.bank} --sensor {t}/s.yaml",
        "s.yaml",
        make=folder("s.yaml"),
    ),
    case(
        "restore-sensor-binary",
        "restore {w.run} {w.photo} -o {t}/out --sensor {t}/s.yaml",
        "s.yaml",
        make=binary("s.yaml", JUNK),
    ),
    case("develop-sensor-missing", "develop {w.dng} -o {t}/out --sensor {t}/s.yaml", "s.yaml"),
]

RGB = np.full((24, 32, 3), 128, np.uint8)
IMAGES = [
    case("image-missing", SIM + "nofile.png", "nofile.png"),
    case("image-folder", SIM + "x.png", "x.png", make=folder("x.png")),
    case("image-text", SIM + "x.png", "x.png", make=text("x.png", "not an image")),
    case("image-empty", SIM + "x.png", "x.png", make=binary("x.png", b"")),
    case(
        "image-truncated-png",
        SIM + "x.png",
        "x.png",
        make=edited("x.png", lambda w: w.photo, lambda p: p.write_bytes(p.read_bytes()[:120])),
    ),
    case(
        "image-cmyk-tiff",
        SIM + "c.tif",
        "c.tif",
        "CMYK",
        make=image("c.tif", np.full((24, 32, 4), 60, np.uint8), photometric="separated"),
    ),
    case(
        "image-cmyk-tiff-black",
        SIM + "k.tif",
        "k.tif",
        "CMYK",
        make=image(
            "k.tif",
            np.dstack([np.zeros((24, 32, 3), np.uint8), np.full((24, 32), 255, np.uint8)]),
            photometric="separated",
        ),
    ),
    case(
        "image-two-channels",
        SIM + "g.tif",
        "g.tif",
        make=image("g.tif", np.zeros((24, 32, 2), np.uint8), photometric="minisblack", planarconfig="contig"),
    ),
    case(
        "image-five-channels",
        SIM + "f.tif",
        "f.tif",
        make=image("f.tif", np.zeros((24, 32, 5), np.uint8), photometric="minisblack", planarconfig="contig"),
    ),
    case("image-transparent-png", SIM + "a.png", "a.png", make=image("a.png", np.zeros((24, 32, 4), np.uint8))),
    case("image-float-nan-tiff", SIM + "n.tif", "n.tif", make=image("n.tif", np.full((24, 32, 3), np.nan, np.float32))),
    case("image-one-pixel", SIM + "one.png", "one.png", make=image("one.png", np.zeros((1, 1, 3), np.uint8))),
    case("image-jpeg-garbage", SIM + "j.jpg", "j.jpg", make=binary("j.jpg", b"\xff\xd8\xff" + JUNK)),
    case("image-bracket-name", SIM + "'p[bold]x.png'", "p[bold]x.png", make=text("p[bold]x.png", "not an image")),
    case("image-raw-to-simulate", "simulate --no-blur -o {t}/out {w.dng}", "shot.dng"),
    case(
        "simulate-second-input-bad",
        "simulate --no-blur -o {t}/out {w.photo} {t}/bad.png",
        "bad.png",
        make=text("bad.png", "not an image"),
    ),
    case(
        "simulate-same-name-twice",
        "simulate --no-blur -o {t}/out {t}/d1/x.png {t}/d2/x.png",
        "x.png",
        make=(image("d1/x.png", RGB), image("d2/x.png", RGB)),
    ),
    case("restore-image-text", "restore {w.run} {t}/x.png -o {t}/out", "x.png", make=text("x.png", "no")),
    case(
        "restore-second-input-bad",
        "restore {w.run} {w.photo} {t}/bad.png -o {t}/out",
        "bad.png",
        make=text("bad.png", "no"),
    ),
    case(
        "restore-same-name-twice",
        "restore {w.run} {t}/d1/x.png {t}/d2/x.png -o {t}/out",
        "x.png",
        make=(image("d1/x.png", RGB), image("d2/x.png", RGB)),
    ),
    case("restore-image-missing", "restore {w.run} {t}/nofile.png -o {t}/out", "nofile.png"),
    case("dataset-no-photos", "dataset make {t}/empty -o {t}/d --bank {w.bank}", "empty", make=folder("empty")),
    case(
        "dataset-photo-text",
        "dataset make {t}/ph -o {t}/d --bank {w.bank}",
        "bad.png",
        make=(copy_of(lambda w: w.photos, "ph"), text("ph/bad.png", "not an image")),
    ),
    case("dataset-photos-missing", "dataset make {t}/typo_dir -o {t}/d", "typo_dir"),
    case("dataset-photos-is-file", "dataset make {w.photo} -o {t}/d --bank {w.bank}", "photo.png"),
]

TRUNCATED_DNG = edited("t.dng", lambda w: w.dng, lambda p: p.write_bytes(p.read_bytes()[:300]))
RAWS = [
    case("raw-info-missing", "raw info {t}/nofile.dng", "nofile.dng"),
    case("raw-info-text", "raw info {t}/x.dng", "x.dng", make=text("x.dng", "not a raw file")),
    case("raw-info-truncated", "raw info {t}/t.dng", "t.dng", make=TRUNCATED_DNG),
    case("raw-info-jpeg-named-dng", "raw info {t}/j.dng", "j.dng", make=binary("j.dng", b"\xff\xd8\xff\xe0" + JUNK)),
    case("raw-info-empty-folder", "raw info {t}/empty", "empty", make=folder("empty")),
    case("raw-info-png", "raw info {w.photo}", "photo.png"),
    case("raw-info-bracket-name", "raw info '{t}/r[bold]x.dng'", "r[bold]x.dng", make=text("r[bold]x.dng", "x")),
    case("develop-truncated", "develop {t}/t.dng -o {t}/out", "t.dng", make=TRUNCATED_DNG),
    case("develop-second-input-bad", "develop {w.dng} {t}/x.dng -o {t}/out", "x.dng", make=text("x.dng", "no")),
    case("develop-png", "develop {w.photo} -o {t}/out", "photo.png"),
    case("sensor-from-raw-missing", "sensor from-raw {t}/nofile.dng --pixel-um 4 -o {t}/cam.yaml", "nofile.dng"),
    case(
        "sensor-from-raw-text",
        "sensor from-raw {t}/x.dng --pixel-um 4 -o {t}/cam.yaml",
        "x.dng",
        make=text("x.dng", "x"),
    ),
    case(
        "sensor-from-raw-dark-missing",
        "sensor from-raw {w.dng} --pixel-um 4 --dark {t}/dark.dng -o {t}/cam.yaml",
        "dark.dng",
    ),
    case(
        "sensor-from-raw-flat-truncated",
        "sensor from-raw {w.dng} --pixel-um 4 --flat {t}/t.dng -o {t}/cam.yaml",
        "t.dng",
        make=TRUNCATED_DNG,
    ),
    case("restore-raw-truncated", "restore {w.run} {t}/t.dng -o {t}/out", "t.dng", make=TRUNCATED_DNG),
    case("restore-raw-folder-empty", "restore {w.run} {t}/empty -o {t}/out", "empty", make=folder("empty")),
]


def _manifest(edit):
    return lambda p: (p / "manifest.json").write_text(edit((p / "manifest.json").read_text()))


def _drop_key(key: str):
    def edit(text: str) -> str:
        d = json.loads(text)
        d.pop(key)
        return json.dumps(d)

    return edit


BANK = lambda w: w.bank  # noqa: E731
DATA = lambda w: w.data  # noqa: E731
RUN = lambda w: w.run  # noqa: E731
SHOW = "psf show {t}/b -o {t}/fig"
BANKS = [
    case("bank-missing", "psf show {t}/nobank -o {t}/fig", "nobank"),
    case("bank-is-file", "psf show {w.photo} -o {t}/fig", "photo.png"),
    case("bank-empty-folder", SHOW, "b", "manifest.json", make=folder("b")),
    case("bank-manifest-corrupt", SHOW, "manifest.json", make=edited("b", BANK, _manifest(lambda s: s[:40]))),
    case("bank-manifest-list", SHOW, "manifest.json", make=edited("b", BANK, _manifest(lambda s: "[1, 2]"))),
    case(
        "bank-manifest-no-fields",
        SHOW,
        "manifest.json",
        "fields",
        make=edited("b", BANK, _manifest(_drop_key("fields"))),
    ),
    case(
        "bank-field-missing", SHOW, "field_0001.npz", make=edited("b", BANK, lambda p: (p / "field_0001.npz").unlink())
    ),
    case(
        "bank-field-truncated",
        SHOW,
        "field_0001.npz",
        make=edited("b", BANK, lambda p: (p / "field_0001.npz").write_bytes((p / "field_0001.npz").read_bytes()[:99])),
    ),
    case(
        "bank-field-text",
        SHOW,
        "field_0000.npz",
        make=edited("b", BANK, lambda p: (p / "field_0000.npz").write_text("hello")),
    ),
    case("simulate-bank-missing", "simulate {w.photo} -o {t}/out --bank {t}/nobank", "nobank"),
    case("simulate-bank-is-file", "simulate {w.photo} -o {t}/out --bank {w.photo}", "photo.png"),
    case("simulate-bank-wrong-pitch", "simulate {w.photo} -o {t}/out --bank {w.bank}", "bank"),
    case("dataset-bank-missing", "dataset make {w.photos} -o {t}/d --bank {t}/nobank", "nobank"),
    case("dataset-bank-empty", "dataset make {w.photos} -o {t}/d --bank {t}/b", "b", make=folder("b")),
    case(
        "dataset-bank-of-other-lens",
        "dataset make {w.photos} -o {t}/d --bank {w.bank} --size 32 --lens double_gauss",
        "--lens",
        "double_gauss",
    ),
    case(
        "dataset-bank-of-other-pitch",
        "dataset make {w.photos} -o {t}/d --bank {w.bank} --size 32 --sensor phone",
        "phone",
    ),
    case("evaluate-bank-empty", "evaluate --pairs {w.data} --bank {t}/b --methods wiener", "b", make=folder("b")),
]

PAIRS = [
    case("train-data-missing", "train {t}/nodata -o {t}/run", "nodata"),
    case("train-data-is-file", "train {w.photo} -o {t}/run", "photo.png"),
    case("train-data-empty", "train {t}/d -o {t}/run", "manifest.json", make=folder("d")),
    case(
        "train-manifest-corrupt",
        "train {t}/d -o {t}/run",
        "manifest.json",
        make=edited("d", DATA, _manifest(lambda s: s[:50])),
    ),
    case(
        "train-manifest-utf16",
        "train {t}/d -o {t}/run",
        "manifest.json",
        make=edited("d", DATA, _manifest(lambda s: s.encode("utf-16").decode("latin-1"))),
    ),
    case(
        "train-manifest-no-records",
        "train {t}/d -o {t}/run",
        "manifest.json",
        "records",
        make=edited("d", DATA, _manifest(_drop_key("records"))),
    ),
    case(
        "train-pair-missing",
        "train {t}/d -o {t}/run --epochs 1 --crop 32",
        "_input.png",
        make=edited("d", DATA, lambda p: [q.unlink() for q in sorted((p / "pairs").glob("*_input.png"))[:1]]),
    ),
    case("evaluate-pairs-missing", "evaluate --pairs {t}/nodata --methods input", "nodata"),
    case(
        "evaluate-manifest-list",
        "evaluate --pairs {t}/d --methods input",
        "manifest.json",
        make=edited("d", DATA, _manifest(lambda s: "[]")),
    ),
    case("ablation-data-missing", "ablation {t}/nodata -o {t}/abl", "nodata"),
    case(
        "dataset-settings-corrupt",
        "dataset make {w.photos} -o {t}/d --bank {w.bank} --crops 1 --size 32",
        "settings.json",
        make=edited("d", DATA, lambda p: (p / "settings.json").write_text("{")),
    ),
]


def _garbage_checkpoint(p):
    (p / "best.pt").write_bytes(JUNK)
    (p / "last.pt").write_bytes(JUNK)


RUNS = [
    case("restore-run-missing", "restore {t}/norun {w.photo} -o {t}/out", "norun"),
    case("restore-run-empty", "restore {t}/r {w.photo} -o {t}/out", "r", make=folder("r")),
    case(
        "restore-checkpoint-garbage",
        "restore {t}/r {w.photo} -o {t}/out",
        "best.pt",
        make=edited("r", RUN, _garbage_checkpoint),
    ),
    case("restore-checkpoint-text", "restore {t}/x.pt {w.photo} -o {t}/out", "x.pt", make=text("x.pt", "hello")),
    case(
        "restore-checkpoint-truncated",
        "restore {t}/r {w.photo} -o {t}/out",
        "best.pt",
        make=edited("r", RUN, lambda p: (p / "best.pt").write_bytes((p / "best.pt").read_bytes()[:2000])),
    ),
    case(
        "evaluate-model-garbage",
        "evaluate --pairs {w.data} --methods model --model {t}/r",
        "best.pt",
        make=edited("r", RUN, _garbage_checkpoint),
    ),
    case(
        "evaluate-held-out-no-split",
        "evaluate --pairs {w.data} --methods input --held-out {t}/r",
        "split.json",
        make=folder("r"),
    ),
    case(
        "evaluate-held-out-split-corrupt",
        "evaluate --pairs {w.data} --methods input --held-out {t}/r",
        "split.json",
        make=edited("r", RUN, lambda p: (p / "split.json").write_text("[1,")),
    ),
    case("train-resume-nothing", "train {w.data} -o {t}/r --resume", "r", make=folder("r")),
    case(
        "train-resume-garbage",
        "train {w.data} -o {t}/r --resume --crop 32",
        "last.pt",
        make=edited("r", RUN, _garbage_checkpoint),
    ),
    case("export-run-missing", "export {t}/norun -o {t}/m.onnx", "norun"),
    case("export-run-empty", "export {t}/r -o {t}/m.onnx", "r", "best.pt", make=folder("r")),
    case("export-checkpoint-text", "export {t}/x.pt -o {t}/m.onnx", "x.pt", make=text("x.pt", "hello")),
    case(
        "export-checkpoint-garbage", "export {t}/r -o {t}/m.onnx", "best.pt", make=edited("r", RUN, _garbage_checkpoint)
    ),
    case(
        "restore-onnx-garbage",
        "restore {t}/m.onnx {w.photo} -o {t}/out --engine onnxruntime",
        "m.onnx",
        "not an ONNX model",
        make=binary("m.onnx", JUNK),
    ),
    case(
        "restore-onnx-empty",
        "restore {t}/m.onnx {w.photo} -o {t}/out --engine onnxruntime",
        "m.onnx",
        make=binary("m.onnx", b""),
    ),
    case("restore-onnx-missing", "restore {t}/m.onnx {w.photo} -o {t}/out --engine onnxruntime", "m.onnx"),
]

REPORTS = [
    case("report-missing-folder", "report {t}/nodemo", "nodemo"),
    case("report-no-json", "report {t}/d", "report.json", make=folder("d")),
    case("report-corrupt", "report {t}/d", "report.json", make=text("d/report.json", '{"metrics": ')),
    case("report-utf16", "report {t}/d", "report.json", make=text("d/report.json", "{}", "utf-16")),
    case("report-list", "report {t}/d", "report.json", make=text("d/report.json", "[1, 2]")),
    case("report-missing-keys", "report {t}/d", "report.json", make=text("d/report.json", '{"metrics": {}}')),
    case("report-json-is-folder", "report {t}/d", "report.json", make=folder("d/report.json")),
]

ALL: list[Case] = LENS_FILES + SENSOR_FILES + IMAGES + RAWS + BANKS + PAIRS + RUNS + REPORTS


@pytest.mark.parametrize("c", ALL, ids=[c.id for c in ALL])
def test_bad_input_file(c: Case, world, tmp_path, capsys, monkeypatch) -> None:
    check_case(c, tmp_path, world, capsys, monkeypatch)


def test_case_ids_are_unique() -> None:
    assert len({c.id for c in ALL}) == len(ALL)
