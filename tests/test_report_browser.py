"""The HTML report in a real browser: headless Chromium driven by Playwright.

Needs Debian's ``chromium`` (``.ci/run`` installs it) and the ``playwright``
Python package (the ``test`` extra); never ``playwright install``: the
system browser is used through ``executable_path``.
"""
import shutil
from pathlib import Path

import pytest

from mcvar import report
from test_experiments import fake_target

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')")
if CHROMIUM is None:
    pytest.skip("no Chromium browser installed (apt-get install chromium; .ci/run does)", allow_module_level=True)


@pytest.fixture(scope="module")
def page_in_browser(tmp_path_factory):
    out = tmp_path_factory.mktemp("browser-report")
    target = fake_target(methods=("unbiased", "biased"), samplers=("random",), spp=(1, 4, 16, 64))
    paths = report.convergence_report(target, out, replicates=6, seed=31337, workers=1, progress=False)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page()
            messages, errors = [], []
            page.on("console", lambda m: messages.append((m.type, m.text)))
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(paths["html"].resolve().as_uri(), wait_until="load")
            yield page, messages, errors
        finally:
            browser.close()


def test_page_loads_without_errors(page_in_browser):
    page, messages, errors = page_in_browser
    assert errors == []
    assert [m for m in messages if m[0] == "error"] == []


def test_every_image_decodes(page_in_browser):
    page, _, _ = page_in_browser
    sizes = page.eval_on_selector_all(
        "img", "imgs => imgs.map(i => [i.complete, i.naturalWidth, i.naturalHeight])")
    # 5 figures, the reference, and an estimate and an error map per method
    assert len(sizes) == 5 + 1 + 2 * 2
    assert all(done and w > 0 and h > 0 for done, w, h in sizes), sizes
    # the image tiles are upscaled: at least 256 pixels wide, shown without smoothing
    tiles = page.eval_on_selector_all(
        ".tile img", "imgs => imgs.map(i => [i.naturalWidth, getComputedStyle(i).imageRendering])")
    assert tiles and all(w >= 256 and r == "pixelated" for w, r in tiles), tiles


def test_verdict_table_comes_first_and_details_open_for_print(page_in_browser):
    page, _, _ = page_in_browser
    rows = page.eval_on_selector_all("table.verdicts tbody tr",
                                     "rows => rows.map(r => [...r.cells].map(c => c.textContent))")
    assert [r[0] for r in rows] == ["unbiased", "biased"]
    assert rows[0][3] == "both" and rows[1][3] == "neither"
    headings = page.eval_on_selector_all("h2", "hs => hs.map(h => h.textContent)")
    assert headings[:2] == ["Verdicts", "Speed for accuracy"]
    shown = "() => [...document.querySelectorAll('details table')].map(t => t.checkVisibility())"
    assert page.evaluate(shown) and not any(page.evaluate(shown))  # collapsed on screen
    page.emulate_media(media="print")  # the print stylesheet alone opens them ...
    assert all(page.evaluate(shown))
    page.emulate_media(media="screen")
    page.evaluate("() => window.dispatchEvent(new Event('beforeprint'))")  # ... and so does the script
    assert all(page.evaluate(shown))
