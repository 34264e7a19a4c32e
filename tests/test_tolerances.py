"""Decentred and tilted surfaces (analytic truth), tolerance files and seeded draws."""

import dataclasses
import math

import pytest
import torch

from lensim.calibrate.tolerances import (
    draw,
    drawn_lens,
    elements,
    perturbed_lens,
    tolerances_from_dict,
)
from lensim.errors import InputError
from lensim.optics.lens import Lens
from lensim.optics.lens_file import lens_from_dict, lens_to_dict, load_lens
from lensim.optics.materials import ConstantIndex
from lensim.optics.pose import rotation
from lensim.optics.surfaces import Surface
from lensim.optics.trace import Rays, trace, trace_reference

TOL = {
    "elements": {"all": {"decentre_mm": 0.02, "tilt_deg": 0.05, "spacing_mm": 0.01}, "2": {"decentre_mm": 0.05}},
    "image": {"focus_mm": 0.02, "tilt_deg": 0.03},
}


def _rays(xy: torch.Tensor, z0: float = -5.0) -> Rays:
    n = xy.shape[0]
    pos = torch.cat([xy, torch.full((n, 1), z0, dtype=torch.float64)], dim=1)
    d = torch.zeros(n, 3, dtype=torch.float64)
    d[:, 2] = 1.0
    return Rays(pos, d, torch.zeros(n, dtype=torch.float64), torch.ones(n, dtype=torch.bool))


def _wl(n: int) -> torch.Tensor:
    return torch.full((n,), 0.5876, dtype=torch.float64)


def test_decentring_every_surface_shifts_the_image_rigidly():
    # translation equivariance: the whole lens moved by (dx, dy) with rays moved by the same
    lens = load_lens("cooke_triplet", warn=False)
    dx, dy = 0.031, -0.017
    moved = lens.with_changes(surfaces=[dataclasses.replace(s, pose=(dx, dy, 0.0, 0.0)) for s in lens.surfaces])
    xy = torch.tensor([[0.0, 0.0], [1.0, 2.0], [-3.0, 0.5], [2.5, -2.5]], dtype=torch.float64)
    a = trace(lens, _rays(xy), _wl(4))
    b = trace(moved, _rays(xy + torch.tensor([dx, dy], dtype=torch.float64)), _wl(4))
    assert bool(b.rays.valid.all())
    shift = b.rays.position[:, :2] - a.rays.position[:, :2]
    assert torch.allclose(shift, torch.tensor([dx, dy], dtype=torch.float64).expand(4, 2), atol=1e-11)
    assert torch.allclose(b.rays.direction, a.rays.direction, atol=1e-13)
    assert torch.allclose(b.rays.opl, a.rays.opl, atol=1e-11)


def test_tilted_plate_displaces_a_ray_by_the_textbook_amount():
    # both faces tilted by theta about their own vertices: parallel faces t cos(theta) apart;
    # a ray along z leaves parallel, displaced by t' sin(theta) (1 - cos(theta) / sqrt(n^2 - sin^2))
    n, t, theta = 1.6, 8.0, 7.0
    plate = [
        Surface(0.0, t, ConstantIndex(n), is_stop=True, pose=(0.0, 0.0, theta, 0.0)),
        Surface(0.0, 20.0, pose=(0.0, 0.0, theta, 0.0)),
    ]
    lens = Lens(plate, aperture_value=2.0, wavelengths_um=[0.5876])
    res = trace_reference(lens, _rays(torch.zeros(1, 2, dtype=torch.float64)), _wl(1))
    th = math.radians(theta)
    expected = t * math.cos(th) * math.sin(th) * (1.0 - math.cos(th) / math.sqrt(n * n - math.sin(th) ** 2))
    assert abs(res.rays.position[0, 1].item()) == pytest.approx(expected, rel=1e-12)
    assert torch.allclose(res.rays.direction[0], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-14)


def test_tilted_image_plane_is_where_rays_stop():
    lens = load_lens("cooke_triplet", warn=False).with_changes(image_tilt=(0.4, -0.3))
    xy = torch.tensor([[0.0, 3.0], [2.0, -1.0], [-4.0, 1.0]], dtype=torch.float64)
    res = trace(lens, _rays(xy), _wl(3))
    normal = rotation(0.4, -0.3)[:, 2]
    vertex = torch.tensor([0.0, 0.0, float(lens.vertex_z()[-1])], dtype=torch.float64)
    assert torch.allclose((res.rays.position - vertex) @ normal, torch.zeros(3, dtype=torch.float64), atol=1e-12)
    # the same rays as through the nominal lens, stopped on the tilted plane along their path
    nominal = trace(load_lens("cooke_triplet", warn=False), _rays(xy), _wl(3)).rays
    step = res.rays.position - nominal.position
    assert torch.allclose(
        torch.linalg.cross(step, nominal.direction), torch.zeros(3, 3, dtype=torch.float64), atol=1e-12
    )
    assert float(step.norm(dim=1).max()) > 1e-7


def test_elements_of_the_cooke_triplet_and_double_gauss():
    assert elements(load_lens("cooke_triplet", warn=False)) == [[0, 1], [2, 3], [4, 5]]
    dg = load_lens("double_gauss", warn=False)
    groups = elements(dg)
    assert all(i not in sum(groups, []) for i, s in enumerate(dg.surfaces) if s.is_stop)
    assert len(groups) == 4  # two singlets and two cemented doublets


def test_draws_are_reproducible_by_seed_and_index():
    lens = load_lens("cooke_triplet", warn=False)
    tol = tolerances_from_dict(TOL, lens)
    a, b = draw(tol, 7, 3), draw(tol, 7, 3)
    assert a.values == b.values
    assert draw(tol, 8, 3).values != a.values
    assert draw(tol, 7, 4).values != a.values
    assert set(a.values) == set(tol.parameters())
    for name, v in a.values.items():
        assert abs(v) <= tol.parameters()[name]
    assert tol.parameters()["e2.decentre_x"] == 0.05 and tol.parameters()["e1.decentre_x"] == 0.02
    normal = tolerances_from_dict({**TOL, "distribution": "normal"}, lens)
    vals = [v for k in range(200) for n, v in draw(normal, 1, k).values.items() if n == "e1.decentre_x"]
    assert max(abs(v) for v in vals) <= 0.02 and 0.004 < float(torch.tensor(vals).std()) < 0.012


def test_drawn_lens_round_trips_through_the_lens_file(tmp_path):
    lens = load_lens("cooke_triplet", warn=False)
    tol = tolerances_from_dict(TOL, lens)
    out = drawn_lens(lens, tol, 5, 2)
    assert out.has_poses and not lens.has_poses
    assert out.as_built["seed"] == 5 and out.as_built["draw"] == 2
    back = lens_from_dict(lens_to_dict(out), "x")
    assert [v for s in back.surfaces for v in s.pose] == pytest.approx([v for s in out.surfaces for v in s.pose])
    assert back.image_tilt == pytest.approx(out.image_tilt) and back.as_built == out.as_built
    assert back.image_defocus == pytest.approx(out.image_defocus)


def test_element_tilt_is_rigid_about_its_centre():
    lens = load_lens("cooke_triplet", warn=False)
    out = perturbed_lens(lens, {"e2.tilt_x": 0.1, "e1.spacing": 0.01})
    p2, p3 = out.surfaces[2].pose, out.surfaces[3].pose
    assert p2[2] == p3[2] == 0.1
    assert p2[1] == pytest.approx(-p3[1]) and p2[1] != 0.0  # the vertices move opposite ways about the centre
    assert out.surfaces[1].thickness == pytest.approx(lens.surfaces[1].thickness + 0.01)


@pytest.mark.parametrize(
    "data, field",
    [
        ({"elements": {"all": {"decenter_mm": 0.1}}}, "elements.all.decenter_mm"),
        ({"elements": {"9": {"tilt_deg": 0.1}}}, "elements.9"),
        ({"image": {"tilt_deg": -1}}, "image.tilt_deg"),
        ({"shape": 1}, "tolerances.shape"),
        ({"elements": {"1-2": {}, "2": {}}}, "elements.2"),
    ],
)
def test_bad_tolerances_name_the_key(data, field):
    lens = load_lens("cooke_triplet", warn=False)
    with pytest.raises(InputError) as e:
        tolerances_from_dict(data, lens, "tol.yaml")
    assert e.value.field == field and str(e.value).startswith("tol.yaml: ")
    if "decenter" in field:
        assert "decentre_mm" in str(e.value)


def test_lens_file_pose_errors():
    data = lens_to_dict(load_lens("cooke_triplet", warn=False))
    data["surfaces"][0]["tilt"] = [0.1]
    with pytest.raises(InputError, match=r"surfaces\[0\]\.tilt: expected a pair"):
        lens_from_dict(data, "lens.yaml")


def test_turning_the_perturbation_turns_the_field():
    # the chief ray of field -h of a lens decentred along y lands where field +h of the
    # lens turned by 180 deg lands, mirrored (lens_at_azimuth: fields at other azimuths)
    from lensim.calibrate.tolerance_report import lens_at_azimuth
    from lensim.optics.aiming.rays import chief_ray_image_height

    lens = perturbed_lens(load_lens("cooke_triplet", warn=False), {"e2.decentre_y": 0.05, "e1.tilt_x": 0.1})
    turned = lens_at_azimuth(lens, 180.0)
    assert turned.surfaces[2].pose[1] == pytest.approx(-lens.surfaces[2].pose[1])
    below = chief_ray_image_height(lens, -14.0)
    above = chief_ray_image_height(turned, 14.0)
    assert below == pytest.approx(-above, abs=1e-9)
    assert abs(below + chief_ray_image_height(lens, 14.0)) > 1e-5  # the decentre breaks the symmetry


def test_lens_tolerance_and_perturb_commands(tmp_path, capsys, monkeypatch):
    import json

    from cli_runner import run_cli

    tol = tmp_path / "tol.yaml"
    tol.write_text("elements:\n  '2': {tilt_deg: 0.05}\n  '3': {spacing_mm: 0.02}\nimage: {focus_mm: 0.02}\n")
    args = ["lens", "tolerance", "cooke_triplet", "--tolerances", str(tol), "--field", "0", "--field", "1"]
    code, out, err = run_cli(
        [*args, "--draws", "2", "--pupil-samples", "32", "--aiming", "paraxial", "--json", "--quiet"],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    report = json.loads(out)
    assert len(report["per_draw"]) == 2 and report["fields"] == [0.0, 20.0]
    names = [row["parameter"] for row in report["sensitivity"]]
    assert sorted(names) == ["e2.tilt_x", "e2.tilt_y", "e3.spacing", "image.focus"]
    worst = report["sensitivity"][0]["worst"]
    assert worst < 0 and all(worst <= row["worst"] for row in report["sensitivity"])
    again = run_cli(
        [
            *args,
            "--draws",
            "2",
            "--pupil-samples",
            "32",
            "--aiming",
            "paraxial",
            "--json",
            "--quiet",
            "--no-sensitivity",
        ],
        capsys,
        monkeypatch,
    )[1]
    assert json.loads(again)["per_draw"] == report["per_draw"]
    unit = tmp_path / "unit.yaml"
    code, _, err = run_cli(
        ["lens", "perturb", "cooke_triplet", "--tolerances", str(tol), "--seed", "0", "--draw", "1", "-o", str(unit)],
        capsys,
        monkeypatch,
    )
    assert code == 0, err
    assert load_lens(unit, warn=False).as_built["parameters"] == report["per_draw"][1]["parameters"]
    tol.write_text("elements: {all: {decenter_mm: 0.02}}\n")
    code, _, err = run_cli([*args, "-o", str(tmp_path / "t.png")], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1
    assert "tol.yaml: elements.all.decenter_mm: unknown key; expected one of decentre_mm" in err
    assert not (tmp_path / "t.png").exists()


def test_dataset_make_draws_pairs_through_perturbed_lenses(tmp_path, capsys, monkeypatch):
    import json

    from cli_runner import run_cli
    from lensim.images import write_image
    from lensim.psf.bank import PSFBank

    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(4):
        write_image(photos / f"p{k}.png", torch.rand(3, 48, 64, generator=torch.Generator().manual_seed(k)))
    tol = tmp_path / "tol.yaml"
    tol.write_text("elements: {'2': {decentre_mm: 0.05}}\nimage: {focus_mm: 0.03}\n")
    args = ["dataset", "make", str(photos), "-o", str(tmp_path / "data"), "--lens", "cooke_triplet"]
    args += ["--sensor", "apsc_mirrorless", "--crops", "1", "--size", "32", "--seed", "3", "--fields", "3"]
    args += ["--wavelengths-nm", "500:600:100", "--pupil-samples", "32", "--cache", str(tmp_path / "cache")]
    args += ["--tolerances", str(tol), "--tolerance-draws", "2", "--quiet", "--json"]
    code, out, err = run_cli(args, capsys, monkeypatch)
    assert code == 0, err
    manifest = json.loads((tmp_path / "data" / "manifest.json").read_text())
    draws = manifest["tolerances"]["draws"]
    assert [d["draw"] for d in draws] == [0, 1] and [d["photos"] for d in draws] == [2, 2]
    assert sorted(r["tolerance_draw"] for r in manifest["records"]) == [0, 0, 1, 1]
    banks = [PSFBank.load(d["bank"]) for d in draws]
    lenses = [b.manifest["lens"] for b in banks]
    assert lenses[0] != lenses[1] and lenses[0]["as_built"]["parameters"] == draws[0]["parameters"]
    assert lenses[0]["surfaces"][2]["decentre"][0] == pytest.approx(draws[0]["parameters"]["e2.decentre_x"])
    bad = [*args[:-6], "--tolerances", str(tol), "--fno", "4,5.6"]
    code, _, err = run_cli(bad, capsys, monkeypatch)
    assert code == 2 and "--tolerances" in err and err.count("\n") == 1
    code, _, err = run_cli([*args[:-6], "--posed-draws"], capsys, monkeypatch)
    assert code == 2 and "--posed-draws" in err and "--tolerances" in err and err.count("\n") == 1
    _stage_is_each_draws_own(tmp_path / "data", args, capsys, monkeypatch)
    _posed_draws(tmp_path, args, manifest, capsys, monkeypatch)


def _posed_draws(tmp_path, args, turned, capsys, monkeypatch):
    """--posed-draws: each draw's photos through its posed banks (8: a quadrant's lens and its
    mirrored lens's, lensim.render.posed), and their Wiener stage too (keyed apart from the
    turned draws' stage); same crops and targets, other inputs."""
    import json

    from cli_runner import run_cli
    from lensim.images import read_image

    posed_args = [a if a != str(tmp_path / "data") else str(tmp_path / "posed") for a in args] + ["--posed-draws"]
    code, _, err = run_cli(posed_args, capsys, monkeypatch)
    assert code == 0, err
    manifest = json.loads((tmp_path / "posed" / "manifest.json").read_text())
    draws = manifest["tolerances"]["draws"]
    assert [d["bank"] for d in draws] == [d["bank"] for d in turned["tolerances"]["draws"]]
    assert all(len(set(d["posed_banks"].values())) == 8 and d["bank"] not in d["posed_banks"].values() for d in draws)
    diff = 0.0
    for rt, rp in zip(turned["records"], manifest["records"], strict=True):
        assert rt["crops"][0]["sensor_top"] == rp["crops"][0]["sensor_top"]
        inputs, targets = ([read_image(tmp_path / d / r["crops"][0][k])[0] for d, r in (("data", rt), ("posed", rp))]
                           for k in ("input", "target"))  # fmt: skip
        assert torch.equal(*targets)
        diff = max(diff, float((inputs[0] - inputs[1]).abs().max()))
    assert diff > 0
    from lensim.data.pairs import crop_capture
    from lensim.evaluate.harness import record_banks
    from lensim.render.mapping import native_mapping
    from lensim.restore.psf_stage import cached_path, ensure_wiener_cache, stage_bank_entry, wiener_channels
    from lensim.sensor.profile import sensor_from_dict

    root, sensor = tmp_path / "posed", sensor_from_dict(manifest["sensor"])
    assert stage_bank_entry(manifest) == {"tolerance_draw": [d["posed_banks"] for d in draws]}
    folder, bank_of = ensure_wiener_cache(root), record_banks(manifest, root)
    for i, rec in enumerate(manifest["records"]):
        banks, crop = bank_of(i, rec), rec["crops"][0]
        assert {k: str(b.directory) for k, b in banks.items()} == draws[rec["tolerance_draw"]]["posed_banks"]
        x, _ = read_image(root / crop["input"])
        mapping = native_mapping(*x.shape[1:], sensor, crop["sensor_top"], crop["sensor_left"])
        want = wiener_channels(x, mapping, banks, crop_capture(rec, crop)).clamp(0, 1)
        assert (read_image(cached_path(folder, root / crop["input"]))[0] - want).abs().max() < 1.0 / 65535 + 1e-6
    _robust_stage(tmp_path / "posed", tmp_path / "robust", manifest)


def _robust_stage(data, robust, manifest):
    """Pairs whose manifest says "stage_bank": "tolerance_robust": every crop's cached
    stage is the tolerance-robust stage over all the draws' posed banks (wiener_channels
    with the list), not its own draw's, in its own cache folder; evaluate's methods get the
    draws' banks."""
    import json

    from lensim.data.pairs import crop_capture
    from lensim.evaluate import harness
    from lensim.images import read_image
    from lensim.psf.bank import PSFBank
    from lensim.render.mapping import native_mapping
    from lensim.restore.psf_stage import cached_path, ensure_wiener_cache, wiener_channels
    from lensim.sensor.profile import sensor_from_dict

    robust.mkdir()
    (robust / "pairs").symlink_to(data / "pairs")
    (robust / "manifest.json").write_text(json.dumps({**manifest, "stage_bank": "tolerance_robust"}))
    posed = [{k: PSFBank.load(f) for k, f in d["posed_banks"].items()} for d in manifest["tolerances"]["draws"]]
    folder = ensure_wiener_cache(robust)
    assert folder != ensure_wiener_cache(data).parent / folder.name
    # another bank would be computed into the robust stage's cache: refused, as for per-draw stages
    with pytest.raises(InputError, match="tolerance draws"):
        ensure_wiener_cache(robust, bank=manifest["bank"])
    broken = robust.parent / "robust_without_draws"
    broken.mkdir()
    (broken / "manifest.json").write_text(json.dumps({**manifest, "stage_bank": "tolerance_robust", "tolerances": {}}))
    with pytest.raises(InputError, match="robust_without_draws.*tolerances"):
        ensure_wiener_cache(broken)
    sensor = sensor_from_dict(manifest["sensor"])
    for rec in manifest["records"]:
        crop = rec["crops"][0]
        x, _ = read_image(robust / crop["input"])
        stored, _ = read_image(cached_path(folder, robust / crop["input"]))
        mapping = native_mapping(*x.shape[1:], sensor, crop["sensor_top"], crop["sensor_left"])
        want, own = (
            wiener_channels(x, mapping, b, crop_capture(rec, crop)).clamp(0, 1)
            for b in (posed, posed[rec["tolerance_draw"]])
        )
        assert (stored - want).abs().max() < 1.0 / 65535 + 1e-6
        assert (stored - own).abs().max() > 100 / 65535
    seen: list = []
    harness.evaluate_rows(robust, {"spy": lambda image, ctx: seen.append(ctx) or image})
    assert seen and all(
        [{k: str(b.directory) for k, b in d.items()} for d in c.bank]
        == [d["posed_banks"] for d in manifest["tolerances"]["draws"]]
        for c in seen
    )


def _stage_is_each_draws_own(data, args, capsys, monkeypatch):
    """The Wiener stage of each tolerance pair is computed with its own draw's bank (not
    draw 0's, as lensim did, nor the nominal lens's), and evaluate's methods get it too; the
    pairs' "bank" is the nominal lens's (what a restoration has). A manifest from before
    (draw 0's bank as "bank") gets the same stage, and making the pairs again rewrites it."""
    import json
    import shutil

    from cli_runner import run_cli
    from lensim.data.pairs import crop_capture
    from lensim.evaluate import harness
    from lensim.images import read_image
    from lensim.psf.bank import PSFBank
    from lensim.render.mapping import native_mapping
    from lensim.restore.psf_stage import cached_path, ensure_wiener_cache, wiener_channels
    from lensim.sensor.profile import sensor_from_dict

    manifest = json.loads((data / "manifest.json").read_text())
    assert manifest["stage_bank"] == "tolerance_draw"
    nominal = PSFBank.load(manifest["bank"])
    draws = [PSFBank.load(d["bank"]) for d in manifest["tolerances"]["draws"]]
    assert "as_built" not in nominal.manifest["lens"]
    assert nominal.manifest["lens"]["surfaces"] == manifest["lens"]["surfaces"]
    sensor = sensor_from_dict(manifest["sensor"])

    def check(folder):
        for rec in manifest["records"]:
            crop = rec["crops"][0]
            x, _ = read_image(data / crop["input"])
            stored, _ = read_image(cached_path(folder, data / crop["input"]))
            mapping = native_mapping(*x.shape[1:], sensor, crop["sensor_top"], crop["sensor_left"])
            own, first, nom = (
                wiener_channels(x, mapping, b, crop_capture(rec, crop)).clamp(0, 1)
                for b in (draws[rec["tolerance_draw"]], draws[0], nominal)
            )
            assert (stored - own).abs().max() < 1.0 / 65535 + 1e-6
            assert (stored - nom).abs().max() > 100 / 65535
            if rec["tolerance_draw"] != 0:
                assert (stored - first).abs().max() > 100 / 65535

    folder = ensure_wiener_cache(data)
    check(folder)
    # lensim evaluate's methods (the Wiener oracle, the network's stage) get each record's
    # draw's bank too, or the bank given
    for given, want in ((None, lambda r: draws[r["tolerance_draw"]]), (nominal, lambda r: nominal)):
        seen: list = []
        harness.evaluate_rows(data, {"spy": lambda image, ctx, seen=seen: seen.append(ctx) or image}, bank=given)
        assert seen and all(str(c.bank.directory) == str(want(manifest["records"][c.record]).directory) for c in seen)
    old = {k: v for k, v in manifest.items() if k != "stage_bank"}
    old["bank"] = manifest["tolerances"]["draws"][0]["bank"]  # what lensim recorded before
    (data / "manifest.json").write_text(json.dumps(old))
    shutil.rmtree(data / "wiener")
    assert ensure_wiener_cache(data) == folder
    check(folder)
    with pytest.raises(InputError, match="tolerance draws") as e:
        ensure_wiener_cache(data, bank=nominal)
    assert "\n" not in str(e.value)
    settings = json.loads((data / "settings.json").read_text())
    settings.pop("stage_bank")
    (data / "settings.json").write_text(json.dumps({**settings, "bank": old["bank"]}))
    code, _, err = run_cli(args, capsys, monkeypatch)
    assert code == 0, err
    assert json.loads((data / "manifest.json").read_text()) == manifest
