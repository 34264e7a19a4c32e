"""`lensim restore` on camera raw files: develop + restore equals the in-memory chain,
camera checks, linear DNG output, batches (resume, validation before output)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_runner import run_cli
from lensim.raw.dng import DngCamera, DngExif, profile_colour, write_capture_dng, write_cfa_dng
from lensim.restore.checkpoint import CHECKPOINT_FORMAT, atomic_torch_save
from lensim.restore.infer import restore_image
from lensim.restore.network import FieldAwareUNet
from lensim.sensor import isp
from lensim.sensor.profile import load_sensor, sensor_from_dict

rawpy = pytest.importorskip("rawpy")


def small_sensor():
    """The APS-C profile's colour and levels on a 64 x 48 sensor (fast to restore)."""
    data = load_sensor("apsc_mirrorless").to_dict()
    data.update(name="tiny test sensor", resolution=[64, 48], pixel_pitch_um=3.92)
    return sensor_from_dict(data, "test")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, FieldAwareUNet]:
    torch.manual_seed(0)
    model = FieldAwareUNet(8, 2, zero_init_tail=False).eval()
    run = tmp_path_factory.mktemp("run")
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": small_sensor().to_dict(),
            "lens": None,
        },
        run / "last.pt",
    )
    return run, model


def capture(seed: int = 0, size: tuple[int, int] = (48, 64)) -> tuple[torch.Tensor, isp.CaptureParams]:
    """A noisy, quantized mosaic of a random photo on the small sensor."""
    sensor = small_sensor()
    g = torch.Generator().manual_seed(seed)
    cam, params = isp.unprocess(torch.rand(3, *size, generator=g), sensor, g)
    raw = isp.quantize_raw(isp.add_noise(isp.mosaic(cam, sensor.bayer_pattern), 1e-3, 2e-3, g), sensor)
    return raw, params


def read_tif(path: Path) -> np.ndarray:
    import tifffile

    return tifffile.imread(path).astype(np.float64) / 65535.0


def test_raw_restore_equals_the_in_memory_chain(run, tmp_path: Path, capsys, monkeypatch):
    folder, model = run
    raw, params = capture()
    write_capture_dng(
        tmp_path / "in" / "shot.dng", raw, small_sensor(), params, orientation=6, exif=DngExif(iso=200, exposure_s=0.01)
    )
    code, _, err = run_cli(
        [
            "restore",
            str(folder),
            str(tmp_path / "in"),
            "-o",
            str(tmp_path / "out"),
            "--dng",
            "--quiet",
            "--tile",
            "32",
            "--overlap",
            "8",
            "--precision",
            "float32",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    developed = isp.raw_to_srgb(raw, params, bits=None)
    expected = restore_image(model, developed, (0.0, 0.0), (48.0, 64.0), tile=32, overlap=8).clamp(0, 1)
    got = read_tif(tmp_path / "out" / "shot.tif")
    assert got.shape == (64, 48, 3)  # orientation 6: turned 90 degrees clockwise
    want = torch.rot90(expected, -1, (-2, -1)).permute(1, 2, 0).numpy()
    assert np.abs(got - want).max() < 1.0 / 65535 + 1e-6
    with rawpy.imread(str(tmp_path / "out" / "shot.dng")) as lin:  # the linear DNG: the raw's colour, EXIF
        assert lin.raw_type == rawpy.RawType.Stack and lin.sizes.flip == 6 and lin.other.iso_speed == 200
        np.testing.assert_allclose(lin.camera_whitebalance[:3], [params.r_gain, 1, params.b_gain], rtol=1e-5)
        cam = torch.from_numpy(lin.raw_image[..., :3].astype(np.float32).transpose(2, 0, 1) / 65535)
    again = isp.process(cam, params, bits=None)  # developing the linear DNG gives the restored photo back
    inside = (expected > 0.02) & (expected < 0.98)
    assert float((again - expected)[inside].abs().max()) < 3e-3


def test_developing_in_strips_is_developing_the_frame(tmp_path: Path):
    from lensim.raw import read_raw
    from lensim.raw.develop import develop_raw

    raw, params = capture(4, size=(70, 64))
    sensor = small_sensor()
    shot = read_raw(write_capture_dng(tmp_path / "s.dng", raw, sensor, params))
    whole, _ = develop_raw(shot, sensor, orient=False, strip_rows=10**6)  # one strip: the whole frame
    strips, used = develop_raw(shot, sensor, orient=False, strip_rows=20)  # 4 strips, the last one short
    assert float((strips - whole).abs().max()) < 1e-6 and used.r_gain == pytest.approx(params.r_gain)


def test_other_camera_is_refused_then_allowed(run, tmp_path: Path, capsys, monkeypatch):
    folder, _ = run
    raw, params = capture(1)
    sensor = small_sensor()
    dn = isp.digital_numbers(raw, sensor).to(torch.int32).numpy()
    write_cfa_dng(
        tmp_path / "other.dng",
        dn,
        "RGGB",
        sensor.black_level,
        int(sensor.white_level),
        profile_colour(sensor, params.r_gain, params.b_gain),
        DngCamera("Acme", "Z9"),
    )
    args = ["restore", str(folder), str(tmp_path / "other.dng"), "-o", str(tmp_path / "out"), "--quiet"]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "Acme Z9 64x48" in err and "tiny test sensor 64x48" in err and "--allow-other-camera" in err
    assert not (tmp_path / "out").exists()
    code, _, err = run_cli(args + ["--allow-other-camera"], capsys, monkeypatch)
    assert code == 0, err
    assert (tmp_path / "out" / "other.tif").is_file()


def test_batch_is_checked_before_output_and_resumes(run, tmp_path: Path, capsys, monkeypatch):
    folder, _ = run
    raws = tmp_path / "raws"
    for k in range(2):
        raw, params = capture(k)
        write_capture_dng(raws / f"s{k}.dng", raw, small_sensor(), params)
    (raws / "bad.dng").write_bytes(b"\xff\xd8\xff\xe0" + b"\0" * 64)  # a JPEG named .dng
    out = tmp_path / "out"
    args = ["restore", str(folder), str(raws), "-o", str(out), "--quiet", "--json"]
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 2 and "bad.dng" in err and len(err.strip().splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())
    code, _, err = run_cli(args + ["--sensor-offset", "0,0"], capsys, monkeypatch)  # a raw's place is its active area
    assert code == 2 and "--sensor-offset" in err
    (raws / "bad.dng").unlink()
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 0, err
    first = (out / "s0.tif").stat().st_mtime_ns
    code, stdout, _ = run_cli(args, capsys, monkeypatch)
    assert code == 0 and stdout.count('"skipped": true') == 2
    assert (out / "s0.tif").stat().st_mtime_ns == first


@pytest.mark.slow
def test_worker_processes_write_what_one_process_writes(run, tmp_path: Path, capsys, monkeypatch):
    """--workers 2 (a local Dask cluster) and --scheduler (a cluster given by address, here
    with two worker threads in this process) write the files one process writes, and
    report them by the paths given (relative ones here)."""
    distributed = pytest.importorskip("distributed")
    folder, _ = run
    monkeypatch.chdir(tmp_path)
    for k in range(3):
        raw, params = capture(k)
        write_capture_dng(Path("raws") / f"s{k}.dng", raw, small_sensor(), params)
    threads = torch.get_num_threads()
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, protocol="tcp://", dashboard_address=":0"
    ) as c:
        runs = {"1": ["--workers", "1"], "2": ["--workers", "2"], "cluster": ["--scheduler", c.scheduler_address]}
        for name, where in runs.items():
            code, stdout, err = run_cli(
                ["restore", str(folder), "raws", "-o", name, "--quiet", "--json", *where], capsys, monkeypatch
            )
            assert code == 0, err
            records = sorted(json.loads(stdout)["images"], key=lambda r: r["input"])
            assert [(r["input"], r["output"], r["skipped"]) for r in records] == [
                (f"raws/s{k}.dng", f"{name}/s{k}.tif", False) for k in range(3)
            ]
    torch.set_num_threads(threads)  # the cluster's jobs set their threads in this process
    for name in ("2", "cluster"):
        for k in range(3):
            # the same up to one 16-bit step (float sums in another thread count)
            one, other = read_tif(tmp_path / "1" / f"s{k}.tif"), read_tif(tmp_path / name / f"s{k}.tif")
            assert np.abs(one - other).max() <= 1.0 / 65535 + 1e-9, (name, k)


def test_a_worker_loads_the_model_once_and_restores_as_this_process(run, tmp_path: Path, monkeypatch):
    """restore_in_worker, the job a Dask worker runs: its jobs pickle; the process loads
    the model on its first job only (again when the checkpoint file changes); the files
    are those restored here with the loaded model."""
    import os
    import pickle

    from lensim.raw import restore as raw_restore
    from lensim.restore import checkpoint

    folder, model = run
    loads: list[str] = []
    real = checkpoint.load_checkpoint
    monkeypatch.setattr(checkpoint, "load_checkpoint", lambda path, **kw: loads.append(path) or real(path, **kw))
    monkeypatch.setattr(raw_restore, "_MODEL", {})
    settings = raw_restore.RestoreSettings(
        checkpoint=str(folder / "last.pt"), sensor=small_sensor().to_dict(), tile=32, overlap=8
    )
    for k in range(3):
        raw, params = capture(k)
        write_capture_dng(tmp_path / "raws" / f"s{k}.dng", raw, small_sensor(), params)
    (tmp_path / "w").mkdir()
    jobs = [raw_restore.RawJob(tmp_path / "raws" / f"s{k}.dng", tmp_path / "w" / f"s{k}.tif", None) for k in range(3)]
    threads = torch.get_num_threads()
    try:
        for k, job in enumerate(jobs):
            if k == 2:  # the checkpoint rewritten (a newer modification time): loaded anew
                stat = os.stat(folder / "last.pt")
                os.utime(folder / "last.pt", ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
            task = pickle.loads(pickle.dumps(raw_restore.WorkerJob(job, settings, 1)))
            assert raw_restore.restore_in_worker(task)["output"] == str(job.tif)
            assert torch.get_num_threads() == 1 and len(loads) == (1 if k < 2 else 2)
        assert len(raw_restore._MODEL) == 1  # only the latest model is kept
    finally:
        torch.set_num_threads(threads)
    raw_restore.restore_raw_files([j.source for j in jobs], tmp_path / "here", model, settings)
    for k in range(3):
        here, there = read_tif(tmp_path / "here" / f"s{k}.tif"), read_tif(tmp_path / "w" / f"s{k}.tif")
        assert np.abs(here - there).max() <= 1.0 / 65535 + 1e-9, k


def test_a_scheduler_that_does_not_answer_is_one_line_and_writes_nothing(run, tmp_path: Path, capsys, monkeypatch):
    import socket

    dask = pytest.importorskip("dask")
    folder, _ = run
    raw, params = capture(0)
    write_capture_dng(tmp_path / "raws" / "s0.dng", raw, small_sensor(), params)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    with dask.config.set({"distributed.comm.timeouts.connect": "0.5s"}):
        code, _, err = run_cli(
            [
                "restore",
                str(folder),
                str(tmp_path / "raws"),
                "-o",
                str(tmp_path / "out"),
                "--quiet",
                "--scheduler",
                address,
            ],
            capsys,
            monkeypatch,
        )
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert address in err and "no Dask scheduler answered" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_simulated_dng_restores_as_in_memory(tmp_path: Path, capsys, monkeypatch):
    """simulate (the lens's PSFs, noise, ADC) -> CFA DNG -> `lensim restore` gives the PSNR
    against the sharp photo that the in-memory chain (simulate's own output restored at the
    same sensor place) gives, within 0.05 dB; the crop lies off axis, so the recorded place
    on the sensor matters to the field-aware network."""
    from lensim.evaluate.metrics import psnr
    from lensim.optics.lens_file import load_lens
    from lensim.psf.bank import BankSettings, get_bank
    from lensim.render.mapping import native_mapping
    from lensim.render.pipeline import simulate

    sensor = load_sensor("apsc_mirrorless")
    settings = BankSettings(fields=(0.0, 0.6, 1.0), wavelengths_nm=(500, 600), pupil_samples=32, kernel_pixels=15)
    bank = get_bank(load_lens("cooke_triplet"), sensor.pixel_pitch_um, settings, memory_only=True)
    torch.manual_seed(1)
    model = FieldAwareUNet(8, 2, zero_init_tail=False).eval()
    with torch.no_grad():  # a mild correction, so the PSNRs are those of a photo
        model.tail.weight.mul_(0.05)
    atomic_torch_save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "model_config": model.config,
            "model_state": model.state_dict(),
            "sensor": sensor.to_dict(),
            "lens": None,
        },
        tmp_path / "run" / "last.pt",
    )
    photo = torch.nn.functional.interpolate(
        torch.rand(1, 3, 8, 12, generator=torch.Generator().manual_seed(2)),
        size=(48, 72),
        mode="bicubic",
        align_corners=False,
    )[0].clamp(0, 1)
    top, left = 400, 4600
    mapping = native_mapping(48, 72, sensor, top, left)
    camera, _ = simulate(
        photo,
        bank,
        sensor,
        torch.Generator().manual_seed(3),
        mapping=mapping,
        bits=None,
        raw_path=tmp_path / "shot.dng",
    )
    place, frame = (float(top), float(left)), (4000.0, 6000.0)
    in_memory = restore_image(model, isp.quantize(camera, 8), place, frame).clamp(0, 1)  # simulate's 8-bit photo
    code, _, err = run_cli(
        [
            "restore",
            str(tmp_path / "run"),
            str(tmp_path / "shot.dng"),
            "-o",
            str(tmp_path / "out"),
            "--quiet",
            "--precision",
            "float32",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    from_dng = torch.from_numpy(read_tif(tmp_path / "out" / "shot.tif").transpose(2, 0, 1)).float()
    a, b = psnr(in_memory.numpy(), photo.numpy()), psnr(from_dng.numpy(), photo.numpy())
    assert abs(a - b) < 0.05, (a, b)
    # the DNG's recorded place on the sensor is used: same output as the float in-memory chain there
    exact = restore_image(model, camera, place, frame).clamp(0, 1)
    centred = restore_image(model, camera, (1976.0, 2964.0), frame).clamp(0, 1)
    assert float((exact - from_dng).abs().max()) < 2e-5 < 0.1 * float((centred - from_dng).abs().max())


def test_json_record_keeps_an_infinite_focus_distance(run, tmp_path: Path, capsys, monkeypatch):
    folder, _ = run
    raw, params = capture(0)
    write_capture_dng(tmp_path / "raws" / "s0.dng", raw, small_sensor(), params)
    code, stdout, err = run_cli(
        [
            "restore",
            str(folder),
            str(tmp_path / "raws"),
            "-o",
            str(tmp_path / "out"),
            "--quiet",
            "--json",
            "--focus-m",
            "inf",
        ],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    (record,) = json.loads(stdout)["images"]
    assert record["settings"]["focus_m"] == "inf" and float(record["settings"]["focus_m"]) == math.inf
