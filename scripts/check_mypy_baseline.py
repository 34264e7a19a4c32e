"""mypy on the library against a baseline that only shrinks: .mypy-baseline.txt holds the
number of mypy errors per module when type checking came in. This script runs `mypy`
(settings in pyproject.toml's [tool.mypy]) and fails when any module has more errors than
its baseline (a module not listed has 0); when a module has fewer, it says so, and
``--update`` lowers the baseline to the new counts (it never raises one).

    python scripts/check_mypy_baseline.py            # CI: fail on growth, note shrinkage
    python scripts/check_mypy_baseline.py --update   # lower the baseline where counts fell
    python scripts/check_mypy_baseline.py --init     # record the current counts (once)

A module renamed or split takes its counts along: edit the file by hand in the same commit
(the total must not grow).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BASELINE = REPO / ".mypy-baseline.txt"
HEADER = (
    "# mypy errors per module (python scripts/check_mypy_baseline.py); counts may only fall:\n"
    "# fix errors, then run it with --update\n"
)
ERROR = re.compile(r"^(?P<path>[^:\s]+\.pyi?):\d+(?::\d+)?: error: ")


def module_name(path: str) -> str:
    """lensim/psf/bank/__init__.py -> lensim.psf.bank."""
    parts = list(Path(path).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def mypy_counts() -> Counter[str]:
    """Errors per module from `python -m mypy` (its paths and options from pyproject.toml)."""
    run = subprocess.run([sys.executable, "-m", "mypy"], cwd=REPO, capture_output=True, text=True, check=False)
    counts: Counter[str] = Counter()
    for line in run.stdout.splitlines():
        match = ERROR.match(line)
        if match:
            counts[module_name(match["path"])] += 1
    if run.returncode not in (0, 1) or (run.returncode == 1 and not counts):
        raise SystemExit(f"mypy failed ({run.returncode}):\n{run.stdout}{run.stderr}")
    return counts


def read_baseline() -> dict[str, int]:
    baseline: dict[str, int] = {}
    for number, line in enumerate(BASELINE.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip() and not line.startswith("#"):
            try:
                module, count = line.split()
                baseline[module] = int(count)
            except ValueError:
                raise SystemExit(f"{BASELINE}:{number}: expected 'module count', got {line!r}") from None
    return baseline


def write_baseline(counts: dict[str, int]) -> None:
    from lensim.io import atomic_write_text

    rows = "".join(f"{module} {n}\n" for module, n in sorted(counts.items()) if n > 0)
    atomic_write_text(BASELINE, HEADER + rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--update", action="store_true", help="lower the baseline where the counts fell")
    mode.add_argument("--init", action="store_true", help="record the current counts as the baseline")
    args = parser.parse_args()
    counts = mypy_counts()
    if args.init:
        write_baseline(dict(counts))
        print(f"mypy baseline: {sum(counts.values())} errors in {len(counts)} modules recorded")
        return 0
    baseline = read_baseline()
    grew = {m: (baseline.get(m, 0), n) for m, n in counts.items() if n > baseline.get(m, 0)}
    fell = {m: (b, counts.get(m, 0)) for m, b in baseline.items() if counts.get(m, 0) < b}
    if args.update:
        write_baseline({m: min(b, counts.get(m, 0)) for m, b in baseline.items()})
        fell = {}
    for module, (before, now) in sorted(grew.items()):
        print(
            f"mypy: {module} has {now} errors, its baseline is {before}: fix the new ones "
            f"(`.venv/bin/mypy -m {module}` lists them)"
        )
    if fell:
        lower = ", ".join(f"{m} ({b} -> {n})" for m, (b, n) in sorted(fell.items()))
        print(
            f"mypy: fewer errors than the baseline in {lower}; "
            "run `python scripts/check_mypy_baseline.py --update` to lower it"
        )
    print(
        f"mypy: {sum(counts.values())} errors in {len(counts)} modules (baseline {sum(baseline.values())})"
        + ("" if not grew else f"; {len(grew)} modules over their baseline")
    )
    return 1 if grew else 0


if __name__ == "__main__":
    sys.exit(main())
