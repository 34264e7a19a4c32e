"""A lens with poses (an as-built lens from `lensim calibrate`) through the user story:
`lensim dataset make --lens as_built.yaml` renders the pairs through its posed banks
(lensim.render.posed.sensor_banks) and records them; `lensim train` of a PSF-informed
network computes each crop's Wiener stage with those banks at the crop's place on the
sensor; `lensim evaluate` gives them to the Wiener oracle and to the network's stage;
`lensim restore RUN` (and with --lens as_built.yaml) gives them to the stage of a photo.

Tiny sizes: the tiny camera's sensor (128 x 96 pixels) and photos, banks of 3 fields and 2
wavelengths, a width-8 network trained 2 steps."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from lensim.data.pairs import crop_capture
from lensim.images import read_image, write_image
from lensim.psf.bank import PSFBank
from lensim.render.mapping import native_mapping
from lensim.restore import psf_stage
from lensim.restore.psf_stage import WienerStage, cache_folder, cached_path, wiener_channels
from lensim.sensor.profile import load_sensor
from tests.cli_runner import run_cli
from tests.tiny_camera import tiny_camera

pytestmark = pytest.mark.usefixtures("one_torch_thread")

BANK = ["--fields", "3", "--wavelengths-nm", "500,600", "--pupil-samples", "48"]
TRAIN = ["--arch", "psfnet", "--width", "8", "--crop", "32", "--batch-size", "2", "--val-fraction", "0.5"]
TRAIN += ["--epochs", "1", "--steps-per-epoch", "2", "--threads", "1", "--quiet"]


def _as_built(path: Path) -> Path:
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens

    save_lens(perturbed_lens(load_lens("cooke_triplet", warn=False), {"e2.decentre_x": 0.03}), path)
    return path


@pytest.fixture(scope="module")
def story(tmp_path_factory) -> dict:
    """Pairs of an as-built lens made and a PSF-informed network trained on them, through the CLI."""
    base = tmp_path_factory.mktemp("posed")
    sharp, sensor_file, _, _ = tiny_camera(base)
    as_built = _as_built(base / "as_built.yaml")
    mp = pytest.MonkeyPatch()
    capsys = _Capture()
    mp.setenv("LENSIM_CACHE", str(base / "cache"))
    pairs, run = base / "pairs", base / "run"
    args = ["dataset", "make", str(sharp), "--lens", str(as_built), "--sensor", str(sensor_file), "-o", str(pairs)]
    code, _, err = run_cli([*args, "--crops", "2", "--size", "48", *BANK, "--quiet"], capsys, mp)
    assert code == 0, err
    code, _, err = run_cli(["train", str(pairs), "-o", str(run), *TRAIN], capsys, mp)
    assert code == 0, err
    yield {"base": base, "pairs": pairs, "run": run, "as_built": as_built, "sensor_file": sensor_file, "mp": mp}
    mp.undo()


class _Capture:
    """capsys for a module fixture: run_cli reads it twice; nothing is checked here."""

    def readouterr(self) -> tuple[str, str]:
        return "", ""


def _banks(manifest: dict) -> tuple[dict[str, PSFBank], PSFBank]:
    """(the posed banks by source, the lens's own bank) the manifest names."""
    return {k: PSFBank.load(v) for k, v in manifest["posed_banks"].items()}, PSFBank.load(manifest["bank"])


def _spy(monkeypatch, module, name: str) -> list:
    """Record the bank argument (third) of every call of module.name; the call goes through."""
    calls: list = []
    real = getattr(module, name)

    def spy(*args, **kwargs):
        calls.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, spy)
    return calls


def _folders(bank) -> dict[str, str] | str:
    return {k: str(b.directory) for k, b in bank.items()} if isinstance(bank, dict) else str(bank.directory)


def _stages(calls: list, posed: dict[str, str]) -> list[dict[str, str]]:
    """The banks by source of the stage's calls (wiener_channels also calls itself with each
    source's bank: those must be posed banks)."""
    assert all(_folders(b) in posed.values() for b in calls if not isinstance(b, dict))
    return [_folders(b) for b in calls if isinstance(b, dict)]


def test_pairs_of_a_lens_with_poses_record_its_posed_banks_and_train_with_their_stage(story):
    manifest = json.loads((story["pairs"] / "manifest.json").read_text())
    posed, single = _banks(manifest)
    assert len(posed) == 8 and str(single.directory) not in manifest["posed_banks"].values()
    sensor = load_sensor(str(story["sensor_file"]))
    model_config = json.loads((story["run"] / "config.json").read_text())
    stage = WienerStage.from_dict(model_config.get("stage"))
    folder = cache_folder(story["pairs"], stage)
    assert json.loads((folder / "stage.json").read_text())["bank"] == manifest["posed_banks"]
    differs = 0
    for rec in manifest["records"]:
        for cr in rec["crops"]:
            x, _ = read_image(story["pairs"] / cr["input"])
            mapping = native_mapping(48, 48, sensor, cr["sensor_top"], cr["sensor_left"])
            cached, _ = read_image(cached_path(folder, story["pairs"] / cr["input"]))
            want = wiener_channels(x, mapping, posed, crop_capture(rec, cr), stage).clamp(0, 1)
            assert (cached - want).abs().max() <= 1.0 / 65535 + 1e-6
            turned = wiener_channels(x, mapping, single, crop_capture(rec, cr), stage).clamp(0, 1)
            differs += int((cached - turned).abs().max() > 0.01)
    assert differs == sum(len(r["crops"]) for r in manifest["records"])


def test_evaluate_gives_the_oracle_and_the_network_the_posed_banks(story, tmp_path, capsys, monkeypatch):
    from lensim.evaluate import baselines

    manifest = json.loads((story["pairs"] / "manifest.json").read_text())
    oracle = _spy(monkeypatch, baselines, "wiener")
    stages = _spy(monkeypatch, psf_stage, "wiener_channels")
    args = ["evaluate", "--pairs", str(story["pairs"]), "--methods", "input,wiener,model", "--model"]
    code, out, err = run_cli([*args, str(story["run"]), "--json"], capsys, monkeypatch)
    assert code == 0, err
    posed_folders = set(manifest["posed_banks"].values())
    assert oracle and {str(b.directory) for b in oracle} <= posed_folders  # each source's bank, none other
    top = _stages(stages, manifest["posed_banks"])
    assert top and all(b == manifest["posed_banks"] for b in top)
    posed = json.loads(out)["methods"]
    code, out, err = run_cli([*args, str(story["run"]), "--json", "--bank", manifest["bank"]], capsys, monkeypatch)
    assert code == 0, err
    single = json.loads(out)["methods"]
    assert all(single[m]["psnr_db"] != posed[m]["psnr_db"] for m in ("wiener", "model"))


def test_restore_of_the_run_takes_its_posed_banks(story, tmp_path, capsys, monkeypatch):
    """A photo restored by the run, by itself and with --lens as_built.yaml (its pairs'
    banks, none computed), and with --lens another as-built lens (that lens's posed banks)."""
    import lensim.restore.universal as uni
    from lensim.calibrate.tolerances import perturbed_lens
    from lensim.optics.lens_file import load_lens, save_lens
    from lensim.psf.bank import BankSettings, get_bank

    manifest = json.loads((story["pairs"] / "manifest.json").read_text())
    monkeypatch.setenv("LENSIM_CACHE", str(story["base"] / "cache"))
    photo = tmp_path / "photo.png"
    write_image(photo, torch.rand(3, 96, 128, generator=torch.Generator().manual_seed(0)), 8)
    stages = _spy(monkeypatch, psf_stage, "wiener_channels")
    banks_before = len(list((story["base"] / "cache").rglob("manifest.json")))
    outs = []
    for extra in ([], ["--lens", str(story["as_built"])]):
        out = tmp_path / f"out{len(outs)}"
        code, _, err = run_cli(["restore", str(story["run"]), str(photo), "-o", str(out), *extra], capsys, monkeypatch)
        assert code == 0, err
        outs.append(read_image(out / "photo.png")[0])
    assert _stages(stages, manifest["posed_banks"]) == [manifest["posed_banks"]] * 2
    assert torch.equal(outs[0], outs[1])
    assert len(list((story["base"] / "cache").rglob("manifest.json"))) == banks_before
    other = tmp_path / "other.yaml"
    save_lens(perturbed_lens(load_lens("cooke_triplet", warn=False), {"e2.decentre_y": -0.02}), other)
    tiny = BankSettings(fields=3, wavelengths_nm=(500, 600), pupil_samples=48)

    def cheap(lens, sensor, fno, focus_m, workers=1, progress=None):  # the zero-shot bank, at tiny settings
        return get_bank(lens, sensor.pixel_pitch_um, tiny, response=sensor.spectral_response)

    monkeypatch.setattr(uni, "zero_shot_bank", cheap)
    code, _, err = run_cli(
        ["restore", str(story["run"]), str(photo), "-o", str(tmp_path / "other"), "--lens", str(other)],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    other_banks = [_folders(b) for b in stages if isinstance(b, dict)][2:]
    assert len(other_banks) == 1 and len(other_banks[0]) == 8
    assert not set(other_banks[0].values()) & set(manifest["posed_banks"].values())


def test_a_bank_or_a_grid_for_a_lens_with_poses_is_one_line(story, tmp_path, capsys, monkeypatch):
    manifest = json.loads((story["pairs"] / "manifest.json").read_text())
    sharp = story["base"] / "sharp"
    base = ["dataset", "make", str(sharp), "--sensor", str(story["sensor_file"]), "--size", "48", "--quiet"]
    for extra, named in (
        (["--bank", manifest["bank"]], "--bank"),
        (["--lens", str(story["as_built"]), "--fno", "4,5.6"], "--lens"),
    ):
        code, _, err = run_cli([*base, *extra, "-o", str(tmp_path / "p")], capsys, monkeypatch)
        assert code == 2 and len(err.strip().splitlines()) == 1 and named in err and "poses" in err, err
        assert not (tmp_path / "p").exists()


def test_simulate_renders_a_lens_with_poses_through_its_posed_banks(story, tmp_path, capsys, monkeypatch):
    photo = story["base"] / "sharp" / "coffee.png"  # the tiny sensor's size
    args = ["simulate", str(photo), "--lens", str(story["as_built"]), "--sensor", str(story["sensor_file"]), *BANK]
    code, _, err = run_cli([*args, "-o", str(tmp_path / "sim"), "--quiet"], capsys, monkeypatch)
    assert code == 0, err
    folders = json.loads((tmp_path / "sim" / "coffee.json").read_text())["bank"]
    manifest = json.loads((story["pairs"] / "manifest.json").read_text())
    assert set(folders) == set(manifest["posed_banks"]) and len(set(folders.values())) == 8
    for extra, named in ((["--distortion"], "--distortion"), (["--bank", manifest["bank"]], "--bank")):
        code, _, err = run_cli([*args, *extra, "-o", str(tmp_path / "bad"), "--quiet"], capsys, monkeypatch)
        assert code == 2 and len(err.strip().splitlines()) == 1 and named in err and "poses" in err, err
        assert not (tmp_path / "bad").exists()


def test_tolerance_pairs_about_a_lens_with_poses_restore_with_its_posed_banks(story, tmp_path, capsys, monkeypatch):
    """Tolerance draws about an as-built lens: the pairs record the as-built lens's posed
    banks (the same folders its own pairs have), what a restoration of a run trained on
    them takes by default, while each pair's stage stays its own draw's."""
    from lensim.restore.psf_stage import network_bank, stage_bank_entry

    tol = tmp_path / "tol.yaml"
    tol.write_text("elements: {'2': {decentre_mm: 0.01}}\n")
    pairs = tmp_path / "pairs"
    args = ["dataset", "make", str(story["base"] / "sharp"), "--lens", str(story["as_built"]), "-o", str(pairs)]
    args += ["--sensor", str(story["sensor_file"]), "--size", "48", "--crops", "1", *BANK]
    code, _, err = run_cli([*args, "--tolerances", str(tol), "--tolerance-draws", "1"], capsys, monkeypatch)
    assert code == 0, err
    manifest = json.loads((pairs / "manifest.json").read_text())
    own = json.loads((story["pairs"] / "manifest.json").read_text())
    assert manifest["posed_banks"] == own["posed_banks"] and manifest["bank"] == own["bank"]
    assert _folders(network_bank({"dataset": str(pairs)})) == own["posed_banks"]
    assert stage_bank_entry(manifest) == {"tolerance_draw": [manifest["tolerances"]["draws"][0]["bank"]]}
