"""Hostile options and output paths, every command: numbers out of range or not finite
(with their units in the message), unknown names (devices, methods, variants, formats),
output paths that are the wrong kind, under a file or unwritable, and command-line usage
errors. Same checks as test_hostile_inputs.py (tests/hostile_world.py)."""

from __future__ import annotations

import pytest

from hostile_world import Case, case, check_case, folder, text
from reference_lenses import REFERENCE_LENSES

PSF = "psf compute cooke_triplet "
BANK = "psf bank --lens cooke_triplet --pixel-um 20 --fields 2 --wavelengths-nm 550 --pupil-samples 32 -o {t}/b "
SIM = "simulate {w.photo} -o {t}/out --bank {w.bank} "
DATASET = "dataset make {w.photos} -o {t}/d --bank {w.bank} --crops 1 --size 32 "
TRAIN = "train {w.data} -o {t}/r --epochs 1 --width 4 --depth 2 --crop 32 "
RESTORE = "restore {w.run} {w.photo} -o {t}/out "
EXPORT = "export {w.run} -o {t}/m.onnx "
EVAL = "evaluate --pairs {w.data} --methods input "
AFILE = text("afile", "a file, not a folder")
UNWRITABLE = "/proc/lensim-hostile"

PSF_COMPUTE = [
    case("psf-field-above-1", PSF + "--field 1.5", "--field", "1.5"),
    case("psf-field-negative", PSF + "--field -0.2", "--field", "-0.2"),
    case("psf-field-nan", PSF + "--field nan", "--field", "nan"),
    case("psf-wavelength-zero", PSF + "--wavelength-nm 0", "--wavelength-nm", "nm"),
    case("psf-wavelength-huge", PSF + "--wavelength-nm 1e9", "--wavelength-nm", "nm"),
    case("psf-wavelength-negative", PSF + "--wavelength-nm -550", "--wavelength-nm", "-550"),
    case("psf-wavelength-inf", PSF + "--wavelength-nm inf", "--wavelength-nm"),
    case("psf-method-unknown", PSF + "--method banana", "--method", "banana"),
    case("psf-aiming-unknown", PSF + "--aiming banana", "--aiming", "banana"),
    case("psf-pupil-samples-zero", PSF + "--pupil-samples 0", "--pupil-samples"),
    case("psf-grid-zero", PSF + "--grid 0", "--grid"),
    case("psf-grid-negative", PSF + "--grid -8", "--grid"),
    case("psf-spacing-zero", PSF + "--spacing-um 0", "--spacing-um", "um"),
    case("psf-spacing-nan", PSF + "--spacing-um nan", "--spacing-um"),
    case("psf-output-txt", PSF + "-o {t}/psf.txt", "psf.txt", ".npy"),
    case("psf-output-folder", PSF + "-o {t}/psf.npy", "psf.npy", make=folder("psf.npy")),
    case("psf-output-under-file", PSF + "-o {t}/afile/psf.npy", "afile", make=AFILE),
    case("psf-output-unwritable", PSF + "-o " + UNWRITABLE + "/psf.npy", UNWRITABLE),
]

PSF_BANK = [
    case("bank-pixel-zero", "psf bank --lens cooke_triplet --pixel-um 0 -o {t}/b", "--pixel-um", "um"),
    case("bank-pixel-negative", "psf bank --lens cooke_triplet --pixel-um -4 -o {t}/b", "--pixel-um"),
    case("bank-pixel-nan", "psf bank --lens cooke_triplet --pixel-um nan -o {t}/b", "--pixel-um"),
    case("bank-sensor-and-pixel", "psf bank --lens cooke_triplet --pixel-um 4 --sensor phone -o {t}/b", "--pixel-um"),
    case("bank-neither-sensor-nor-pixel", "psf bank --lens cooke_triplet -o {t}/b", "--sensor"),
    case("bank-no-lens", "psf bank --pixel-um 4 -o {t}/b", "lens"),
    case("bank-lens-twice", "psf bank cooke_triplet --lens double_gauss --pixel-um 4 -o {t}/b", "lens"),
    case("bank-kernel-even", BANK + "--kernel 4", "--kernel"),
    case("bank-kernel-negative", BANK + "--kernel -3", "--kernel"),
    case("bank-fields-one", "psf bank --lens cooke_triplet --pixel-um 4 --fields 1 -o {t}/b", "--fields"),
    case("bank-fields-zero", "psf bank --lens cooke_triplet --pixel-um 4 --fields 0 -o {t}/b", "--fields"),
    case(
        "bank-wavelengths-text",
        "psf bank --lens cooke_triplet --pixel-um 4 --wavelengths-nm abc -o {t}/b",
        "--wavelengths-nm",
        "abc",
    ),
    case(
        "bank-wavelengths-zero",
        "psf bank --lens cooke_triplet --pixel-um 4 --wavelengths-nm 0 -o {t}/b",
        "--wavelengths-nm",
    ),
    case(
        "bank-wavelengths-reversed",
        "psf bank --lens cooke_triplet --pixel-um 4 --wavelengths-nm 700:400:10 -o {t}/b",
        "--wavelengths-nm",
    ),
    case(
        "bank-pupil-samples-zero",
        "psf bank --lens cooke_triplet --pixel-um 4 --pupil-samples 0 -o {t}/b",
        "--pupil-samples",
    ),
    case("bank-response-missing-csv", BANK + "--response {t}/nofile.csv", "nofile.csv"),
    case("bank-response-unknown", BANK + "--response 'Banana 9000'", "--response", "Banana 9000"),
    case(
        "bank-response-bad-csv",
        BANK + "--response {t}/r.csv",
        "r.csv",
        make=text("r.csv", "wavelength_nm,r,g,b\n1,x\n"),
    ),
    case("bank-illuminant-unknown", BANK + "--illuminant banana", "--illuminant", "banana"),
    case("bank-method-unknown", BANK + "--method banana", "--method", "banana"),
    case("bank-aiming-unknown", BANK + "--aiming banana", "--aiming", "banana"),
    case("bank-max-spacing-zero", BANK + "--max-spacing-um 0", "--max-spacing-um"),
    case("bank-workers-zero", BANK + "--workers 0", "--workers"),
    case("bank-scheduler-http", BANK + "--scheduler http://10.0.0.5:8786", "--scheduler", "http://10.0.0.5:8786"),
    case("bank-scheduler-port-zero", BANK + "--scheduler tcp://localhost:0", "--scheduler", "tcp://localhost:0"),
    case("bank-scheduler-blank", BANK + "--scheduler ''", "--scheduler"),
    case("bank-fno-empty-item", BANK + "--fno 5.6,,8", "--fno", "5.6,,8"),
    case("bank-fno-zero", BANK + "--fno 0", "--fno", "0"),
    case("bank-fno-duplicate", BANK + "--fno 8,8.0", "--fno", "twice"),
    case("bank-fno-nan", BANK + "--fno 8,nan", "--fno", "nan"),
    case("bank-fno-text", BANK + "--fno 8,f2", "--fno", "f2"),
    case("bank-fno-faster-than-lens", BANK + "--fno 2,8", "--fno", "F/2"),
    case("bank-focus-duplicate-inf", BANK + "--focus-m inf,Infinity", "--focus-m", "twice"),
    case("bank-focus-negative", BANK + "--focus-m inf,-3", "--focus-m", "-3"),
    case("bank-focus-inside-lens", BANK + "--focus-m inf,0.01", "--focus-m", "inside the lens"),
    case("bank-object-empty", BANK + "--object-m ,", "--object-m"),
    case("bank-config-unknown", BANK + "--config wide,tele", "configuration", "wide"),
    case("bank-output-file", BANK.replace("{t}/b", "{t}/afile"), "afile", make=AFILE),
    case("bank-output-under-file", BANK.replace("{t}/b", "{t}/afile/b"), "afile", make=AFILE),
    case("bank-output-unwritable", BANK.replace("{t}/b", UNWRITABLE + "/b"), UNWRITABLE),
    case(
        "bank-output-other-settings",
        "psf bank --lens cooke_triplet --sensor apsc_mirrorless --fields 3 "
        "--wavelengths-nm 550 --pupil-samples 32 -o {w.bank}",
        "bank",
    ),
    case("show-gamma-zero", "psf show {w.bank} -o {t}/fig --gamma 0", "--gamma"),
    case("show-gamma-nan", "psf show {w.bank} -o {t}/fig --gamma nan", "--gamma"),
    case("show-output-file", "psf show {w.bank} -o {t}/afile", "afile", make=AFILE),
    case("show-output-under-file", "psf show {w.bank} -o {t}/afile/fig", "afile", make=AFILE),
    case("show-setting-of-a-single-bank", "psf show {w.bank} -o {t}/fig --setting 0", "--setting", "not a grid"),
]

LENS = [
    case("info-aiming-unknown", "lens info cooke_triplet --aiming banana", "--aiming", "banana"),
    case("convert-output-folder", "lens convert cooke_triplet -o {t}/out.yaml", "out.yaml", make=folder("out.yaml")),
    case("convert-output-under-file", "lens convert cooke_triplet -o {t}/afile/out.yaml", "afile", make=AFILE),
    case("convert-output-suffix", "lens convert cooke_triplet -o {t}/out.txt", "out.txt"),
    case("convert-output-unwritable", "lens convert cooke_triplet -o " + UNWRITABLE + "/l.yaml", UNWRITABLE),
    case("plot-output-folder", "lens plot cooke_triplet -o {t}/p.png", "p.png", make=folder("p.png")),
    case("plot-output-under-file", "lens plot cooke_triplet -o {t}/afile/p.png", "afile", make=AFILE),
    case("plot-output-suffix", "lens plot cooke_triplet -o {t}/p.txt", "p.txt"),
    case("plot-output-unwritable", "lens plot cooke_triplet -o " + UNWRITABLE + "/p.png", UNWRITABLE),
    case("plot-field-above-1", "lens plot cooke_triplet -o {t}/p.png --field 1.5", "field", "between 0 and 1", "1.5"),
    case("plot-field-deg-90", "lens plot cooke_triplet -o {t}/p.png --field-deg 95", "--field-deg"),
    case("plot-two-field-kinds", "lens plot cooke_triplet -o {t}/p.png --field 0.5 --field-deg 3", "--field-deg"),
    case("spot-nothing-asked", "lens spot cooke_triplet", "--output"),
    case("spot-output-folder", "lens spot cooke_triplet -o {t}/s.png", "s.png", make=folder("s.png")),
    case("spot-output-under-file", "lens spot cooke_triplet -o {t}/afile/s.png", "afile", make=AFILE),
    case("spot-image-height-nan", "lens spot cooke_triplet --json --image-height-mm nan", "--image-height-mm"),
]

LENSFUN = (
    "lens lensfun cooke_triplet --maker m --model x --mount Generic --crop-factor 1.5 --focal 50 "
    "--aperture 5.6 -o {t}/p.xml "
)
LENS_OUTPUTS = [
    case("field-sensor-missing", "lens field cooke_triplet --sensor {t}/nofile.yaml", "nofile.yaml"),
    case(
        "field-sensor-utf16",
        "lens field cooke_triplet --sensor {t}/s.yaml",
        "s.yaml",
        make=text("s.yaml", "name: x\n", "utf-16"),
    ),
    case("field-field-above-1", "lens field cooke_triplet --field 2", "field", "2"),
    case("field-image-height-inf", "lens field cooke_triplet --image-height-mm inf", "--image-height-mm"),
    case(
        "plot-kind-output-folder",
        "lens plot cooke_triplet --kind distortion -o {t}/d.png",
        "d.png",
        make=folder("d.png"),
    ),
    case("plot-layout-with-sensor", "lens plot cooke_triplet -o {t}/p.png --sensor phone", "--sensor"),
    case("lensfun-output-folder", LENSFUN, "p.xml", make=folder("p.xml")),
    case("lensfun-output-under-file", LENSFUN.replace("{t}/p.xml", "{t}/afile/p.xml"), "afile", make=AFILE),
    case("lensfun-output-suffix", LENSFUN.replace("p.xml", "p.txt"), "p.txt"),
    case("lensfun-crop-factor-zero", LENSFUN.replace("--crop-factor 1.5", "--crop-factor 0"), "crop"),
    case("lensfun-aperture-negative", LENSFUN.replace("--aperture 5.6", "--aperture -2"), "aperture"),
    case("lensfun-focal-nan", LENSFUN.replace("--focal 50", "--focal nan"), "focal"),
    case("lensfun-distance-negative", LENSFUN + "--distance -1", "distance"),
    case("lensfun-sensor-missing", LENSFUN + "--sensor {t}/nofile.yaml", "nofile.yaml"),
]

MTF = "lens mtf cooke_triplet --json "
WAVEFRONT = "lens wavefront cooke_triplet --json "
LENS_ANALYSES = [
    case("mtf-nothing-asked", "lens mtf cooke_triplet", "--output"),
    case("mtf-frequency-zero", MTF + "--frequency 0", "--frequency", "lp/mm"),
    case("mtf-frequency-negative", MTF + "--frequency 10 --frequency -30", "--frequency", "-30"),
    case("mtf-frequency-nan", MTF + "--frequency nan", "--frequency"),
    case("mtf-max-frequency-zero", MTF + "--max-frequency 0", "--max-frequency"),
    case("mtf-field-above-1", MTF + "--field 1.5", "field", "between 0 and 1", "1.5"),
    case("mtf-field-deg-90", MTF + "--field-deg 95", "--field-deg"),
    case("mtf-focus-range-zero", MTF + "--focus-range-um 0", "--focus-range-um", "um"),
    case("mtf-sweep-fields-one", MTF + "--sweep-fields 1", "--sweep-fields"),
    case("mtf-focus-steps-negative", MTF + "--focus-steps -1", "--focus-steps"),
    case("mtf-pupil-samples-small", MTF + "--pupil-samples 4", "--pupil-samples"),
    case("mtf-channel-without-sensor", MTF + "--channel g", "--channel", "--sensor"),
    case("mtf-channel-unknown", MTF + "--sensor phone --channel y", "--channel", "y"),
    case("mtf-sensor-missing", MTF + "--sensor {t}/nofile.yaml", "nofile.yaml"),
    case("mtf-wavelengths-zero", MTF + "--wavelengths-nm 0,550", "--wavelengths-nm"),
    case("mtf-output-suffix", "lens mtf cooke_triplet -o {t}/m.txt", "m.txt"),
    case("mtf-output-folder", "lens mtf cooke_triplet -o {t}/m.png", "m.png", make=folder("m.png")),
    case(
        "wavefront-zernike-terms-above-fringe",
        WAVEFRONT + "--zernike fringe --zernike-terms 38",
        "--zernike-terms",
        "38",
    ),
    case("wavefront-zernike-terms-above-noll", WAVEFRONT + "--zernike-terms 232", "--zernike-terms", "232"),
    case("wavefront-zernike-terms-zero", WAVEFRONT + "--zernike-terms 0", "--zernike-terms"),
    case("wavefront-zernike-unknown", WAVEFRONT + "--zernike zemax", "--zernike", "zemax"),
    case("wavefront-two-fields", WAVEFRONT + "--field 0 --field 1", "--field", "one field"),
    case("wavefront-field-above-1", WAVEFRONT + "--field 2", "field", "2"),
    case("wavefront-wavelength-zero", WAVEFRONT + "--wavelength-nm 0", "--wavelength-nm", "nm"),
    case("fans-rays-two", "lens fans cooke_triplet --json --rays 2", "--rays"),
    case("fans-field-above-1", "lens fans cooke_triplet --json --field 1.01", "field", "1.01"),
    case("field-curves-output-under-file", "lens field-curves cooke_triplet -o {t}/afile/c.png", "afile", make=AFILE),
    case(
        "field-curves-image-height-nan",
        "lens field-curves cooke_triplet --json --image-height-mm nan",
        "--image-height-mm",
    ),
    case("energy-method-unknown", "lens energy cooke_triplet --json --method banana", "--method", "banana"),
    case("energy-centre-unknown", "lens energy cooke_triplet --json --centre middle", "--centre", "middle"),
    case("energy-grid-small", "lens energy cooke_triplet --json --grid 4", "--grid"),
    case("energy-spacing-zero", "lens energy cooke_triplet --json --spacing-um 0", "--spacing-um", "um"),
    case("energy-field-above-1", "lens energy cooke_triplet --json --field -0.5", "field", "-0.5"),
]

SIMULATE = [
    case("simulate-format-jpg", SIM + "--format jpg", "--format", "jpg"),
    case("simulate-raw-format-jpg", "simulate {w.photo} -o {t}/out --raw --format jpg", "--format", "jpg"),
    case("simulate-bits-12", SIM + "--bits 12", "--bits", "12"),
    case("simulate-demosaic-unknown", SIM + "--demosaic banana", "--demosaic", "banana"),
    case("simulate-workers-zero", "simulate {w.photo} -o {t}/out --workers 0", "--workers"),
    case("simulate-fields-one", "simulate {w.photo} -o {t}/out --fields 1", "--fields"),
    case("simulate-pupil-samples-negative", "simulate {w.photo} -o {t}/out --pupil-samples -5", "--pupil-samples"),
    case("simulate-wavelengths-text", "simulate {w.photo} -o {t}/out --wavelengths-nm x:y", "--wavelengths-nm"),
    case("simulate-output-file", "simulate {w.photo} -o {t}/afile --no-blur", "afile", make=AFILE),
    case("simulate-output-under-file", "simulate {w.photo} -o {t}/afile/out --no-blur", "afile", make=AFILE),
    case("simulate-output-unwritable", "simulate {w.photo} -o " + UNWRITABLE + " --no-blur", UNWRITABLE),
    case("simulate-cache-is-file", "simulate {w.photo} -o {t}/out --cache {t}/afile", "afile", make=AFILE),
]

DATASET_MAKE = [
    case("dataset-crops-zero", DATASET.replace("--crops 1", "--crops 0"), "--crops"),
    case("dataset-size-zero", DATASET.replace("--size 32", "--size 0"), "--size"),
    case("dataset-size-odd", DATASET.replace("--size 32", "--size 31"), "--size"),
    case("dataset-size-larger-than-photos", DATASET.replace("--size 32", "--size 512"), "--size"),
    case("dataset-placements-zero", DATASET + "--placements 0", "--placements"),
    case("dataset-workers-zero", DATASET + "--workers 0", "--workers"),
    case("dataset-bank-and-fno", DATASET + "--fno 5.6,8", "--bank", "not both"),
    case("dataset-fno-duplicate", "dataset make {w.photos} -o {t}/d --crops 1 --size 32 --fno 8,8", "--fno", "twice"),
    case(
        "dataset-focus-empty-item", "dataset make {w.photos} -o {t}/d --crops 1 --size 32 --focus-m inf,,1", "--focus-m"
    ),
    case("dataset-scheduler-spaces", DATASET + "--scheduler 'tcp://a b:1'", "--scheduler", "tcp://a b:1"),
    case("dataset-demosaic-unknown", DATASET + "--demosaic banana", "--demosaic", "banana"),
    case("dataset-exposure-reversed", DATASET + "--exposure-ev 1,-1", "--exposure-ev", "1,-1"),
    case("dataset-exposure-text", DATASET + "--exposure-ev dark", "--exposure-ev", "dark"),
    case("dataset-exposure-huge", DATASET + "--exposure-ev -20,0", "--exposure-ev", "-20"),
    case("dataset-exposure-nan", DATASET + "--exposure-ev nan", "--exposure-ev"),
    case("dataset-output-file", DATASET.replace("{t}/d", "{t}/afile"), "afile", make=AFILE),
    case("dataset-output-under-file", DATASET.replace("{t}/d", "{t}/afile/d"), "afile", make=AFILE),
    case("dataset-output-unwritable", DATASET.replace("{t}/d", UNWRITABLE), UNWRITABLE),
    case(
        "dataset-output-other-settings",
        "dataset make {w.photos} -o {w.data} --bank {w.bank} --crops 2 --size 32",
        "data",
    ),
]

TRAINING = [
    case("train-epochs-zero", TRAIN + "--epochs 0", "--epochs"),
    case("train-batch-zero", TRAIN + "--batch-size 0", "--batch-size"),
    case("train-lr-zero", TRAIN + "--lr 0", "--lr"),
    case("train-lr-nan", TRAIN + "--lr nan", "--lr"),
    case("train-lr-schedule-unknown", TRAIN + "--lr-schedule banana", "--lr-schedule", "banana"),
    case("train-loss-unknown", TRAIN + "--loss banana", "--loss", "banana"),
    case("train-lr-halve-zero", TRAIN + "--lr-halve-every 0", "--lr-halve-every"),
    case("train-crop-negative", TRAIN + "--crop -2", "--crop"),
    case("train-crop-larger-than-pairs", TRAIN.replace("--crop 32", "--crop 64"), "--crop"),
    case("train-width-negative", TRAIN + "--width -1", "--width"),
    case("train-arch-unknown", TRAIN + "--arch banana", "--arch", "banana"),
    case("train-stem-three", TRAIN + "--arch nafnet --stem 3", "--stem", "3"),
    case("train-stem-unet", TRAIN + "--arch unet --stem 2", "--stem", "nafnet"),
    case("train-field-modulation-nafnet", TRAIN + "--arch nafnet --field-modulation", "--field-modulation", "nafnet"),
    case("train-nafnet-deformable-scales-zero", TRAIN + "--deformable --deformable-scales 0", "--deformable-scales"),
    case("train-depth-zero", TRAIN + "--depth 0", "--depth"),
    case("train-deformable-groups-zero", TRAIN + "--deformable-groups 0", "--deformable-groups"),
    case("train-val-fraction-above-1", TRAIN + "--val-fraction 1.5", "--val-fraction", "1.5"),
    case("train-val-fraction-negative", TRAIN + "--val-fraction -0.1", "--val-fraction"),
    case("train-time-budget-negative", TRAIN + "--time-budget-s -1", "--time-budget-s", "s"),
    case("train-time-budget-nan", TRAIN + "--time-budget-s nan", "--time-budget-s"),
    case("train-steps-negative", TRAIN + "--steps-per-epoch -1", "--steps-per-epoch"),
    case("train-threads-negative", TRAIN + "--threads -2", "--threads"),
    case("train-device-banana", TRAIN + "--device banana", "--device", "banana"),
    case("train-device-cuda9", TRAIN + "--device cuda:9", "--device", "cuda:9"),
    case("train-output-file", TRAIN.replace("{t}/r", "{t}/afile"), "afile", make=AFILE),
    case("train-output-under-file", TRAIN.replace("{t}/r", "{t}/afile/r"), "afile", make=AFILE),
    case("train-output-unwritable", TRAIN.replace("{t}/r", UNWRITABLE), UNWRITABLE),
]

RESTORING = [
    case("restore-bits-12", RESTORE + "--bits 12", "--bits", "12"),
    case("restore-tile-small", RESTORE + "--tile 8", "--tile"),
    case("restore-overlap-negative", RESTORE + "--overlap -1", "--overlap"),
    case("restore-overlap-above-tile", RESTORE + "--tile 64 --overlap 64", "--overlap"),
    case("restore-offset-text", RESTORE + "--sensor-offset abc", "--sensor-offset", "abc"),
    case("restore-offset-outside", RESTORE + "--sensor-offset 99999,0", "--sensor-offset"),
    case("restore-device-banana", RESTORE + "--device banana", "--device", "banana"),
    case("restore-device-cuda9", RESTORE + "--device cuda:9", "--device", "cuda:9"),
    case("restore-workers-zero", "restore {w.run} {w.dng} -o {t}/out --workers 0", "--workers"),
    case(
        "restore-scheduler-http",
        "restore {w.run} {w.dng} -o {t}/out --scheduler http://10.0.0.5:8786",
        "--scheduler",
        "http://10.0.0.5:8786",
    ),
    case(
        "restore-scheduler-no-port",
        "restore {w.run} {w.dng} -o {t}/out --scheduler tcp://host:",
        "--scheduler",
        "tcp://host:",
    ),
    case("restore-scheduler-without-raws", RESTORE + "--scheduler tcp://10.0.0.5:8786", "--scheduler", "raw"),
    case("restore-threads-negative", RESTORE + "--threads -1", "--threads"),
    case("restore-fno-zero", RESTORE + "--fno 0", "--fno", "0"),
    case("restore-fno-nan", RESTORE + "--fno nan", "--fno", "nan"),
    case("restore-fno-inf", RESTORE + "--fno inf", "--fno", "inf"),
    case("restore-fno-text", RESTORE + "--fno f/4", "--fno"),
    case("restore-focus-negative", RESTORE + "--focus-m -2", "--focus-m", "-2"),
    case("restore-focus-nan", RESTORE + "--focus-m nan", "--focus-m", "nan"),
    case("restore-focal-zero", RESTORE + "--focal-mm 0", "--focal-mm", "0"),
    case("restore-focal-inf", RESTORE + "--focal-mm inf", "--focal-mm", "inf"),
    case("restore-dng-without-raws", RESTORE + "--dng", "--dng"),
    case("restore-output-file", RESTORE.replace("{t}/out", "{t}/afile"), "afile", make=AFILE),
    case("restore-output-under-file", RESTORE.replace("{t}/out", "{t}/afile/out"), "afile", make=AFILE),
    case("restore-output-unwritable", RESTORE.replace("{t}/out", UNWRITABLE), UNWRITABLE),
    case("restore-engine-banana", RESTORE + "--engine banana", "--engine", "banana"),
    case(
        "restore-onnx-engine-torch",
        "restore {t}/m.onnx {w.photo} -o {t}/out",
        "m.onnx",
        "--engine onnxruntime",
        make=text("m.onnx", "x"),
    ),
    case("restore-onnx-device-banana", RESTORE + "--engine onnxruntime --device banana", "--device", "banana"),
    case("export-opset-16", EXPORT + "--opset 16", "--opset", "16"),
    case("export-opset-99", EXPORT + "--opset 99", "--opset", "99"),
    case("export-output-txt", "export {w.run} -o {t}/m.txt", "m.txt", ".onnx"),
    case("export-output-folder", EXPORT, "m.onnx", make=folder("m.onnx")),
    case("export-output-under-file", "export {w.run} -o {t}/afile/m.onnx", "afile", make=AFILE),
    case("export-output-unwritable", "export {w.run} -o " + UNWRITABLE + "/m.onnx", UNWRITABLE),
    case("develop-bits-12", "develop {w.dng} -o {t}/out --bits 12", "--bits", "12"),
    case("develop-format-jpg", "develop {w.dng} -o {t}/out --format jpg", "--format", "jpg"),
    case("develop-wb-unknown", "develop {w.dng} -o {t}/out --wb banana", "--wb", "banana"),
    case("develop-wb-zero-kelvin", "develop {w.dng} -o {t}/out --wb 0K", "--wb", "0K"),
    case("develop-output-file", "develop {w.dng} -o {t}/afile", "afile", make=AFILE),
    case("develop-output-under-file", "develop {w.dng} -o {t}/afile/out", "afile", make=AFILE),
    case("from-raw-output-suffix", "sensor from-raw {w.dng} --pixel-um 4 -o {t}/cam.txt", "cam.txt"),
    case("from-raw-pixel-zero", "sensor from-raw {w.dng} --pixel-um 0 -o {t}/cam.yaml", "--pixel-um", "um"),
    case("from-raw-pixel-nan", "sensor from-raw {w.dng} --pixel-um nan -o {t}/cam.yaml", "--pixel-um"),
    case(
        "from-raw-output-folder",
        "sensor from-raw {w.dng} --pixel-um 4 -o {t}/cam.yaml",
        "cam.yaml",
        make=folder("cam.yaml"),
    ),
    case(
        "from-raw-output-under-file", "sensor from-raw {w.dng} --pixel-um 4 -o {t}/afile/cam.yaml", "afile", make=AFILE
    ),
]

EVALUATING = [
    case("evaluate-method-unknown", "evaluate --pairs {w.data} --methods input,banana", "--methods", "banana"),
    case("evaluate-model-without-run", "evaluate --pairs {w.data} --methods model", "--methods", "model"),
    case("evaluate-model-missing", "evaluate --pairs {w.data} --methods model --model {t}/norun", "norun"),
    case("evaluate-plain-without-run", "evaluate --pairs {w.data} --methods plain", "--methods", "--plain"),
    case(
        "evaluate-plain-unet-without-run", "evaluate --pairs {w.data} --methods plain-unet", "'plain-unet'", "--plain"
    ),
    case("evaluate-plain-and-its-old-name", EVAL + "--plain {w.run} --plain-unet {w.run}", "--plain-unet", "not both"),
    case(
        "evaluate-plain-arch-mismatch",
        "evaluate --pairs {w.data} --methods plain --plain {w.run} --arch unet",
        "holds a 'nafnet' network",
        "--arch",
    ),
    case("evaluate-rl-iterations-negative", EVAL + "--rl-iterations -3", "--rl-iterations", "-3"),
    case("evaluate-unsharp-sigma-zero", EVAL + "--unsharp-sigma 0", "--unsharp-sigma"),
    case("evaluate-unsharp-amount-nan", EVAL + "--unsharp-amount nan", "--unsharp-amount"),
    case("evaluate-max-crops-zero", EVAL + "--max-crops 0", "--max-crops"),
    case(
        "evaluate-device-banana",
        "evaluate --pairs {w.data} --methods model --model {w.run} --device banana",
        "--device",
        "banana",
    ),
    case("evaluate-sources-unknown", EVAL + "--sources nophoto.png", "nophoto.png"),
    case("evaluate-arch-unknown", EVAL + "--arch banana", "--arch", "banana"),
    case(
        "evaluate-arch-mismatch",
        "evaluate --pairs {w.data} --methods model --model {w.run} --arch unet",
        "holds a 'nafnet' network",
        "--arch",
    ),
    case("evaluate-output-file", EVAL + "-o {t}/afile", "afile", make=AFILE),
    case("evaluate-output-under-file", EVAL + "-o {t}/afile/e", "afile", make=AFILE),
    case("ablation-variant-unknown", "ablation {w.data} -o {t}/a --variants full,banana", "--variants", "banana"),
    case("ablation-budget-negative", "ablation {w.data} -o {t}/a --time-budget-s -1", "--time-budget-s"),
    case("ablation-width-zero", "ablation {w.data} -o {t}/a --width 0", "--width"),
    case("ablation-arch-unknown", "ablation {w.data} -o {t}/a --arch banana", "--arch", "banana"),
    case(
        "ablation-variant-of-other-arch",
        "ablation {w.data} -o {t}/a --arch nafnet --variants plain-unet",
        "--variants",
        "plain-unet",
    ),
    case("ablation-crop-tiny", "ablation {w.data} -o {t}/a --crop 8", "--crop"),
    case("ablation-device-banana", "ablation {w.data} -o {t}/a --device banana", "--device", "banana"),
    case("ablation-output-file", "ablation {w.data} -o {t}/afile", "afile", make=AFILE),
    case("demo-workers-negative", "demo -o {t}/demo --quick --workers -1", "--workers"),
    case("demo-device-banana", "demo -o {t}/demo --quick --device banana", "--device", "banana"),
    case("demo-device-cuda9", "demo -o {t}/demo --quick --device cuda:9", "--device", "cuda:9"),
    case("demo-output-file", "demo -o {t}/afile --quick", "afile", make=AFILE),
    case("demo-output-under-file", "demo -o {t}/afile/demo --quick", "afile", make=AFILE),
    case("assets-export-file", "assets --export-photos {t}/afile", "afile", make=AFILE),
    case("assets-export-under-file", "assets --export-photos {t}/afile/p", "afile", make=AFILE),
    case("assets-export-unwritable", "assets --export-photos " + UNWRITABLE, UNWRITABLE),
    case("assets-export-test-file", "assets --export-test-photos {t}/afile", "afile", make=AFILE),
    case(
        "assets-export-test-same",
        "assets --export-photos {t}/p --export-test-photos {t}/p",
        "--export-test-photos",
        "--export-photos",
    ),
]

ZOOM = str(REFERENCE_LENSES / "nikon_80-200_zoom.zmx")
SHOOTING = [  # single-value shooting settings (psf bank and dataset make grids: above)
    case("shoot-fno-too-fast", PSF + "--fno 2", "--fno", "F/2", "maximum aperture F/5"),
    case("shoot-fno-zero", PSF + "--fno 0", "--fno", "'0'"),
    case("shoot-fno-negative", PSF + "--fno -4", "--fno", "-4"),
    case("shoot-fno-nan", PSF + "--fno nan", "--fno", "nan"),
    case("shoot-fno-inf", PSF + "--fno inf", "--fno", "inf"),
    case("shoot-fno-text", PSF + "--fno f8", "--fno", "f8"),
    case("shoot-fno-list", PSF + "--fno 8,11", "--fno", "one value", "8,11"),
    case("shoot-fno-empty", PSF + "--fno ''", "--fno"),
    case("shoot-focus-negative", PSF + "--focus-m -1", "--focus-m", "-1"),
    case("shoot-focus-zero", PSF + "--focus-m 0", "--focus-m", "metres"),
    case("shoot-focus-nan", PSF + "--focus-m nan", "--focus-m", "nan"),
    case("shoot-focus-huge", PSF + "--focus-m 1e12", "--focus-m", "inf"),
    case("shoot-focus-too-close", PSF + "--focus-m 0.1", "--focus-m", "cannot focus at 0.1 m"),
    case("shoot-focus-inside-lens", PSF + "--focus-m 0.02", "--focus-m", "inside the lens"),
    case("shoot-object-nan", PSF + "--object-m nan", "--object-m", "nan"),
    case("shoot-object-negative", PSF + "--object-m -2 --focus-m 1", "--object-m", "-2"),
    case("shoot-object-inside-lens", PSF + "--object-m 0.03 --focus-m 1", "--object-m", "inside the lens"),
    case("shoot-config-none-declared", PSF + "--config tele", "--config", "declares no configurations"),
    case("shoot-config-unknown", "psf compute " + ZOOM + " --config 4", "--config", "1..3"),
    case("shoot-config-blank", PSF + "--config ' '", "--config"),
    case("shoot-simulate-with-bank", SIM + "--fno 8", "--fno", "--lens"),
    case("shoot-simulate-other-lens", SIM + "--lens cooke_triplet --fno 8", "--lens", "at these settings"),
    case("shoot-simulate-focus-nan", "simulate {w.photo} -o {t}/out --focus-m nan", "--focus-m"),
    case("shoot-simulate-fno-list", "simulate {w.photo} -o {t}/out --fno 8,11", "--fno", "psf bank"),
    case("shoot-demo-fno-too-fast", "demo --quick -o {t}/demo --fno 2", "--fno", "F/2"),
    case("shoot-demo-object-zero", "demo --quick -o {t}/demo --object-m 0", "--object-m"),
    case("shoot-info-config", "lens info cooke_triplet --config 1", "--config"),
    case("shoot-spot-focus-close", "lens spot cooke_triplet --json --focus-m 0.1", "--focus-m"),
    case("shoot-field-fno-fast", "lens field cooke_triplet --fno 1", "--fno"),
    case("shoot-plot-object-negative", "lens plot cooke_triplet -o {t}/p.png --object-m -3", "--object-m"),
    case("shoot-lensfun-aperture-fast", LENSFUN.replace("--aperture 5.6", "--aperture 2"), "--aperture", "F/5"),
]

USAGE = [
    case("usage-unknown-option", "lens info cooke_triplet --bogus", "--bogus"),
    case("usage-missing-argument", "lens info", "lens_file"),
    case("usage-unknown-command", "lens banana", "banana"),
    case("usage-unknown-top-command", "simulat", "simulat"),
    case("usage-not-an-integer", "psf bank --lens cooke_triplet --pixel-um 4 --fields abc -o {t}/b", "--fields"),
    case("usage-not-a-number", "psf compute cooke_triplet --field abc", "--field"),
    case("usage-option-without-value", "simulate {w.photo} -o", "-o"),
    case("usage-out-of-range-rays", "lens plot cooke_triplet -o {t}/p.png --rays 0", "--rays"),
    case("usage-bad-choice", "lens spot cooke_triplet --json --reference banana", "--reference", "banana"),
]

if "CUDAExecutionProvider" not in __import__("onnxruntime").get_available_providers():  # the CPU build (CI's)
    RESTORING.append(
        case(
            "restore-onnx-device-cuda",
            RESTORE + "--engine onnxruntime --device cuda:0",
            "--device",
            "cuda:0",
            "CUDAExecutionProvider",
        )
    )

ALL: list[Case] = (
    PSF_COMPUTE
    + PSF_BANK
    + LENS
    + LENS_OUTPUTS
    + LENS_ANALYSES
    + SIMULATE
    + DATASET_MAKE
    + TRAINING
    + RESTORING
    + EVALUATING
    + SHOOTING
    + USAGE
)


@pytest.mark.parametrize("c", ALL, ids=[c.id for c in ALL])
def test_bad_option(c: Case, world, tmp_path, capsys, monkeypatch) -> None:
    check_case(c, tmp_path, world, capsys, monkeypatch)


def test_case_ids_are_unique() -> None:
    assert len({c.id for c in ALL}) == len(ALL)


def test_warnings_and_errors_print_text_literally(capsys) -> None:
    """Square brackets are text, not rich markup; control characters are escaped."""
    from lensim.cli.common import _show_warning, print_error_line

    _show_warning("bad[bold]name.yaml: ccm [[1, 2], [3, 4]]", UserWarning, "x.py", 1)
    print_error_line("error", "red", "a\x00b [red]c[/red]\nd")
    assert capsys.readouterr().err.splitlines() == [
        "warning: bad[bold]name.yaml: ccm [[1, 2], [3, 4]]",
        "error: a\\x00b [red]c[/red] d",
    ]
