"""Do two versions of simrun give the same results? Every dataset bit for bit, every attribute equal.

A change that should not change behaviour (a refactoring) is checked with it: the shipped configs are run by the
code of a git revision and by the working tree, and the two results files are compared. Only what measures the
machine is left out: wall times and what follows from them, the creation time, the host, the command line.

    python tests/compare_results.py files OLD.h5 NEW.h5
    python tests/compare_results.py revision REV [CONFIG ...] [--all] [--jobs N] [--keep DIR]

``revision`` checks REV out into a temporary git worktree and runs each config twice, once with each code, from a
package tree of symbolic links (so neither needs installing: the environment running this script provides the
dependencies). Without CONFIG it runs FAST_CONFIGS, the shipped configs that take seconds; ``--all`` runs every
config in configs/. Exit status 0 when every file agrees, 1 when one differs (each difference printed).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# the shipped configs that run in seconds each, covering the producers of runs: fixed steps, controlled steps,
# lanes (damping_curves' spring runs), a scipy peer (high_order_kepler), contact, FEM, and a record without series
FAST_CONFIGS = ("quickstart", "spring_stability", "circular_orbits", "damping_curves", "high_order_kepler",
                "course_square", "xpbd_damping", "fem_square")

# what measures the machine or the moment, not the run: left out of the comparison
# (``config``: the config's text, whose comments may change, and ``config_hash``, which hashes the model files' absolute
# paths: ``resolved_config`` holds what they mean, compared with the two checkouts' paths made one)
VOLATILE_ATTRIBUTES = frozenset({"wall_time", "created", "host", "cpu", "command_line", "package_versions", "config",
                                 "config_hash",
                                 "simrun_version", "config_git_commit", "threads", "real_time_factor",
                                 "wall_time_per_frame", "time_per_step"})
VOLATILE_COLUMNS = frozenset({"wall_time", "real_time_factor", "wall_time_per_frame"})
# datasets that hold wall times, per step or per frame
VOLATILE_DATASETS = frozenset({"step_wall_time", "frame_wall_time", "solve_wall_time"})


def _equal(a, b, aliases=()) -> bool:
    """Bit for bit where both are arrays of one dtype (NaN equal to NaN at the same place); equal values otherwise,
    texts after each (old, new) of ``aliases`` is replaced in the old one (the checkouts' folders)."""
    if isinstance(a, bytes) and isinstance(b, bytes):
        a, b = a.decode(), b.decode()
    if isinstance(a, str) and isinstance(b, str):
        for old, new in aliases:
            a = a.replace(old, new)
        return a == b
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        if a.dtype.names:
            return all(_equal(a[name], b[name]) for name in a.dtype.names)
        if a.dtype.kind in "fc":
            return a.tobytes() == b.tobytes() or bool(np.array_equal(a, b, equal_nan=True))
        return bool(np.array_equal(a, b))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def _attributes(node) -> dict:
    return {key: node.attrs[key] for key in node.attrs if key not in VOLATILE_ATTRIBUTES}


def differences(old_path: Path, new_path: Path, aliases=()) -> list[str]:
    """Every way the two results files differ, one line each (empty: the same results); ``aliases``: (old, new)
    pairs of texts that stand for the same thing (the two checkouts' folders in a file path)."""
    found: list[str] = []
    with h5py.File(old_path, "r") as old, h5py.File(new_path, "r") as new:
        def compare(name: str, a, b) -> None:
            where = name or "/"
            attrs_a, attrs_b = _attributes(a), _attributes(b)
            for key in sorted(attrs_a.keys() | attrs_b.keys()):
                if key not in attrs_a or key not in attrs_b:
                    found.append(f"{where}: attribute {key!r} only in {'new' if key in attrs_b else 'old'}")
                elif not _equal(attrs_a[key], attrs_b[key], aliases):
                    found.append(f"{where}: attribute {key!r}: {attrs_a[key]!r} != {attrs_b[key]!r}")
            if isinstance(a, h5py.Dataset) or isinstance(b, h5py.Dataset):
                if not (isinstance(a, h5py.Dataset) and isinstance(b, h5py.Dataset)):
                    found.append(f"{where}: a dataset in one file only")
                    return
                if name.rsplit("/", 1)[-1] in VOLATILE_DATASETS:
                    return
                values_a, values_b = a[()], b[()]
                if a.dtype.names and name.endswith("summary"):
                    kept = [field for field in a.dtype.names if field not in VOLATILE_COLUMNS]
                    if set(a.dtype.names) != set(b.dtype.names):
                        found.append(f"{where}: columns {a.dtype.names} != {b.dtype.names}")
                        return
                    values_a, values_b = values_a[kept], values_b[kept]
                    if "run_id" in kept:  # rows in the order the runs finished: compared run by run
                        values_a, values_b = (np.sort(values, order="run_id") for values in (values_a, values_b))
                elif a.dtype.names:  # a lane chunk's table: its wall times left out
                    kept = [field for field in a.dtype.names if field not in VOLATILE_ATTRIBUTES]
                    if set(a.dtype.names) != set(b.dtype.names):
                        found.append(f"{where}: fields {a.dtype.names} != {b.dtype.names}")
                        return
                    values_a, values_b = values_a[kept], values_b[kept]
                if not _equal(values_a, values_b):
                    found.append(f"{where}: dataset differs ({a.dtype}{a.shape} vs {b.dtype}{b.shape})")
                return
            for key in sorted(a.keys() | b.keys()):
                if key not in a or key not in b:
                    found.append(f"{where}/{key}: only in {'new' if key in b else 'old'}")
                else:
                    compare(f"{name}/{key}", a[key], b[key])

        compare("", old, new)
    return found


def package_tree(source: Path, into: Path) -> Path:
    """A folder from which ``import simrun`` imports ``source``'s code uninstalled: simrun/ holds links to runner/'s
    entries and to systems/, integrators/ and solvers/ (pyproject.toml's package-dir)."""
    package = into / "simrun"
    package.mkdir(parents=True)
    for entry in (source / "runner").iterdir():
        (package / entry.name).symlink_to(entry)
    for library in ("systems", "integrators", "solvers"):
        (package / library).symlink_to(source / library)
    return into


def run_config(tree: Path, config: Path, output: Path, jobs: int) -> None:
    """One config by the code at ``tree``, in a process of its own: ``simrun.fit`` for a calibration, else
    ``simrun.run`` (figures left out: they read the file alone)."""
    entry = "fit" if any(line.startswith("fit:") for line in config.read_text().splitlines()) else "run"
    script = (f"import simrun; simrun.{entry}({str(config)!r}, output={str(output)!r}, jobs={jobs}, progress=False, "
              "figures=False)")
    done = subprocess.run([sys.executable, "-c", script], env={**_environment(), "PYTHONPATH": str(tree)},
                          cwd=output.parent, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{config.name} at {tree}: exit {done.returncode}\n{done.stderr[-4000:]}")


def _environment() -> dict:
    import os

    return {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}


def compare_revision(revision: str, configs: list[Path], jobs: int, keep: Path | None) -> int:
    folder = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="simrun-compare-"))
    folder.mkdir(parents=True, exist_ok=True)
    old_source = folder / "old-source"
    if not old_source.exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old_source), revision], check=True,
                       capture_output=True)
    status = 0
    try:
        trees = {}
        for side, source in (("old", old_source), ("new", ROOT)):
            tree = folder / f"{side}-package"
            if not tree.exists():
                package_tree(source, tree)
            trees[side] = tree
        for config in configs:
            outputs = {side: folder / f"{side}-results" / config.stem for side in trees}
            for side, tree in trees.items():
                outputs[side].parent.mkdir(exist_ok=True)
                # the old side runs the old revision's copy of the config, so that a config's own change shows
                source_config = (old_source if side == "old" else ROOT) / "configs" / config.name
                run_config(tree, source_config, outputs[side], jobs)
            found = differences(outputs["old"] / "results.h5", outputs["new"] / "results.h5",
                                aliases=[(str(old_source), str(ROOT))])
            print(f"{config.stem}: {'the same' if not found else f'{len(found)} differences'}")
            for line in found[:50]:
                print(f"  {line}")
            status = status or (1 if found else 0)
    finally:
        if keep is None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old_source)],
                           capture_output=True)
    return status


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    files = commands.add_parser("files", help="compare two results files")
    files.add_argument("old", type=Path)
    files.add_argument("new", type=Path)
    revision = commands.add_parser("revision", help="run configs at a git revision and in the working tree, compare")
    revision.add_argument("revision")
    revision.add_argument("configs", nargs="*", help="config stems or paths (default: FAST_CONFIGS)")
    revision.add_argument("--all", action="store_true", help="every config in configs/")
    revision.add_argument("--jobs", type=int, default=1)
    revision.add_argument("--keep", type=Path, help="a folder to keep the worktree and results in")
    args = parser.parse_args(argv)
    if args.command == "files":
        found = differences(args.old, args.new)
        for line in found:
            print(line)
        print("the same" if not found else f"{len(found)} differences")
        return 1 if found else 0
    if args.all:
        configs = sorted((ROOT / "configs").glob("*.yaml"))
    else:
        configs = [ROOT / "configs" / f"{Path(name).stem}.yaml" for name in (args.configs or FAST_CONFIGS)]
    return compare_revision(args.revision, configs, args.jobs, args.keep)


if __name__ == "__main__":
    sys.exit(main())
