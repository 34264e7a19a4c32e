"""Check a demo report: report.json and report.html exist, the metrics of the methods the
report must hold are finite numbers, every embedded image is a PNG. Exit 1 with a reason
otherwise. Usage: python scripts/check_report.py DEMO_DIR"""

import base64
import json
import math
import re
import sys
from pathlib import Path

out = Path(sys.argv[1])
report = json.loads((out / "report.json").read_text())
problems = []
methods = report["metrics"]["methods"]
required = ["input", "model", "plain", "wiener"]
if (report.get("training", {}).get("model") or {}).get("init") == "universal":
    required.append("universal")  # the demo's network started from it: its zero-shot score is shown
for name in required:
    m = methods.get(name)
    if m is None:
        problems.append(f"metrics: no method {name}")
        continue
    for key in ("psnr_db", "ssim"):
        if not isinstance(m.get(key), (int, float)) or not math.isfinite(m[key]):
            problems.append(f"metrics.{name}.{key}: expected a finite number, got {m.get(key)!r}")
for row in report["slanted_edge"]:
    for stage in ("before", "after"):
        if not math.isfinite(row[stage]["mtf_area"]):
            problems.append(f"slanted_edge: non-finite MTF area at field {row['normalized_field']}")
raw_file = report.get("raw_file") or {}
for key in ("developed_psnr_db", "restored_psnr_db"):  # the demo's raw stage: a DNG through `lensim restore`
    if not isinstance(raw_file.get(key), (int, float)) or not math.isfinite(raw_file[key]):
        problems.append(f"raw_file.{key}: expected a finite number, got {raw_file.get(key)!r}")
page = (out / "report.html").read_text()
images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
if len(images) < 8:
    problems.append(f"report.html: expected at least 8 embedded figures, found {len(images)}")
for i, data in enumerate(images):
    if not base64.b64decode(data).startswith(b"\x89PNG"):
        problems.append(f"report.html: embedded image {i} is not a PNG")
if problems:
    print("report check failed: " + "; ".join(problems))
    sys.exit(1)
print(
    f"report check passed: {len(images)} figures, "
    + ", ".join(f"{k} {v['psnr_db']:.2f} dB" for k, v in methods.items())
)
