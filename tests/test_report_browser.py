"""The demo report renders in a real browser (headless Chromium): every figure decodes.

Slow (a quick demo plus a browser start): `bash scripts/setup_browser.sh` installs Debian's
Chromium, then `pytest -m slow tests/test_report_browser.py`."""

import shutil
import subprocess

import pytest


@pytest.mark.slow
def test_every_report_image_loads_in_headless_chromium(tmp_path):
    chromium = shutil.which("chromium")
    assert chromium, "Chromium is not installed: run scripts/setup_browser.sh"
    from lensim.demo import run_demo

    run_demo(tmp_path / "demo", quick=True)
    page = tmp_path / "demo" / "report.html"
    # a probe appended to a copy of the page reports how many images decoded
    probe = tmp_path / "probe.html"
    probe.write_text(
        page.read_text().replace(
            "</body>",
            "<script>window.onload=()=>{const i=[...document.images];"
            "document.title=`images ${i.length} loaded ${i.filter(x=>x.complete&&x.naturalWidth>0).length}`;}</script></body>",
        )
    )
    out = subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            f"--user-data-dir={tmp_path / 'profile'}",
            "--virtual-time-budget=5000",
            "--dump-dom",
            probe.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    import re

    m = re.search(r"<title>images (\d+) loaded (\d+)</title>", out.stdout)
    assert m, f"no result from Chromium: {out.stderr[-500:]}"
    total, loaded = int(m.group(1)), int(m.group(2))
    assert total >= 8 and loaded == total
