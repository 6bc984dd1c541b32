"""`simrun measure TRAJECTORY... --config CONFIG`: trajectories computed by any code, measured on the config's system.

    simrun measure verlet.npz --config spring.yaml --name verlet            # one trajectory, its own results file
    simrun measure a.npz b.h5 --config cloth.yaml --name mine --name theirs # several, into one file
    simrun measure verlet.npz --config spring.yaml --with-runs              # beside the config's own runs

Each trajectory becomes a run whose integrator is ``recorded:<label>`` (integrators/recorded.py): simrun reads its
states, evaluates the config's system on them (runner/execution/recorded.py) and writes the results file, figures
and report where the config's ``output`` says (or ``--output``), as `simrun CONFIG` does; a second call with the same
files resumes. The trajectory file is documented in docs/results-format.md ("Trajectory files").
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from simrun.commands._options import add_executor_options, add_experiment_options, executor_name
from simrun.commands.run import EXIT_INTERRUPTED, print_written

LABEL = re.compile(r"^[A-Za-z0-9._+-]{1,60}$")


def add_parser(commands) -> None:
    measure = commands.add_parser(
        "measure", help="measure trajectories computed by any code on a config's system, as runs of their own",
        description="Read each TRAJECTORY (.npz or HDF5 with t (n,), x (n, dof_count) and optionally v), evaluate "
                    "CONFIG's system on its states, and write them as runs named recorded:<label> into the config's "
                    "results file, with its figures and report; without v, velocities are central differences of x, "
                    "and every run that uses them says so.")
    measure.add_argument("trajectories", nargs="+", metavar="TRAJECTORY",
                         help="a trajectory file: .npz or HDF5 (.h5, .hdf5) with t, x and optionally v")
    measure.add_argument("--config", required=True, help="the experiment's YAML file: the system the trajectories were "
                                                          "computed for, its duration and what to record")
    measure.add_argument("--name", dest="names", action="append", default=[], metavar="LABEL",
                         help="the label of a trajectory's code, once per trajectory in order (runs are named "
                              "recorded:LABEL; default: the file's name)")
    measure.add_argument("--with-runs", action="store_true",
                         help="run the config's own integrators too, into the same file (default: the trajectories alone)")
    add_experiment_options(measure, "--set duration=20")
    add_executor_options(measure, "runs")
    measure.add_argument("--force", action="store_true", help="start over even if the output folder holds other results")
    measure.add_argument("-q", "--quiet", action="store_true", help="print only errors and the final paths")
    measure.set_defaults(handler=handle)


def handle(args) -> int:
    import yaml

    from simrun.errors import ConfigError
    from simrun.experiment.config import apply_override, load_yaml
    from simrun.pipeline import Interrupted, run

    if args.names and len(args.names) != len(args.trajectories):
        raise ConfigError(f"--name: {len(args.names)} labels for {len(args.trajectories)} trajectories; give one "
                          "--name per trajectory, in order, or none")
    for label in args.names:
        if not LABEL.match(label):
            raise ConfigError(f"--name: {label!r} is not a label; allowed: 1-60 letters, digits and . _ + -")
    entries = []
    for number, text in enumerate(args.trajectories):
        path = Path(text).expanduser()
        if not path.is_file():
            raise ConfigError(f"TRAJECTORY: file {text!r} not found")
        entry = {"type": "recorded", "trajectory": str(path.resolve())}
        if args.names:
            entry["source"] = args.names[number]
        entries.append(entry)
    raw, _ = load_yaml(args.config)
    for assignment in args.overrides:
        apply_override(raw, assignment)
    own = list(raw.get("integrators") or []) if args.with_runs else []
    listed = yaml.safe_dump(entries + own, default_flow_style=True, width=float("inf")).strip()
    try:
        results = run(args.config, output=args.output, jobs=args.jobs, executor=executor_name(args),
                      scheduler=args.scheduler, force=args.force, progress=not args.quiet, figures=not args.no_plots,
                      svg=args.svg, overrides=[*args.overrides, f"integrators={listed}"],
                      command_line=getattr(args, "command_line", None))
    except Interrupted as interrupted:
        print(f"simrun: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print_written(results, figures=not args.no_plots)
    return 0
