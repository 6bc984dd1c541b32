"""How long each shipped config takes a newcomer: `simrun CONFIG -j 2` (or `simrun fit`) from a cold numba cache,
figures included, timed whole; the run count and statuses read back from the results file.

    python -m benchmarks.config_times                        # every config in configs/, into config_times.json
    python -m benchmarks.config_times configs/fem_square.yaml  # some of them (the others' records are kept)
    python -m benchmarks.config_times --write-comments         # each config's comment quotes its record

The records go to benchmarks/config_times.json. tests/test_quoted_times.py holds every config comment and every
doc that quotes a config's time or run count to this file: a quote is `N runs, about T with -j 2`, T as
``time_text`` writes it. A cold cache is what a fresh clone's first run compiles; it is what a newcomer waits for.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORD = Path(__file__).with_name("config_times.json")
JOBS = 2
# The runs that did not end ok are listed by id for sweeps up to this size (a map's thousands are counted only).
MAX_LISTED_RUNS = 1000
# A config still running after this long is recorded as not finished (its time a lower bound).
DEFAULT_TIMEOUT = 1800.0


def time_text(seconds: float) -> str:
    """A measured total as the configs and docs quote it: "about 25 s", "about 2 min 30 s", "about 14 min".

    Rounded to what a newcomer can hold to on a machine like the one measured: 5 s under a minute, 10 s under ten
    minutes, whole minutes above."""
    if seconds < 57.5:
        return f"about {max(5, 5 * round(seconds / 5))} s"
    if seconds < 595:
        tens = round(seconds / 10)
        minutes, rest = divmod(10 * tens, 60)
        return f"about {minutes} min" + (f" {rest} s" if rest else "")
    return f"about {round(seconds / 60)} min"


def quote_text(record: dict) -> str:
    """The canonical quote of one config: "30 runs, about 25 s with -j 2" ("more than 30 min" when it did not finish)."""
    runs = record["runs"]
    total = time_text(record["seconds"]) if record["finished"] else f"more than {record['seconds'] / 60:.0f} min"
    return f"{runs:,} run{'s' if runs != 1 else ''}, {total} with -j {JOBS}"


def run_count(config: Path) -> int:
    from simrun.experiment.config import load_experiment
    from simrun.experiment.sweep import expand_runs

    experiment, _ = load_experiment(config)
    return len(expand_runs(experiment))


def is_calibration(config: Path) -> bool:
    import yaml

    return "fit" in (yaml.safe_load(config.read_text()) or {})


def measure(config: Path, timeout: float) -> dict:
    """One config, timed whole from a cold numba cache into a temporary folder."""
    import simrun

    command = "fit" if is_calibration(config) else "run"
    with tempfile.TemporaryDirectory(prefix="simrun-times-") as scratch:
        output = Path(scratch) / "output"
        environment = {**os.environ, "NUMBA_CACHE_DIR": str(Path(scratch) / "numba-cache")}
        arguments = [sys.executable, "-m", "simrun", command, str(config), "-j", str(JOBS), "--output", str(output), "-q"]
        load = os.getloadavg()[0]
        start = time.monotonic()
        try:
            finished = subprocess.run(arguments, cwd=ROOT, env=environment, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"seconds": timeout, "finished": False, "runs": run_count(config), "command": f"simrun {command}",
                    "load_before": round(load, 2)}
        seconds = time.monotonic() - start
        if finished.returncode != 0:
            raise SystemExit(f"{config}: simrun {command} exited with {finished.returncode}:\n{finished.stderr[-2000:]}")
        results = simrun.load(output / "results.h5")
        statuses = Counter(str(run.status) for run in results.runs.values())
        # the runs that did not end ok, by status: what a config's comment says of its outcomes is checked against them
        not_ok = {str(status): sorted(run_id for run_id, run in results.runs.items() if str(run.status) == str(status))
                  for status in statuses if str(status) != "ok"}
    return {"seconds": round(seconds, 1), "finished": True, "runs": len(results.runs), "statuses": dict(sorted(statuses.items())),
            "not_ok": dict(sorted(not_ok.items())) if len(results.runs) <= MAX_LISTED_RUNS else {},
            "command": f"simrun {command}", "load_before": round(load, 2)}


def machine() -> dict:
    from simrun.results.writer import cpu_description

    return {"cpu": cpu_description(), "python": platform.python_version(), "jobs": JOBS}


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


# the end of a config's canonical quote: where the number comes from
QUOTE_SOURCE = "on a fresh clone, numba's first compile included (benchmarks/config_times.json)."
QUOTE_LINE = re.compile(r"^# .*\d runs?, (?:about|more than) .* with -j \d+ on a fresh clone.*$", re.M)


def write_quote(config: Path, record: dict) -> None:
    """Put the config's canonical quote in its comment: in place of the old one, else as the comment's last line."""
    text = config.read_text()
    line = f"# {quote_text(record)} {QUOTE_SOURCE}"
    if QUOTE_LINE.search(text):
        text = QUOTE_LINE.sub(line, text, count=1)
    else:
        lines = text.splitlines(keepends=True)
        end = next(number for number, item in enumerate(lines) if not item.startswith("#"))
        lines.insert(end, line + "\n")
        text = "".join(lines)
    config.write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="*", type=Path, help="configs to measure (default: every one in configs/)")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, help="s per config before it is recorded unfinished")
    parser.add_argument("--write-comments", action="store_true",
                        help="measure nothing: write each recorded config's quote into its comment")
    args = parser.parse_args(argv)
    configs = args.configs or sorted((ROOT / "configs").glob("*.yaml"))
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {"configs": {}}
    if args.write_comments:
        for config in configs:
            if config.stem in record["configs"]:
                write_quote(config.resolve(), record["configs"][config.stem])
        return 0
    for config in configs:
        config = config.resolve()
        measured = measure(config, args.timeout)
        measured.update(date=datetime.date.today().isoformat(), commit=commit(), machine=machine())
        record["configs"][config.stem] = measured
        record["configs"] = dict(sorted(record["configs"].items()))
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
        shown = quote_text(measured) if measured["finished"] else f"not finished in {args.timeout:g} s"
        print(f"{config.stem}: {shown}  {measured.get('statuses', '')}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
