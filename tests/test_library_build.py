"""The lens library's bank plan, bank build and pairs (lensim.data.library_banks,
lensim.data.library_pairs): the plan's size and hold-outs, a resumed build that skips what is
done, a bank the lens cannot give recorded and skipped, pairs that never use a held-out lens.

The banks here are tiny (2 fields, one wavelength, 16 pupil samples) so that the build runs in
seconds; the library's own settings are measured by benchmarks/library_banks.py.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

import lensim.data.library_banks as lb
from lensim.assets.library import library_entry, list_lenses
from lensim.data.library_pairs import LibraryPairsSettings, make_library_pairs
from lensim.errors import InputError
from lensim.psf.bank import BankSettings, PSFBank
from lensim.sensor.profile import load_sensor

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = BankSettings(fields=2, wavelengths_nm=(550.0,), pupil_samples=16, kernel_pixels=7, ri_samples=2)


def test_plan_has_300_banks_two_pitches_and_holdouts():
    plan = lb.bank_plan()
    assert len(plan) >= 300
    assert len({b.id for b in plan}) == len(plan)
    held = {b.lens for b in plan if b.holdout}
    assert held == {e.name for e in list_lenses(holdout=True)}
    assert len({library_entry(n).family for n in held}) >= 5  # lenses of different families are held out
    for e in list_lenses():
        mine = [b for b in plan if b.lens == e.name]
        assert len({b.pitch_um for b in mine}) == 2
        assert len({b.fno for b in mine}) == 2 and len({b.focus_m for b in mine}) == 2
    # rounds: the first len(lenses) banks are one per lens
    assert len({b.lens for b in plan[: len(list_lenses())]}) == len(list_lenses())


def test_build_resumes_and_records_what_the_lens_cannot_give(tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", TINY)
    entry = library_entry("cooke_triplet")
    good = lb.bank_plan([entry])[0]
    bad = dataclasses.replace(good, id="cooke_too_fast", fno=1.0)  # faster than the lens opens
    plan = [good, bad]
    seen = []
    r = lb.compute_library_banks(tmp_path, plan, progress=lambda d, t: seen.append((d, t)))
    assert (r.computed, r.failed, r.todo) == (1, 1, 0)
    assert seen[0] == (0, 2) and seen[-1] == (2, 2)
    assert lb.bank_state(tmp_path, good.id) == "done" and lb.bank_state(tmp_path, bad.id) == "failed"
    assert (
        "fno" in (tmp_path / "failed" / "cooke_too_fast.json").read_text()
        or "F-number" in (tmp_path / "failed" / "cooke_too_fast.json").read_text()
    )
    sensor = load_sensor(lb.sensor_file(tmp_path, good.id))
    bank = PSFBank.load(lb.bank_dir(tmp_path, good.id))
    assert sensor.pixel_pitch_um == good.pitch_um == bank.pixel_pitch_um
    assert sensor.half_diagonal_mm <= bank.radii_mm[-1]
    # a rerun computes nothing
    again = lb.compute_library_banks(tmp_path, plan)
    assert (again.done, again.computed, again.failed) == (1, 0, 1)
    assert [b.id for b, _, _ in lb.library_banks(tmp_path)] == [good.id]


def test_build_after_a_kill_keeps_finished_fields(tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", TINY)
    planned = lb.bank_plan([library_entry("cooke_triplet")])[0]
    lb.compute_library_banks(tmp_path, [planned])
    sensor = lb.sensor_file(tmp_path, planned.id)
    sensor.unlink()  # as if killed after the bank's fields and before its sensor file
    field = lb.bank_dir(tmp_path, planned.id) / "field_0000.npz"
    before = field.stat().st_mtime_ns
    r = lb.compute_library_banks(tmp_path, [planned])
    assert r.computed == 1 and sensor.exists()
    assert field.stat().st_mtime_ns == before  # not recomputed


def test_plan_of_other_settings_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", TINY)
    lb.write_plan(tmp_path, [])
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", dataclasses.replace(TINY, pupil_samples=32))
    with pytest.raises(InputError, match="other bank settings"):
        lb.write_plan(tmp_path, [])


def test_near_focus_and_pitches_are_physical():
    e = library_entry("cooke_triplet")
    assert lb.near_focus_m(e) == pytest.approx(1.0)
    fisheye = library_entry("laikin_fisheye_170deg_f1.8")  # f = 5.2 mm, 197 mm long
    assert lb.near_focus_m(fisheye) == pytest.approx(2.0 * fisheye.track_mm / 1000.0, abs=1e-3)
    assert lb.near_focus_m(fisheye) > fisheye.track_mm / 1000.0 > 20 * fisheye.focal_mm / 1000.0
    (w1, p1), (w2, p2) = lb.plan_pitches(e)
    assert p2 / p1 == pytest.approx(w1 / w2, rel=0.01)
    assert not math.isinf(lb.bank_plan([e])[-1].focus_m)


def test_pairs_use_trainable_banks_only(tmp_path, monkeypatch):
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", TINY)
    train = lb.bank_plan([library_entry("cooke_triplet")])[0]
    held = lb.bank_plan([library_entry("smith_tessar_f3.5")])[0]
    held = dataclasses.replace(held, fno=16.0, id="held")  # stopped down: its spot fits the tiny banks
    assert held.holdout and not train.holdout
    lib = tmp_path / "lib"
    lb.compute_library_banks(lib, [train, held])
    settings = LibraryPairsSettings(photos_per_bank=1, placements=1, crops=1, size=32, photo_size=64)
    out = tmp_path / "pairs"
    r = make_library_pairs(lib, out, settings)
    assert (r.made, r.pairs) == (1, 1)
    assert sorted(p.name for p in (out / "pairs").iterdir()) == [train.id]
    again = make_library_pairs(lib, out, settings)
    assert (again.done, again.made) == (1, 0)
    r = make_library_pairs(lib, out, settings, holdout=True)
    assert r.made == 1 and (out / "pairs" / held.id / "manifest.json").exists()


def test_a_spot_too_large_for_the_huygens_window_gets_more_pupil_samples(tmp_path, monkeypatch):
    sized = dataclasses.replace(TINY, kernel_pixels=None, kernel_limit=31)  # kernels hold the spot
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", sized)  # 16 pupil samples: a Huygens window of ~30 um
    planned = lb.bank_plan([library_entry("smith_tessar_f3.5")])[0]  # F/3.5: a 62 um RMS spot at the edge
    r = lb.compute_library_banks(tmp_path, [planned])
    assert (r.computed, r.failed) == (1, 0)
    manifest = PSFBank.load(lb.bank_dir(tmp_path, planned.id)).manifest
    assert manifest["method"] == "huygens" and manifest["pupil_samples"] > 16  # was geometric
    # resumed: a field lost, the bank's raised samples kept (not 16 over its other fields)
    (lb.bank_dir(tmp_path, planned.id) / "field_0001.npz").unlink()
    lb.sensor_file(tmp_path, planned.id).unlink()
    r = lb.compute_library_banks(tmp_path, [planned])
    assert (r.computed, r.failed) == (1, 0)
    assert PSFBank.load(lb.bank_dir(tmp_path, planned.id)).manifest["pupil_samples"] == manifest["pupil_samples"]


def test_a_spot_beyond_the_most_pupil_samples_gets_geometric_psfs(tmp_path, monkeypatch):
    sized = dataclasses.replace(TINY, kernel_pixels=None, kernel_limit=31)
    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", sized)
    monkeypatch.setattr(lb, "MAX_PUPIL_SAMPLES", 32)  # the Tessar's edge asks for more
    planned = lb.bank_plan([library_entry("smith_tessar_f3.5")])[0]
    r = lb.compute_library_banks(tmp_path, [planned])
    assert (r.computed, r.failed) == (1, 0)
    assert PSFBank.load(lb.bank_dir(tmp_path, planned.id)).manifest["method"] == "geometric"


def test_side_by_side_jobs_cross_process_boundaries(tmp_path):
    """The jobs --workers N sends to Dask workers are plain picklable data with module-level
    functions (the spawn test below is slow)."""
    import pickle

    from lensim.data import library_pairs as lp

    planned = lb.bank_plan([library_entry("cooke_triplet")])[0]
    job = (tmp_path, planned, TINY)
    assert pickle.loads(pickle.dumps(job)) == job
    pairs_job = lp._PairsJob(tmp_path, tmp_path, tmp_path, tmp_path / "s.yaml", LibraryPairsSettings())
    assert pickle.loads(pickle.dumps(pairs_job)) == pairs_job
    assert pickle.loads(pickle.dumps(lb._bank_job)) is lb._bank_job
    assert pickle.loads(pickle.dumps(lp._bank_pairs)) is lp._bank_pairs


@pytest.mark.slow
def test_banks_and_pairs_side_by_side_on_workers_match_one_process(tmp_path, monkeypatch):
    """--workers 2: whole banks (and whole banks' pairs) computed side by side in Dask worker
    processes give the same files as one process, and a bank the lens cannot give is still
    recorded (not raised)."""
    import numpy as np

    monkeypatch.setattr(lb, "LIBRARY_BANK_SETTINGS", TINY)
    cooke = lb.bank_plan([library_entry("cooke_triplet")])
    bad = dataclasses.replace(cooke[0], id="cooke_too_fast", fno=1.0)
    plan = [cooke[0], cooke[2], bad]
    settings = LibraryPairsSettings(photos_per_bank=1, placements=1, crops=1, size=32, photo_size=64)
    runs = {}
    for workers in (1, 2):
        lib = tmp_path / f"lib{workers}"
        seen = []
        r = lb.compute_library_banks(lib, plan, workers=workers, progress=lambda d, t, seen=seen: seen.append((d, t)))
        assert (r.computed, r.failed, r.todo) == (2, 1, 0)
        assert seen[0] == (0, 3) and seen[-1] == (3, 3)
        assert lb.bank_state(lib, bad.id) == "failed"
        p = make_library_pairs(lib, tmp_path / f"pairs{workers}", settings, workers=workers)
        assert (p.made, p.pairs) == (2, 2)
        runs[workers] = lib
    for planned in plan[:2]:
        one, two = (PSFBank.load(lb.bank_dir(runs[w], planned.id)) for w in (1, 2))
        assert np.array_equal(one.fields[-1].rgb_azimuths, two.fields[-1].rgb_azimuths)
        for name in ("000000_000_input.png", "000000_000_target.png"):
            a, b = (tmp_path / f"pairs{w}" / "pairs" / planned.id / "pairs" / name for w in (1, 2))
            assert a.read_bytes() == b.read_bytes()
