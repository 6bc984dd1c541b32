"""Reports that scale: a sweep over many settings is answered across them, not setting by setting, and
the page of the shipped 42,000-run damping map opens on its answer and its figures, about three screens, with every
table behind <details>. The page is measured in headless Chromium (skipped where it is not installed, unless
SIMRUN_REQUIRE_CHROMIUM=1, as CI sets it)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

import simrun
from simrun.figures import figure_data
from simrun.findings import findings
from simrun.report.page import ANSWER_FINDINGS, answer, write_report

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SCREEN = (1280, 900)  # CSS px: a laptop's browser window


def _map(tmp_path, stiffness: int, ratios: int):
    config = {"name": "small_map", "system": {"type": "spring_mass", "mass": 1.0, "damping_ratio": 0.0, "x0": 1.0},
              "integrators": ["backward_euler", "implicit_midpoint", "symplectic_euler"], "duration": 2.0,
              "sweep": {"dt": [0.01], "system.stiffness": {"logspace": [0.0, 6.0, stiffness]},
                        "system.damping_ratio": {"linspace": [0.0, 0.9, ratios]}}}
    return simrun.run(config, output=tmp_path / "map", jobs=1, progress=False, figures=False)


def test_a_sweep_over_many_settings_is_answered_across_them(tmp_path):
    """6 stiffnesses x 4 damping ratios, three methods, dt = 0.01 s (h w = 0.01 ... 10): the stability findings say who
    held at how many settings (backward Euler and implicit midpoint at all 6 undamped ones, where a limit is
    predicted, and at the 18 damped ones; symplectic Euler diverging where h w > 2, at the two stiffest of each
    ratio), the largest-dt finding and the accuracy ranking count settings, and no finding names one setting at a
    time."""
    results = _map(tmp_path, 6, 4)
    with results.opened():
        found = findings(figure_data(results))
    stability = [finding.sentence for finding in found if finding.topic == "stability"]
    assert ("backward_euler and implicit_midpoint at 6 of 24 settings (system.damping_ratio 0, system.stiffness 1 … "
            "1e+06): measured: reached the end without diverging") in " ".join(stability), stability
    assert any(sentence.startswith("Every run of backward_euler and implicit_midpoint at 18 of 24 settings "
                                   "(system.damping_ratio 0.3 … 0.9, system.stiffness 1 … 1e+06)") for sentence in stability)
    # w = sqrt(k) = 1, 3.98, 15.8, 63.1, 251, 1000 rad/s: h w > 2 for the two stiffest, 2 x 4 settings
    diverged = [sentence for sentence in stability if sentence.startswith("symplectic_euler at ")
                and "diverged at dt = 0.01 s" in sentence]
    assert {re.match(r"symplectic_euler at (\d+) of 24", sentence).group(1) for sentence in diverged} == {"6", "2"}
    assert all("system.stiffness 6.31e+04 … 1e+06" in sentence for sentence in diverged), diverged
    assert any("At the largest dt, 0.01 s, at 8 of 24 settings (system.damping_ratio 0 … 0.9, system.stiffness "
               "6.31e+04 … 1e+06): only backward_euler and implicit_midpoint" in sentence for sentence in stability)
    accuracy = [finding for finding in found if finding.topic == "accuracy" and "more" not in finding.evidence]
    assert accuracy and all(re.search(r"at [\d,]+ of 24 settings: the cheapest method", finding.sentence)
                            for finding in accuracy)
    # not one sentence per setting: fewer findings than settings, and a setting named alone only where it is alone
    assert len(found) < 24
    named_alone = [finding.sentence for finding in found if "system.stiffness = " in finding.sentence]
    assert len(named_alone) <= 1 and all("at system.stiffness = " in sentence for sentence in named_alone), named_alone
    chosen = answer(found)
    assert len(chosen) <= ANSWER_FINDINGS and {finding.topic for finding in chosen} >= {"stability", "accuracy"}


class _Page(HTMLParser):
    """Where each table is: inside a <details> or not, by the id of its section."""

    def __init__(self):
        super().__init__()
        self.section, self.open_details, self.tables = None, 0, []

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self.section = dict(attrs).get("id")
        elif tag == "details":
            self.open_details += 1
        elif tag == "table":
            self.tables.append((self.section, self.open_details > 0))

    def handle_endtag(self, tag):
        if tag == "details":
            self.open_details -= 1


def _chromium() -> str:
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        if os.environ.get("SIMRUN_REQUIRE_CHROMIUM"):
            pytest.fail("SIMRUN_REQUIRE_CHROMIUM=1 but no chromium on PATH")
        pytest.skip("headless Chromium is not installed (Debian: apt-get install chromium)")
    return browser


def page_layout(browser: str, page: Path, folder: Path) -> dict[str, tuple[int, int]]:
    """{"page": (0, height), section id: (top, height)} in CSS px, the page laid out in headless Chromium at SCREEN,
    every <details> closed as it opens."""
    script = ("<script>addEventListener('load',()=>{const p=document.createElement('pre');p.id='layout';"
              "p.textContent=['page:0:'+document.documentElement.scrollHeight].concat([...document.querySelectorAll("
              "'section')].map(s=>{const r=s.getBoundingClientRect();return s.id+':'+Math.round(r.top+scrollY)+':'"
              "+Math.round(r.height);})).join(' ');document.body.appendChild(p);});</script>")
    probe = folder / "probe.html"
    probe.write_text(page.read_text().replace("</body>", script + "</body>"))
    dumped = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             "--disable-background-networking", "--disable-component-update", "--disable-sync",
                             f"--user-data-dir={folder / 'profile'}", f"--window-size={SCREEN[0]},{SCREEN[1]}",
                             "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                            capture_output=True, text=True, timeout=180).stdout
    found = re.search(r'<pre id="layout">([^<]*)</pre>', dumped)
    assert found, dumped[-2000:]
    layout = {}
    for item in found.group(1).split():
        name, top, height = item.rsplit(":", 2)
        layout[name] = (int(top), int(height))
    layout["page"] = (0, layout["page"][1])
    return layout


@pytest.mark.slow
def test_the_damping_maps_report_opens_on_its_answer_in_about_three_screens(tmp_path):
    """configs/damping_map.yaml as shipped (42,000 runs): the findings (at most ANSWER_FINDINGS, no run listed one by
    one) and the figures end within 3.6 screens; every table of runs is collapsed; the whole page, details closed,
    is under 5 screens (it was 156 screens)."""
    browser = _chromium()
    results = simrun.run(CONFIGS / "damping_map.yaml", output=tmp_path / "map", jobs=2, progress=False, figures=False)
    page = write_report(results.path, tmp_path / "map" / "report.html", reference="none")
    text = page.read_text()
    parsed = _Page()
    parsed.feed(text)
    assert parsed.tables and all(collapsed for _, collapsed in parsed.tables), parsed.tables
    answer_list = text[text.index('<section id="findings">'):].split("<details>", 1)[0]
    assert answer_list.count("<li") <= ANSWER_FINDINGS
    layout = page_layout(browser, page, tmp_path)
    answer_and_figures = layout["figures"][0] + layout["figures"][1]
    assert layout["findings"][0] < layout["figures"][0] < layout["summary"][0]
    assert answer_and_figures <= 3.6 * SCREEN[1], layout
    assert layout["page"][1] <= 5 * SCREEN[1], layout
