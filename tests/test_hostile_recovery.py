"""After a refusal or a failure, the corrected command works: inputs the checks must let
through (a planar RGB TIFF, a small photo with the default pupil grid), and failed runs
that leave nothing in the way of the rerun (dataset make, train)."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from cli_runner import run_cli


def test_planar_rgb_tiff_reads_as_the_same_photo(tmp_path) -> None:
    from lensim.images import read_image

    rgb = (np.random.default_rng(3).random((3, 24, 40)) * 65535).astype(np.uint16)
    tifffile.imwrite(tmp_path / "planar.tif", rgb, photometric="rgb", planarconfig="separate")
    tifffile.imwrite(tmp_path / "contig.tif", np.moveaxis(rgb, 0, -1), photometric="rgb", planarconfig="contig")
    planar, bits = read_image(tmp_path / "planar.tif")
    contig, _ = read_image(tmp_path / "contig.tif")
    assert bits == 16 and planar.shape == (3, 24, 40)
    assert np.array_equal(np.round(planar.numpy() * 65535).astype(np.uint16), rgb)
    assert np.array_equal(planar.numpy(), contig.numpy())


def test_small_photo_gets_the_pupil_sampling_it_needs(world, tmp_path, capsys, monkeypatch) -> None:
    """A 48x32 photo spans the APS-C sensor with 490 um pixels: the default pupil grid
    repeats the PSF inside one kernel window; simulate picks a finer grid and says so,
    and an explicit --pupil-samples that is too coarse is named with the value to give."""
    from PIL import Image

    from lensim.psf.bank import BankSettings

    Image.fromarray(np.full((32, 48, 3), 120, np.uint8)).save(tmp_path / "small.png")
    monkeypatch.setenv("LENSIM_CACHE", str(tmp_path / "cache"))
    args = ["simulate", str(tmp_path / "small.png"), "--fields", "2", "--wavelengths-nm", "550", "--quiet"]
    code, _, err = run_cli([*args, "-o", str(tmp_path / "a"), "--pupil-samples", "16"], capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "--pupil-samples" in err and "expected --pupil-samples" in err and not (tmp_path / "a").exists()
    code, _, err = run_cli([*args, "-o", str(tmp_path / "b")], capsys, monkeypatch)
    assert code == 0, err
    assert f"pupil samples raised from {BankSettings.pupil_samples} to" in err
    assert (tmp_path / "b" / "small.png").is_file()


def test_failed_dataset_make_leaves_nothing_in_the_way(world, tmp_path, monkeypatch) -> None:
    """A dataset make that finishes no photo removes its settings record, so the rerun
    with other settings is not refused as a different dataset."""
    import lensim.data.pairs as pairs
    from lensim.psf.bank import PSFBank
    from lensim.sensor.profile import load_sensor

    bank, sensor = PSFBank.load(world.bank), load_sensor("apsc_mirrorless")

    def fail(job):
        raise RuntimeError("killed")

    monkeypatch.setattr(pairs, "make_pairs_for_image", fail)
    with pytest.raises(RuntimeError):
        pairs.make_dataset(world.photos, tmp_path / "d", bank, "apsc_mirrorless", sensor, crops=1, size=32)
    assert not (tmp_path / "d").exists()
    monkeypatch.undo()
    manifest = pairs.make_dataset(world.photos, tmp_path / "d", bank, "apsc_mirrorless", sensor, crops=2, size=32)
    assert manifest["pairs"] == 6


def test_failed_train_leaves_no_run_without_a_checkpoint(world, tmp_path, capsys, monkeypatch) -> None:
    import lensim.restore.train as train_module

    def fail(loop, batches):
        assert (tmp_path / "r" / "config.json").exists()  # the run had started writing
        raise RuntimeError("an unexpected failure")  # (an allocation failure would be one line: test_faults_memory)

    monkeypatch.setattr(train_module, "_train_epoch", fail)
    with pytest.raises(RuntimeError, match="unexpected"):
        run_cli(
            [
                "train",
                str(world.data),
                "-o",
                str(tmp_path / "r"),
                "--epochs",
                "1",
                "--width",
                "4",
                "--depth",
                "2",
                "--crop",
                "32",
                "--quiet",
            ],
            capsys,
            monkeypatch,
        )
    assert not (tmp_path / "r").exists()


def test_input_errors_cross_process_boundaries() -> None:
    """Worker processes (psf bank, dataset make --workers) send errors to the parent pickled."""
    import pickle

    from lensim.errors import InputError, UnknownGlassError

    for err in (
        InputError("a.yaml", "surfaces[1].radius", "expected a number, got 'x'"),
        UnknownGlassError(None, "material", "unknown glass 'N-BKK7'"),
    ):
        back = pickle.loads(pickle.dumps(err))
        assert type(back) is type(err) and str(back) == str(err)
        assert (back.source, back.field, back.message) == (err.source, err.field, err.message)


def test_pupil_sampling_error_carries_the_needed_samples_across_processes():
    """The bank's sampling error names the pupil samples its window needs as a number
    (simulate raises the sampling from it), also after pickling from a worker process."""
    import pickle

    from lensim.errors import InputError, PupilSamplingError

    err = pickle.loads(pickle.dumps(PupilSamplingError("lens.yaml", "pupil_samples", "expected at least 90", 90)))
    assert (
        isinstance(err, InputError)
        and err.needed == 90
        and str(err) == "lens.yaml: pupil_samples: expected at least 90"
    )
