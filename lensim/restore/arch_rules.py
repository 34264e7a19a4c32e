"""Which restoration network takes which switches: the one home of these rules, used by
the constructors (lensim.restore.network.FieldAwareUNet, lensim.restore.nafnet.NAFNet),
by TrainConfig (lensim.restore.config) and by `lensim train` before any work. Plain
Python (no torch), so the command line checks its options without loading the networks.

The architectures are "nafnet" (the default network: NAFNet with the FOV channels and a 2x
pixel-unshuffle stem), "unet" (the paper's field-aware UNet) and "psfnet" (the
PSF-informed network: NAFNet's body refining the Wiener stage's image; NAFNet's rules). The rules:

- field_modulation is a UNet switch, and it is computed from the FOV channels (use_fov);
- stem (a 2x pixel-unshuffle stem: 2, none: 1) is a NAFNet switch: the UNet takes 1 only;
- deformable blocks split their channels into deformable_groups offset groups, which must
  divide every decoder width;
- deformable_scales counts the deformable decoder scales, coarsest first: 0 up to the
  number of decoder scales for the UNet (None: all), at least 1 for NAFNet with deformable
  blocks (use_deformable=False has none).

A broken rule is an InputError naming the parameter (the command line maps it to its
option); InputError is a ValueError, what the constructors raise for bad arguments.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from lensim.errors import InputError

#: the restoration architectures lensim.restore.models.build_model knows
ARCHS: tuple[str, ...] = ("unet", "nafnet", "psfnet")
#: the stems NAFNet takes: 1 (none) or 2 (a 2x pixel-unshuffle stem)
STEMS = (1, 2)

#: Each architecture's defaults of the switches TrainConfig leaves unset (None / 0): the
#: paper's UNet has the deformable decoder, the context block and no stem; the default
#: network, NAFNet with FOV channels, has neither and a 2x pixel-unshuffle stem
#: (benchmarks/results/nafnet_vs_unet_30min: 30 minutes of training each, two seeds,
#: +0.18 to +0.33 dB over the UNet on held-out photos, +0.04 to +0.10 dB on unseen ones;
#: restores 3.0x faster).
ARCH_DEFAULTS: dict[str, dict[str, Any]] = {
    "unet": {"use_deformable": True, "use_context": True, "stem": 1},
    "nafnet": {"use_deformable": False, "use_context": False, "stem": 2},
    # the PSF-informed network (issue 23): the default network's body refining the Wiener
    # stage's image (lensim.restore.psfnet); NAFNet's rules
    "psfnet": {"use_deformable": False, "use_context": False, "stem": 2},
}


def check_arch(arch: str) -> None:
    """An architecture lensim knows (ARCHS)."""
    if arch not in ARCHS:
        raise InputError(None, "arch", f"expected one of {', '.join(ARCHS)}, got {arch!r}")


def check_switches(
    arch: str | None,
    *,
    use_fov: bool = True,
    use_deformable: bool = False,
    deformable_groups: int = 2,
    deformable_scales: int | None = None,
    field_modulation: bool = False,
    stem: int = 1,
    widths: Sequence[int] | None = None,
) -> None:
    """The rules of the module docstring for a network of `arch` with these switches
    (arch None: not known yet, e.g. a resumed run's; only the rules that hold for every
    architecture). widths: the channels at each scale, finest first (None: not known yet,
    e.g. a default width still to be chosen; the rules that need them are skipped).

    Raises InputError naming the parameter that breaks a rule."""
    if arch is not None:
        check_arch(arch)
    if deformable_groups < 1:
        raise InputError(None, "deformable_groups", f"expected at least 1 offset group, got {deformable_groups}")
    if field_modulation and not use_fov:
        raise InputError(
            None, "field_modulation", "is computed from the field-of-view input; expected it with use_fov=True"
        )
    if stem not in STEMS:
        raise InputError(None, "stem", f"expected one of {', '.join(map(str, STEMS))}, got {stem}")
    if arch is None:
        return
    if field_modulation and arch != "unet":
        raise InputError(None, "field_modulation", f"is an option of arch 'unet'; expected it off with arch {arch!r}")
    if arch == "unet" and stem != 1:
        raise InputError(None, "stem", f"is an option of arch 'nafnet'; expected 1 with arch 'unet', got {stem}")
    if use_deformable and widths is not None and any(w % deformable_groups for w in widths[:-1]):
        raise InputError(
            None,
            "deformable_groups",
            f"expected a divisor of the decoder widths {tuple(widths[:-1])}, got {deformable_groups}",
        )
    _check_scales(arch, use_deformable, deformable_scales, None if widths is None else len(widths) - 1)


def _check_scales(arch: str, use_deformable: bool, scales: int | None, n_dec: int | None) -> None:
    """deformable_scales against the number of decoder scales (None: not known yet)."""
    nafnet = arch in ("nafnet", "psfnet")
    if scales is None or (nafnet and not use_deformable):  # None: all; no deformable blocks: unused
        return
    low = 1 if nafnet else 0
    if scales < low or (n_dec is not None and scales > n_dec):
        top = " or more" if n_dec is None else f" to {n_dec}"
        why = " (use_deformable=False for none)" if low else ""
        raise InputError(
            None, "deformable_scales", f"expected {low}{top} decoder scales with arch {arch!r}{why}, got {scales}"
        )
