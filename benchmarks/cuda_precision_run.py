"""Run a `lensim` command with CUDA's TF32 shortcuts on or off (issue 23's GPU pretraining check).

PyTorch lets cuDNN convolutions use TF32 (a 10-bit mantissa) by default on Ampere and later
GPUs; matrix products do not. This wrapper sets both switches, then runs the command line
exactly as `python -m lensim` would:

    python benchmarks/cuda_precision_run.py --tf32 off library pretrain PAIRS -o RUN --device cuda
"""

from __future__ import annotations

import sys


def main(argv: list[str]) -> None:
    """argv: ``--tf32 on|off`` followed by the lensim command line."""
    if len(argv) < 2 or argv[0] != "--tf32" or argv[1] not in ("on", "off"):
        sys.exit("usage: cuda_precision_run.py --tf32 on|off LENSIM_ARGS...")
    import torch

    allow = argv[1] == "on"
    torch.backends.cudnn.allow_tf32 = allow
    torch.backends.cuda.matmul.allow_tf32 = allow
    from lensim.cli import main as lensim_main

    sys.argv = ["lensim", *argv[2:]]
    lensim_main()


if __name__ == "__main__":
    main(sys.argv[1:])
