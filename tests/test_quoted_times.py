"""Every time a shipped config is quoted to take is the time recorded for it in benchmarks/config_times.json
(`python -m benchmarks.config_times`: the config run whole with -j 2 from a cold numba cache, figures included).

A config's comment states its run count and total as `N runs, about T with -j 2 on a fresh clone`; README.md and
docs/ quote a config's total as `about T with -j 2` (or "on two cores") after naming the config, `name.yaml`, in the
same paragraph. T is what ``time_text`` writes for the recorded seconds, so a quote changes only with a new
measurement. The runs themselves are not timed here: a timed unit test would measure the machine running the tests.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from conftest import config_params
from benchmarks.config_times import JOBS, RECORD, quote_text, time_text
from simrun.experiment.config import load_experiment
from simrun.experiment.sweep import expand_runs

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.yaml"))
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RECORDS = json.loads(RECORD.read_text())["configs"]
# a config's canonical quote in its comment
CONFIG_QUOTE = re.compile(rf"(\d[\d,]*) runs?, (about [^,;]*?|more than [^,;]*?) with -j {JOBS} on a fresh clone")
# a wall-clock total in the docs: "about 25 s with `-j 2`", "about 2 min 30 s on two cores"
DOC_QUOTE = re.compile(r"(about \d+(?:\.\d+)? (?:s|min(?: \d+ s)?|minutes?|seconds?)) (?:with `?-j ?2`?|on (?:two|2) cores|at -j ?2)")


def comment_of(config: Path) -> str:
    return " ".join(line.lstrip("#").strip() for line in config.read_text().splitlines() if line.startswith("#"))


def test_every_shipped_config_was_measured():
    assert sorted(RECORDS) == sorted(config.stem for config in CONFIGS)
    for name, record in RECORDS.items():
        assert record["machine"]["jobs"] == JOBS and record["seconds"] > 0, name


@pytest.mark.parametrize("config", config_params(CONFIGS))
def test_a_configs_comment_states_its_measured_total_and_run_count(config):
    record = RECORDS[config.stem]
    quotes = CONFIG_QUOTE.findall(comment_of(config))
    assert len(quotes) == 1, f"{config.name}: its comment must say once '{quote_text(record)} on a fresh clone'"
    experiment, _ = load_experiment(config)
    assert record["runs"] == len(expand_runs(experiment)), f"{config.name}: measured with another sweep; measure again"
    assert f"{quotes[0][0]} runs, {quotes[0][1]}" == quote_text(record).removesuffix(f" with -j {JOBS}"), config.name
    for quote in DOC_QUOTE.finditer(comment_of(config)):  # no other total in the comment
        assert quote.group(1) == time_text(record["seconds"]), f"{config.name}: {quote.group(0)!r}"


def paragraphs(text: str) -> list[str]:
    return [" ".join(block.split()) for block in re.split(r"\n\s*\n", text)]


@pytest.mark.parametrize("page", PAGES, ids=lambda path: path.name)
def test_a_config_time_the_docs_quote_is_the_measured_one(page):
    for paragraph in paragraphs(page.read_text()):
        for quote in DOC_QUOTE.finditer(paragraph):
            named = re.findall(r"(\w+)\.yaml", paragraph[:quote.start()])
            assert named and named[-1] in RECORDS, f"{page.name}: '{quote.group(0)}' names no shipped config before it"
            assert quote.group(1) == time_text(RECORDS[named[-1]]["seconds"]), \
                f"{page.name}: {named[-1]}.yaml {quote.group(0)!r}; measured: {time_text(RECORDS[named[-1]]['seconds'])}"


@pytest.mark.parametrize("seconds, text", [(3.0, "about 5 s"), (23.0, "about 25 s"), (57.4, "about 55 s"),
                                           (58.0, "about 1 min"), (151.0, "about 2 min 30 s"), (594.0, "about 9 min 50 s"),
                                           (846.0, "about 14 min")])
def test_time_text_rounds_to_what_a_machine_like_the_measured_one_repeats(seconds, text):
    assert time_text(seconds) == text
