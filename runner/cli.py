"""The `simrun` command: thin argument handling around the pipeline.

config -> validated experiment -> runs -> simulate -> HDF5 -> figures
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

# Light imports only: `main` starts the pool's fork server before the simulation's own imports
# (numpy, scipy, pydantic, h5py: ~0.5 s), so that the two run side by side.
from simrun import __version__
from simrun.errors import ConfigError
from simrun.lock import OutputLock, OutputLocked
from simrun.workers import EXECUTORS, default_jobs, may_use_local_pool, start_worker_server

SUBCOMMANDS = ("run", "plot", "animate", "list", "report", "show", "analyze")
EXIT_CONFIG_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report Ctrl-C
DEFAULT_MAX_SIZE_GB = 50.0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simrun",
        description="Batch experiments with the time integrators of physics-based animation. "
                    "`simrun CONFIG.yaml` is short for `simrun run CONFIG.yaml`.",
    )
    parser.add_argument("--version", action="version", version=f"simrun {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = commands.add_parser("run", help="run an experiment: every run of its sweep, then its figures",
                              description="Run every run of CONFIG's sweep, write OUTPUT/results.h5 and draw OUTPUT/figures/.")
    run.add_argument("config", help="the experiment's YAML file, e.g. configs/quickstart.yaml")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override a config key, value in YAML (repeatable), e.g. --set system.stiffness=1000 --set sweep.dt=[0.01,0.02]")
    run.add_argument("--output", help="output folder (default: the config's `output`, else results/<name>)")
    run.add_argument("--no-plots", action="store_true", help="write the results file only")
    run.add_argument("-j", "--jobs", type=int, help="runs at once: local processes or Dask workers (default: the number of cores; 1 = serial)")
    run.add_argument("--executor", choices=EXECUTORS, default="local",
                     help="local: a process pool on this machine (default); dask: a Dask cluster (pip install 'simrun[dask]')")
    run.add_argument("--scheduler", metavar="ADDRESS", help="with --executor dask: an existing scheduler, e.g. tcp://host:8786 (default: a local cluster)")
    run.add_argument("--force", action="store_true", help="start over even if OUTPUT/results.h5 holds other results (default: resume an unchanged config)")
    run.add_argument("--max-size", type=float, default=DEFAULT_MAX_SIZE_GB, metavar="GB",
                     help=f"refuse a sweep whose results would exceed this size (default {DEFAULT_MAX_SIZE_GB:g} GB)")
    run.add_argument("-q", "--quiet", action="store_true", help="print only errors and the final paths")

    plot = commands.add_parser("plot", help="redraw the figures from a results file alone",
                               description="Draw every figure that RESULTS supports into its folder's figures/ (PNG and SVG).")
    plot.add_argument("results", help="a results file, e.g. results/quickstart/results.h5")
    plot.add_argument("--output", help="figure folder (default: figures/ beside the results file)")

    from simrun.report import add_analyze_parser, add_reference_option, add_report_parser, add_show_parser

    add_reference_option(plot)  # simrun plot RESULTS --reference [dop853|...|none|RUN_ID]
    add_report_parser(commands)
    add_show_parser(commands)
    add_analyze_parser(commands)

    animate = commands.add_parser("animate", help="write an animated GIF of one cloth run",
                                  description="Write an animated GIF of one cloth run's frames (from the results file alone).")
    animate.add_argument("results", help="a results file, e.g. results/cloth_hang/results.h5")
    animate.add_argument("run_id", nargs="?", help="the run to animate (default: the first cloth run); `simrun animate RESULTS --list` lists them")
    animate.add_argument("--output", help="GIF path (default: figures/<run_id>.gif beside the results file)")
    animate.add_argument("--fps", type=int, default=20, help="frames per second (default 20)")
    animate.add_argument("--list", action="store_true", help="list the cloth runs that can be animated")

    commands.add_parser("list", help="print the systems, integrators and solvers with their parameters",
                        description="Print every system, integrator and solver that a config may name, with parameters and defaults.")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in SUBCOMMANDS and not argv[0].startswith("-"):
        argv.insert(0, "run")  # `simrun CONFIG.yaml`
    if argv and argv[0] == "run" and may_use_local_pool(argv):
        start_worker_server()
    args = build_parser().parse_args(argv)
    if args.command is None:
        build_parser().print_help()
        return 0
    try:
        if args.command == "run":
            return command_run(args)
        if args.command == "plot":
            return command_plot(args)
        if args.command == "animate":
            return command_animate(args)
        if hasattr(args, "handler"):
            return args.handler(args)
        return command_list()
    except (ConfigError, OutputLocked) as error:
        print(f"simrun: error: {error}", file=sys.stderr)
        return EXIT_CONFIG_ERROR


def command_run(args) -> int:
    from simrun.config import config_hash, expand_runs, load_experiment
    from simrun.executors import execute
    from simrun.store import RESULTS_NAME

    jobs = args.jobs if args.jobs is not None else default_jobs()
    if jobs < 1:
        raise ConfigError(f"--jobs: must be >= 1, got {jobs}")
    experiment, config_text = load_experiment(args.config, args.overrides)
    runs = expand_runs(experiment)
    output = Path(args.output) if args.output else experiment.output_dir
    _check_writable(output)
    _check_size(runs, output, jobs, args.max_size)
    quiet = args.quiet
    say = (lambda *_: None) if quiet else (lambda text: print(text, flush=True))

    output.mkdir(parents=True, exist_ok=True)
    results_path = output / RESULTS_NAME
    digest = config_hash(experiment)
    with OutputLock(output):
        writer = _open_writer(results_path, config_text, digest, experiment.name, args.force)
        with writer:
            done = writer.completed_runs()
            pending = [run for run in runs if run.run_id not in done]
            where = f"{args.executor}, {jobs} job{'s' if jobs > 1 else ''}" if len(pending) > 1 else "serial"
            say(f"simrun {__version__}: {experiment.name}: {len(runs)} runs -> {output} ({where})")
            if done:
                say(f"resuming: skipped {len(runs) - len(pending)} runs already in {results_path}; running {len(pending)}")
            counts: dict[str, int] = {}
            progress = _progress(len(pending), quiet)
            try:
                for number, (run, result) in enumerate(execute(pending, args.executor, jobs, args.scheduler), 1):
                    writer.write_run(run, result)
                    counts[result.status] = counts.get(result.status, 0) + 1
                    detail = f" ({result.message})" if result.status != "ok" and result.message else ""
                    line = f"[{number}/{len(pending)}] {run.run_id}: {result.status}, {result.steps} steps in {result.wall_time:.3g} s{detail}"
                    if progress is None:
                        say(line)
                    else:
                        progress.set_postfix_str(run.run_id, refresh=False)
                        progress.update()
            except KeyboardInterrupt:
                if progress is not None:
                    progress.close()
                kept = len(writer.completed_runs())
                print(f"simrun: interrupted: {kept} of {len(runs)} runs are in {results_path}; "
                      "run the same command again to finish the rest", file=sys.stderr)
                return EXIT_INTERRUPTED
            if progress is not None:
                progress.close()
    summary = ", ".join(f"{n} {s}" for s, n in sorted(counts.items())) or "nothing left to run"
    print(f"results: {results_path}  ({summary})")
    if not args.no_plots:
        from simrun.plots import draw_figures

        figures = draw_figures(results_path, output / "figures")
        print(f"figures: {output / 'figures'}  ({len(figures)} files)")
    return 0


def _open_writer(path: Path, config_text: str, digest: str, name: str, force: bool):
    """A new results file, or the existing one when it holds the same config (resume)."""
    from simrun.store import ResultsFileError, ResultsWriter, stored_config_hash

    if path.exists() and not force:
        try:
            existing = stored_config_hash(path)
        except ResultsFileError as error:
            raise ConfigError(f"output: {str(path)!r} {error}") from None
        if existing != digest:
            raise ConfigError(f"output: {str(path)!r} holds the results of a different config; "
                              "start over with --force, or choose another --output")
        return ResultsWriter.resume(path)
    return ResultsWriter.create(path, config_text, digest, name)


def _progress(total: int, quiet: bool):
    """A progress bar on a terminal; None (plain log lines) when quiet or when stderr is not a terminal."""
    if quiet or total == 0 or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="run", dynamic_ncols=True, file=sys.stderr)


def _check_size(runs, output: Path, jobs: int, max_size_gb: float) -> None:
    """Refuse a sweep whose results would not fit on the disk, under the limit, or in memory."""
    from simrun.store import estimate_run_bytes

    sizes = [estimate_run_bytes(run) for run in runs]
    total = sum(sizes)
    existing = output
    while not existing.exists():
        existing = existing.parent
    free = shutil.disk_usage(existing).free
    limit = min(max_size_gb * 1e9, free)
    if total > limit:
        reason = f"the --max-size limit of {max_size_gb:g} GB" if max_size_gb * 1e9 <= free else f"the {free / 1e9:.3g} GB free"
        raise ConfigError(f"sweep: the results would take about {total / 1e9:.3g} GB, more than {reason}; "
                          "record fewer samples (record.max_samples, record.max_frames) or shorten the sweep")
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    in_flight = sum(sorted(sizes)[-jobs:])
    if in_flight > 0.8 * memory:
        raise ConfigError(f"sweep: {jobs} runs at once would hold about {in_flight / 1e9:.3g} GB in memory, "
                          f"more than 80 % of the {memory / 1e9:.3g} GB here; use fewer --jobs or record fewer samples")


def command_plot(args) -> int:
    path = Path(args.results)
    import h5py

    if not path.is_file() or not h5py.is_hdf5(path):
        raise ConfigError(f"results: {str(path)!r} is not a results file (expected e.g. results/quickstart/results.h5)")
    from simrun.plots import draw_figures
    from simrun.report import plot_reference_errors

    out = Path(args.output) if args.output else path.parent / "figures"
    errors = plot_reference_errors(path, args.reference, say=lambda text: print(text, file=sys.stderr))
    figures = draw_figures(path, out, reference_errors=errors)
    print(f"figures: {out}  ({len(figures)} files)")
    return 0


def command_animate(args) -> int:
    import h5py

    from simrun.cloth_figures import cloth_runs, write_gif
    path = Path(args.results)
    if not path.is_file() or not h5py.is_hdf5(path):
        raise ConfigError(f"results: {str(path)!r} is not a results file (expected e.g. results/cloth_hang/results.h5)")
    with h5py.File(path, "r") as file:
        runs = cloth_runs(file)
    if args.list:
        print("\n".join(runs) if runs else "no cloth runs with frames in this file")
        return 0
    if not runs:
        raise ConfigError(f"results: {str(path)!r} holds no cloth run with frames to animate")
    run_id = args.run_id or runs[0]
    if run_id not in runs:
        raise ConfigError(f"run_id: {run_id!r} is not a cloth run of this file; valid: " + ", ".join(runs))
    if args.fps < 1:
        raise ConfigError(f"--fps: must be >= 1, got {args.fps}")
    output = Path(args.output) if args.output else path.parent / "figures" / f"{run_id}.gif"
    print(f"animation: {write_gif(path, run_id, output, fps=args.fps)}")
    return 0


def command_list() -> int:
    from simrun.integrators import INTEGRATORS
    from simrun.solvers import LINEAR_SOLVERS, SOLVERS, SolverParams
    from simrun.systems import SYSTEMS

    def fields(model) -> list[str]:
        lines = []
        for key, info in model.model_fields.items():
            if key == "type":
                continue
            default = "" if info.is_required() else f" = {info.default!r}"
            note = f"  # {info.description}" if info.description else ""
            lines.append(f"      {key}{default}{note}")
        return lines

    print("systems (system.type):")
    for name, model in SYSTEMS.items():
        print(f"  {name}: {(model.__doc__ or '').strip().splitlines()[0]}")
        print("\n".join(fields(model)))
    print("\nintegrators (integrators: [name] or [{type: name, param: value}]):")
    for name, cls in INTEGRATORS.items():
        kind = "explicit" if cls.explicit else "implicit"
        print(f"  {name}  (order {cls.order}, {kind}): {cls.summary}")
        print("\n".join(fields(cls)))
    linear = [name if cls.missing() is None else f"{name} (not installed: make install-cholmod)"
              for name, cls in LINEAR_SOLVERS.items()]
    print("\nsolvers (solver.type): " + ", ".join(SOLVERS) + "; linear solvers (solver.linear_solver): " + ", ".join(linear))
    print("\n".join(fields(SolverParams)))
    return 0


def _check_writable(output: Path) -> None:
    """Refuse an output folder we cannot write before any run starts (and before creating anything)."""
    existing = output
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ConfigError(f"output: {str(existing)!r} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError:
        raise ConfigError(f"output: cannot write in {str(existing)!r}; choose another --output") from None


if __name__ == "__main__":
    sys.exit(main())
