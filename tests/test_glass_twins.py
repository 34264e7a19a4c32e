"""Patent nd/Vd pairs taken as the catalogue glasses they match (issue 25, defect 4).

Patents give each glass as nd/Vd; a model glass on Schott's normal line loses the anomalous
partial dispersion of ED and fluorite-like glasses, which is what corrects secondary colour.
Truth: the same lens with the catalogue glasses named (the vendor's own dispersion formula
through opticalglass), and each vendor's formula for the table's nd and Vd."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import yaml

from cli_runner import run_cli
from lensim.optics.field_analysis import lateral_colour
from lensim.optics.lens_file import GlassSubstitutionWarning, lens_from_dict, load_lens
from lensim.optics.materials import (
    CatalogGlass,
    ModelGlass,
    _twin_table,
    catalog_glass,
    catalogue_twin,
    written_rounding,
)
from lensim.optics.paraxial import paraxial_data
from lensim.sensor.spectral import spectral_response


def test_written_rounding_is_half_the_last_decimal() -> None:
    assert written_rounding(1.497, 5e-6, 5e-4) == pytest.approx(5e-4)
    assert written_rounding(1.49782, 5e-6, 5e-4) == pytest.approx(5e-6)
    assert written_rounding(81.61, 5e-3, 0.05) == pytest.approx(5e-3)
    assert written_rounding(67.0, 5e-3, 0.05) == pytest.approx(0.05)  # "67.0": trailing zeros are lost
    assert written_rounding(1.5168000345, 5e-6, 5e-4) == pytest.approx(5e-6)


@pytest.mark.parametrize("step", [0, 1])
def test_the_twin_table_holds_each_vendors_formula(step: int) -> None:
    """Every 20th glass of the shipped table (offset by step) against opticalglass now."""
    cats, names, table = _twin_table()
    assert len(names) > 900
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i in range(step * 10, len(names), 20):
            g = catalog_glass(names[i], cats[i])
            assert g.nd == pytest.approx(table[i, 0], abs=1e-7) and g.vd == pytest.approx(table[i, 1], abs=1e-4)


def test_ed_pairs_are_their_catalogue_glasses() -> None:
    """The ED pairs of the issue: 1.49782/82.57 (a Nikon patent) is Hikari's J-FKH1;
    1.497/81.54 is Ohara's S-FPL51 (its own Vd 81.546). A pair that matches nothing, a pair
    asked to stay a model and a model with a dPgF of its own stay models."""
    fkh1 = catalogue_twin(ModelGlass(1.49782, 82.57))
    assert isinstance(fkh1, CatalogGlass) and (fkh1.name, fkh1.catalog) == ("J-FKH1", "Hikari")
    assert fkh1.dpgf > 0.03  # the anomalous partial dispersion the model glass lacks
    fpl51 = catalogue_twin(ModelGlass(1.497, 81.54))
    assert isinstance(fpl51, CatalogGlass) and (fpl51.name, fpl51.catalog) == ("S-FPL51", "Ohara")
    assert catalogue_twin(ModelGlass(1.497, 81.61), ("Hoya",)) == catalog_glass("FCD1", "Hoya")
    assert catalogue_twin(ModelGlass(1.544, 56.0)) is None  # a cyclo-olefin plastic: no glass
    assert catalogue_twin(ModelGlass(1.497, 81.54, forced=True)) is None
    assert catalogue_twin(ModelGlass(1.497, 81.54, 0.03)) is None


def _doublet(crown, flint, bfl: float) -> dict:
    """A cemented ED achromat, f about 100 mm, F/8, its stop 25 mm in front (lateral colour
    at 10 degrees)."""
    return {
        "name": "ED doublet",
        "object": {"distance": "infinity"},
        "aperture": {"type": "epd", "value": 12.5},
        "fields": {"type": "angle", "values": [0, 5, 10]},
        "wavelengths": {"nm": [486.1, 587.6, 656.3], "primary": 1},
        "surfaces": [
            {"radius": "infinity", "thickness": 25.0, "stop": True},
            {"radius": 55.2, "thickness": 4.0, "material": crown},
            {"radius": -55.2, "thickness": 2.0, "material": flint},
            {"radius": -192.3, "thickness": bfl},
        ],
    }


def _blue_lateral_colour_um(lens) -> float:
    sr = spectral_response()
    return float(np.array(lateral_colour(lens, [10.0], sr.wavelengths_nm, sr.weights)["lateral_colour_um"])[0, 2])


def test_an_ed_lens_from_patent_pairs_has_its_catalogue_twins_lateral_colour(tmp_path) -> None:
    """The doublet written as a patent prints it (S-FPL51 1.49700/81.54, S-TIM2 1.62004/36.26)
    loads with the catalogue glasses, one note line naming both, and its blue lateral colour
    at 10 degrees is the catalogue lens's (measured 1.539 um both); kept as model glasses
    (model_glasses=True, --model-glass) it is 2.902 um: the model glass's normal-line
    partial dispersion nearly doubles it."""
    catalogue = lens_from_dict(_doublet("S-FPL51@Ohara", "S-TIM2@Ohara", 95.0))
    para = paraxial_data(catalogue)
    bfl = float(95.0 + para.paraxial_image_z_mm - catalogue.vertex_z()[-1])
    catalogue = lens_from_dict(_doublet("S-FPL51@Ohara", "S-TIM2@Ohara", bfl))
    path = tmp_path / "patent.yaml"
    path.write_text(yaml.safe_dump(_doublet({"nd": 1.49700, "vd": 81.54}, {"nd": 1.62004, "vd": 36.26}, bfl)))
    with pytest.warns(GlassSubstitutionWarning) as caught:
        patent = load_lens(path)
    notes = [str(w.message) for w in caught if issubclass(w.category, GlassSubstitutionWarning)]
    assert len(notes) == 1 and "S-FPL51 (Ohara" in notes[0] and "S-TIM 2 (Ohara" in notes[0], notes
    assert "\n" not in notes[0]
    assert [s.material for s in patent.surfaces[1:3]] == [s.material for s in catalogue.surfaces[1:3]]
    model = load_lens(path, warn=False, model_glasses=True)
    assert all(isinstance(s.material, ModelGlass) and s.material.forced for s in model.surfaces[1:3])
    truth, twin, kept = (_blue_lateral_colour_um(x) for x in (catalogue, patent, model))
    assert truth == pytest.approx(1.539, abs=0.005)
    assert twin == pytest.approx(truth, abs=1e-9)
    assert kept - truth > 1.0  # what the default fixes: 2.90 against 1.54 um


def test_model_glass_option_round_trips_and_refuses_match_glass(tmp_path, capsys, monkeypatch) -> None:
    """`lens convert --model-glass` writes `model: true`, which keeps the model on reload;
    --model-glass beside --match-glass is one error line."""
    path = tmp_path / "patent.yaml"
    path.write_text(yaml.safe_dump(_doublet({"nd": 1.49700, "vd": 81.54}, {"nd": 1.62004, "vd": 36.26}, 97.26)))
    out = tmp_path / "kept.yaml"
    code, _, err = run_cli(["lens", "convert", str(path), "--model-glass", "-o", str(out)], capsys, monkeypatch)
    assert code == 0, err
    written = yaml.safe_load(out.read_text())["surfaces"][1]["material"]
    assert written == {"nd": 1.497, "vd": 81.54, "model": True}
    with warnings.catch_warnings():
        warnings.simplefilter("error", GlassSubstitutionWarning)  # no substitution on reload
        again = load_lens(out)
    assert isinstance(again.surfaces[1].material, ModelGlass)
    code, _, err = run_cli(["lens", "info", str(path), "--model-glass", "--match-glass", "--json"], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1 and "--model-glass" in err, err
