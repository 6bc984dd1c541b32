"""How long each shipped config takes a newcomer: `simrun CONFIG -j 2` (or `simrun fit`) from a cold numba cache,
figures included, timed whole; the run count and statuses read back from the results file.

    python -m benchmarks.config_times                        # every config in configs/, into config_times.json
    python -m benchmarks.config_times configs/fem_square.yaml  # some of them (the others' records are kept)

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
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORD = Path(__file__).with_name("config_times.json")
JOBS = 2
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
    """The canonical quote of one config: "30 runs, about 25 s with -j 2"."""
    runs = record["runs"]
    return f"{runs:,} run{'s' if runs != 1 else ''}, {time_text(record['seconds'])} with -j {JOBS}"


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
            return {"seconds": timeout, "finished": False, "command": f"simrun {command}", "load_before": load}
        seconds = time.monotonic() - start
        if finished.returncode != 0:
            raise SystemExit(f"{config}: simrun {command} exited with {finished.returncode}:\n{finished.stderr[-2000:]}")
        results = simrun.load(output / "results.h5")
        statuses = Counter(str(run.status) for run in results.runs.values())
    return {"seconds": round(seconds, 1), "finished": True, "runs": len(results.runs), "statuses": dict(sorted(statuses.items())),
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("configs", nargs="*", type=Path, help="configs to measure (default: every one in configs/)")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, help="s per config before it is recorded unfinished")
    args = parser.parse_args(argv)
    configs = args.configs or sorted((ROOT / "configs").glob("*.yaml"))
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {"configs": {}}
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
