"""lensim: optical aberration simulation and correction from a lens prescription."""
import os as _os

# torch's OpenMP threads spin-wait for partners; on shared machines another process holding
# a core makes that 10-30x slower (benchmarks/README.md). Passive waiting costs little on a
# dedicated machine; set OMP_WAIT_POLICY yourself to override. Must precede torch's import.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
