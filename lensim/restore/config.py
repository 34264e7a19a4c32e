"""Training settings (TrainConfig), apart from lensim.restore.train so that the command
line reads their defaults without importing torch (lensim.restore.train re-exports it)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from lensim.restore.arch_rules import ARCH_DEFAULTS, check_switches
from lensim.restore.psf_stage import WienerStage


def settings_dim(conditioning: dict[str, Any] | None) -> int:
    """Length of the settings vector of a run conditioned on ``conditioning`` (0: none)."""
    from lensim.restore.conditioning import Conditioning

    return Conditioning.from_dict(conditioning).dim


@dataclass
class TrainConfig:
    """Training settings (all recorded in RUN/config.json and in checkpoints).

    epochs: epochs to train in total (a resumed run may raise it).
    batch_size: crops per optimizer step (per rank under DDP).
    lr: initial Adam learning rate.
    lr_halve_every: epochs between halvings of the "step" schedule.
    lr_schedule: "step" (halve every ``lr_halve_every`` epochs) or "cosine" (lr * (1 +
        cos(pi p)) / 2 at progress p in [0, 1]: the share of the time budget spent when
        one is set, else of the epochs; set before every step); lensim.restore.schedule.
    crop: training sub-crop size in pixels (None: the stored crops).
    arch: "nafnet" (the default: lensim.restore.nafnet.NAFNet, one NAFBlock per encoder
        and decoder scale, two at the smallest), "unet" (the paper's field-aware UNet,
        lensim.restore.network.FieldAwareUNet) or "psfnet" (the PSF-informed network:
        NAFNet refining the Wiener stage's image, lensim.restore.psfnet; it needs the
        pairs' PSF bank); lensim.restore.models builds each.
    width: channels at full resolution (0: the architecture's default, the width at which
        the network, unconditioned, has the reference FieldAwareUNet's parameter count:
        lensim.restore.models.default_width).
    depth, use_fov, deformable_groups, deformable_scales: the network's scales and
        switches, for either architecture.
    use_deformable, use_context: deformable decoder blocks, context block (None: the
        architecture's default, ARCH_DEFAULTS: on for "unet", off for "nafnet").
    field_modulation: FieldAwareUNet only.
    stem: 2 for a pixel-unshuffle stem (every layer at half resolution; NAFNet only), 1 for
        none (0: the architecture's default, ARCH_DEFAULTS: "nafnet" 2, "unet" 1).
    The defaults (None / 0) are filled in by :meth:`resolved`; train() records the
    resolved values in RUN/config.json and in checkpoints.
    loss: the training loss, a key of lensim.restore.losses.LOSSES: "mse" (the paper's),
        "charbonnier" or "charbonnier-edge" (Charbonnier plus an edge term that does not
        reward over-smoothing).
    seed: seeds model initialisation, data order, crops and augmentation.
    augment: random FOV-consistent dihedral ops.
    val_fraction: share of source photos held out for validation.
    val_batch_size: crops per validation forward pass.
    device: "cpu", "cuda", "cuda:N".
    amp: mixed precision on CUDA (ignored on CPU).
    time_budget_s: stop cleanly (checkpoint, log row) once the run has trained this many
        seconds in all, counting the calls before a resume (None: no limit).
    max_steps_per_epoch: cap on steps per epoch (None: the whole epoch), for quick runs.
    checkpoint_every_s: also write RUN/last.pt within an epoch once this many seconds of
        training passed since the last checkpoint (None: at epoch ends only), so a kill
        loses at most that much work; a resume from it continues the same batches.
    checkpoint_every_steps: likewise every this many optimizer steps (None: off).
    use_settings: condition the network on the shooting settings of pairs made across a
        grid (lensim.restore.conditioning: the settings that vary over the training
        records become its inputs). False trains an unconditioned network on the same
        pairs; the ranges are still recorded (and checked when restoring). No effect on
        pairs without settings.
    on_nan: what a NaN or infinite loss (or weights) does: "rollback" (back to the last
        good checkpoint, the bad batch skipped from then on; stopped after repeated
        rollbacks) or "stop" (the run ends with a NonFiniteError, its last good checkpoint
        kept); lensim.restore.divergence.
    conditioning: what the run is conditioned on, Conditioning.to_dict() ({"keys": the
        inputs in vector order, "ranges": {key: [smallest, largest]} over the training
        records}); None: derived from the training records when the run starts (and
        recorded here, in RUN/config.json and in checkpoints).
    init: a checkpoint (or "universal": lensim.restore.universal's shipped model) whose
        weights a new run starts from instead of a random initialisation; its network must
        be the one these settings build. Not used when resuming.
    """

    epochs: int = 30
    batch_size: int = 4
    lr: float = 1e-4
    lr_halve_every: int = 5
    lr_schedule: str = "step"
    crop: int | None = 128
    arch: str = "nafnet"
    width: int = 0
    depth: int = 3
    use_fov: bool = True
    use_deformable: bool | None = None
    use_context: bool | None = None
    deformable_groups: int = 2
    deformable_scales: int | None = None
    field_modulation: bool = False
    loss: str = "mse"
    stem: int = 0
    seed: int = 0
    augment: bool = True
    val_fraction: float = 0.2
    val_batch_size: int = 8
    device: str = "cpu"
    amp: bool = True
    time_budget_s: float | None = None
    max_steps_per_epoch: int | None = None
    checkpoint_every_s: float | None = 300.0
    checkpoint_every_steps: int | None = None
    use_settings: bool = True
    on_nan: str = "rollback"
    conditioning: dict[str, Any] | None = None
    init: str | None = None

    def resolved(self) -> TrainConfig:
        """A copy with the architecture's defaults filled in: use_deformable, use_context
        (None) and stem (0) from ARCH_DEFAULTS, and width (0) from
        lensim.restore.models.default_width (imports torch; the size-matched width of the
        network the other settings describe, without settings inputs, so that it does not
        depend on the conditioning a run derives from its records). An unknown arch is
        left as it is (train() refuses it)."""
        defaults = ARCH_DEFAULTS.get(self.arch)
        if defaults is None:
            return replace(self)
        cfg = replace(
            self,
            use_deformable=defaults["use_deformable"] if self.use_deformable is None else self.use_deformable,
            use_context=defaults["use_context"] if self.use_context is None else self.use_context,
            stem=self.stem or defaults["stem"],
        )
        if cfg.width == 0:
            from lensim.restore.models import default_width

            unconditioned = replace(cfg, conditioning=None)._model_kwargs()
            switches = {k: v for k, v in unconditioned.items() if k not in ("arch", "width", "depth")}
            cfg.width = default_width(cfg.arch, **switches)
        return cfg

    def model_kwargs(self) -> dict[str, Any]:
        """The network's config for lensim.restore.models.build_model ("arch" included), of
        the resolved settings (:meth:`resolved`)."""
        return self.resolved()._model_kwargs()

    def _model_kwargs(self) -> dict[str, Any]:
        """model_kwargs of a config whose switches are resolved (width may still be 0)."""
        switches = {
            "use_fov": self.use_fov,
            "use_deformable": self.use_deformable,
            "use_context": self.use_context,
            "deformable_groups": self.deformable_groups,
            "settings_dim": settings_dim(self.conditioning),
        }
        n = self.depth - 1
        nafnet = self.arch in ("nafnet", "psfnet")  # psfnet: NAFNet's body (lensim.restore.psfnet)
        check_switches(  # which architecture takes which switches (lensim.restore.arch_rules)
            self.arch,
            use_fov=self.use_fov,
            use_deformable=bool(self.use_deformable),
            deformable_groups=self.deformable_groups,
            deformable_scales=n if nafnet and self.deformable_scales is None else self.deformable_scales,
            field_modulation=self.field_modulation,
            stem=self.stem,
            widths=tuple(self.width * 2**s for s in range(self.depth)) if self.width > 0 else None,
        )
        if nafnet:
            stage = {"stage": WienerStage().to_dict()} if self.arch == "psfnet" else {}
            return {
                **stage,
                "arch": self.arch,
                "width": self.width,
                "enc_blocks": [1] * n,
                "middle_blocks": 2,
                "dec_blocks": [1] * n,
                **switches,
                "stem": self.stem,
                "deformable_scales": n if self.deformable_scales is None else self.deformable_scales,
            }
        return {
            "arch": self.arch,
            "width": self.width,
            "depth": self.depth,
            **switches,
            "deformable_scales": self.deformable_scales,
            "field_modulation": self.field_modulation,
        }
