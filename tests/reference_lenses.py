"""Where the vendored reference lenses live: tests/data/lenses (see its README.md).

Test modules and benchmarks import REFERENCE_LENSES from here (tests/ is on sys.path, as
for cli_runner); fixtures get it through conftest's `reference_lenses`. Nothing in the
tests reads files from outside the repository.
"""

from pathlib import Path

REFERENCE_LENSES = Path(__file__).resolve().parent / "data" / "lenses"
