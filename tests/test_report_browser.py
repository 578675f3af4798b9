"""The report page in a real headless browser (Debian's chromium): it loads with no console
error, every plotly figure renders, and the screenshot shows them (kept as an artefact in
out/test_artifacts/report_screenshot.png)."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess

import matplotlib.image
import numpy as np
import pytest

from tests.cli_runner import softforce
from tests.report_fixtures import ARTIFACTS, sense_folder

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
# Headless, as root in containers, with software WebGL (the 3D view) and a fixed viewport.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--hide-scrollbars", "--window-size=1200,4200",
         "--virtual-time-budget=20000")
# Injected first in a copy of the page: records uncaught errors and console.error calls, and
# once the page has loaded writes them, with the number of plots drawn, into the title.
PROBE = """<script>
window.__errors = [];
window.addEventListener("error", e => window.__errors.push(String(e.message)));
const __error = console.error;
console.error = (...args) => { window.__errors.push(args.join(" ")); __error(...args); };
window.addEventListener("load", () => setTimeout(() => {
  document.title = JSON.stringify({errors: window.__errors,
    figures: document.querySelectorAll("div[id^=figure-]").length,
    drawn: document.querySelectorAll("div[id^=figure-] .main-svg").length,
    webgl: document.querySelectorAll("div[id^=figure-] canvas").length,
    scene: (r => [r.top + scrollY, r.bottom + scrollY])(
      document.getElementById("figure-contacts").getBoundingClientRect())});
}, 2000));
</script>"""
# The robot's surface colour in the 3D view (page.scene_div), #7fa3d9, shaded.
MESH_RGB = np.array([0x7F, 0xA3, 0xD9]) / 255


@pytest.fixture(scope="module")
def browser():
    found = next((shutil.which(name) for name in BROWSERS if shutil.which(name)), None)
    if found is None:
        pytest.skip("no chromium on PATH: install Debian's chromium (make setup runs "
                    "scripts/install_system_packages.sh, which installs it) for this test")
    return found


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    sense = sense_folder(tmp_path_factory.getbasetemp() / "report_inputs")
    html = sense / "report" / "report.html"
    if not html.is_file():  # test_report.py makes it when it runs first in the session
        result = softforce("report", sense)
        assert result.returncode == 0, result.stderr
    return html


def _run(browser, *args):
    return subprocess.run([browser, *FLAGS, *args], capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def probed(browser, page, tmp_path_factory):
    """A copy of the page with PROBE loaded once: what PROBE found (read from the DOM), the
    screenshot, and the browser's log."""
    folder = tmp_path_factory.mktemp("browser")
    path, shot = folder / "probed.html", folder / "report.png"
    path.write_text(page.read_text().replace("<head>", "<head>" + PROBE, 1))
    result = _run(browser, "--dump-dom", f"--screenshot={shot}", "--enable-logging=stderr",
                  "--v=0", path.as_uri())
    title = re.search(r"<title>(.*?)</title>", result.stdout, re.S)
    assert title is not None and shot.is_file(), result.stderr[-2000:]
    return json.loads(html.unescape(title.group(1))), shot, result.stderr


def test_page_loads_without_errors_and_draws_every_figure(probed):
    state, _, log = probed
    assert state["errors"] == []
    assert "Uncaught" not in log
    assert state["figures"] >= 6  # forces, contacts (3D), residual, features, timings, truth
    assert state["drawn"] >= state["figures"]  # each figure drew its SVG layer
    assert state["webgl"] >= 1  # the 3D view's WebGL canvas


def test_screenshot_shows_the_figures(probed):
    """The probed copy (PROBE changes only the title, not the layout) photographed."""
    state, shot, _ = probed
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shutil.copy(shot, ARTIFACTS / "report_screenshot.png")
    image = matplotlib.image.imread(shot)[:, :, :3]
    ink = (image < 0.9).any(axis=2)  # not white: text, axes, lines, the robot
    bands = ink.reshape(-1, 300, image.shape[1]).mean(axis=(1, 2))
    assert (bands > 0.01).sum() >= 10, bands.round(3)  # most 300 px bands hold something
    top, bottom = (int(v) for v in state["scene"])
    mesh = np.linalg.norm(image[top:bottom] - MESH_RGB, axis=2) < 0.15
    assert mesh.sum() > 2000  # the 3D view's WebGL drew the robot's surface
