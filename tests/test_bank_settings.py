"""BankSettings: the one way to ask for a bank. The wavelength parser against hand-counted
ranges, field positions against their formulas, refusals on one line, and the commands
asking for the same cached bank with the same options (no bank is computed here)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from lensim.cli import app
from lensim.errors import InputError
from lensim.optics.lens_file import load_lens
from lensim.psf.bank.settings import BankSettings, field_positions, parse_wavelengths_nm


def test_a_range_includes_stop_only_when_a_step_lands_on_it():
    seven = parse_wavelengths_nm("400:700:7")
    assert len(seven) == 43 and seven[0] == 400.0 and seven[-1] == 694.0  # 400 + 42 * 7
    assert np.allclose(np.diff(seven), 7.0)
    ten = parse_wavelengths_nm("400:700:10")
    assert len(ten) == 31 and ten[-1] == 700.0
    assert parse_wavelengths_nm("450, 550,650") == (450.0, 550.0, 650.0)
    assert parse_wavelengths_nm("550") == (550.0,)


@pytest.mark.parametrize("text", ["400:700", "700:400:10", "400:700:0", "400:inf:10", "a,b", "", "550,450", "-5"])
def test_bad_wavelengths_are_one_line_errors(text):
    with pytest.raises(InputError, match="^wavelengths_nm: ") as e:
        parse_wavelengths_nm(text)
    assert "\n" not in str(e.value)


def test_field_positions_follow_their_spacing():
    n = 7
    sqrt = field_positions(n, "sqrt")
    np.testing.assert_allclose(sqrt**2, np.linspace(0.0, 1.0, n), rtol=0, atol=1e-15)
    # the demo's banks were computed at exactly these values: the cached banks stay valid
    assert sqrt.tolist() == [(k / (n - 1)) ** 0.5 for k in range(n)]
    assert field_positions(n, "linear").tolist() == [k / (n - 1) for k in range(n)]
    with pytest.raises(InputError, match="field_spacing"):
        field_positions(n, "log")


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"fields": 1}, "fields"),
        ({"wavelengths_nm": ()}, "wavelengths_nm"),
        ({"pupil_samples": 0}, "pupil_samples"),
        ({"aiming": "none"}, "aiming"),
        ({"kernel_pixels": 14}, "kernel_pixels"),
        ({"field_spacing": "log"}, "field_spacing"),
    ],
)
def test_bad_settings_are_refused(kw, field):
    with pytest.raises(InputError, match=field):
        BankSettings(**kw)


def test_the_cache_key_names_what_shapes_the_bank():
    lens = load_lens("cooke_triplet")
    base = BankSettings(cache_dir=None)
    key = base.cache_key(lens, 4.0, 21, "Nikon 5100 (NPL)")
    assert BankSettings(cache_dir="elsewhere").cache_key(lens, 4.0, 21, "Nikon 5100 (NPL)") == key
    assert BankSettings(wavelengths_nm=list(base.wavelengths_nm)).cache_key(lens, 4.0, 21, "Nikon 5100 (NPL)") == key
    for other in (
        BankSettings(fields=33),
        BankSettings(pupil_samples=64),
        BankSettings(aiming="paraxial"),
        BankSettings(field_spacing="linear"),
    ):
        assert other.cache_key(lens, 4.0, 21, "Nikon 5100 (NPL)") != key
    assert base.cache_key(lens, 4.0, 23, "Nikon 5100 (NPL)") != key
    assert base.cache_key(lens, 4.1, 21, "Nikon 5100 (NPL)") != key
    assert base.cache_key(lens, 4.0, 21, "Sigma SDMerill (NPL)") != key


class _Asked(Exception):
    """Raised by the stand-in bank builders once they have recorded the request."""


@pytest.fixture
def asked(monkeypatch):
    """Record the (lens, pitch, settings, response) each command asks a bank for."""
    calls = []

    def record(lens, pitch_um, settings, response=None, **kw):
        calls.append((lens, pitch_um, settings, response))
        raise _Asked

    monkeypatch.setattr("lensim.psf.bank.get_bank", record)  # simulate, dataset make, psf bank
    return calls


def test_the_commands_ask_for_the_same_bank_with_the_same_options(tmp_path, asked):
    from lensim.images import write_image

    photos = tmp_path / "photos"
    photos.mkdir()
    write_image(photos / "a.png", torch.full((3, 40, 60), 0.5))
    common = ["--lens", "cooke_triplet", "--sensor", "apsc_mirrorless"]
    runner = CliRunner()
    for args in (
        ["simulate", str(photos / "a.png"), "-o", str(tmp_path / "sim"), *common],
        ["dataset", "make", str(photos), "-o", str(tmp_path / "data"), "--size", "32", *common],
        ["psf", "bank", "-o", str(tmp_path / "bank"), *common],
    ):
        res = runner.invoke(app, args)
        assert isinstance(res.exception, _Asked), (args, res.output)
    (_, _, simulate, response), (_, native, dataset, _), (_, pitch, bank, _) = asked
    assert simulate == dataset == bank == BankSettings()
    assert {r for *_, r in asked} == {response} and native == pitch == 3.92
    # dataset make and psf bank at the sensor's pitch: the same cached bank
    lens = load_lens("cooke_triplet")
    assert dataset.cache_key(lens, native, 21, response) == bank.cache_key(lens, pitch, 21, response)


@pytest.mark.parametrize(
    "command",
    [
        ["simulate", "{photo}", "-o", "{out}"],
        ["dataset", "make", "{photos}", "-o", "{out}"],
        ["psf", "bank", "cooke_triplet", "--pixel-um", "4", "-o", "{out}"],
    ],
)
def test_one_field_is_a_one_line_error_before_any_work(tmp_path, command):
    from lensim.images import write_image

    photos = tmp_path / "photos"
    photos.mkdir()
    write_image(photos / "a.png", torch.full((3, 40, 60), 0.5))
    names = {"photo": str(photos / "a.png"), "photos": str(photos), "out": str(tmp_path / "out")}
    res = CliRunner().invoke(app, [a.format(**names) for a in command] + ["--fields", "1"])
    assert isinstance(res.exception, InputError), res.output
    assert "fields" in str(res.exception) and "\n" not in str(res.exception)
    assert not (tmp_path / "out").exists()


def test_pupil_samples_are_raised_to_what_the_kernel_window_needs():
    """with_enough_pupil_samples: the one home of the retry simulate makes for coarse pixels."""
    from lensim.errors import ParameterError, PupilSamplingError
    from lensim.psf.bank.settings import pupil_samples_for, with_enough_pupil_samples

    asked = []

    def compute(settings: BankSettings) -> int:
        asked.append(settings.pupil_samples)
        if settings.pupil_samples < 170:
            raise PupilSamplingError("lens.yaml", "pupil_samples", "the PSF would wrap around", 150)
        return settings.pupil_samples

    assert pupil_samples_for(150) == 176  # 15 % more, a multiple of 8
    with pytest.warns(UserWarning, match=r"^a.png: coarse; pupil samples raised from 128 to 176 for the PSF bank$"):
        assert (
            with_enough_pupil_samples(compute, BankSettings(pupil_samples=128), source="a.png", context="coarse") == 176
        )
    assert asked == [128, 176]
    with pytest.raises(ParameterError) as e:  # the caller chose the samples: named, with the number to give
        with_enough_pupil_samples(compute, BankSettings(pupil_samples=64), fixed=True, source="a.png")
    assert e.value.source == "a.png" and e.value.parameter == "pupil_samples" and "`pupil_samples` 176" in str(e.value)

    def never(settings: BankSettings) -> int:
        raise PupilSamplingError(None, None, "wraps", settings.pupil_samples + 8)

    with pytest.warns(UserWarning), pytest.raises(ParameterError, match="no pupil sampling up to"):
        with_enough_pupil_samples(never, BankSettings())
