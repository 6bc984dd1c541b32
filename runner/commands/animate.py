"""`simrun animate RESULTS [RUN_ID]`: an animated GIF of one run that keeps frames (the cloth), from the file alone."""

from __future__ import annotations

from pathlib import Path

from simrun.commands._options import load_results
from simrun.errors import ConfigError


def add_parser(commands) -> None:
    animate = commands.add_parser("animate", help="write an animated GIF of one cloth run",
                                  description="Write an animated GIF of one cloth run's frames (from the results file alone).")
    animate.add_argument("results", help="a results file, e.g. results/cloth_hang/results.h5")
    animate.add_argument("run_id", nargs="?", help="the run to animate (default: the first cloth run); `simrun animate RESULTS --list` lists them")
    animate.add_argument("--output", help="GIF path (default: figures/<run_id>.gif beside the results file)")
    animate.add_argument("--fps", type=int, default=20, help="frames per second (default 20)")
    animate.add_argument("--list", action="store_true", help="list the cloth runs that can be animated")
    animate.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.figures.frames import frame_runs, write_gif

    results = load_results(args.results)
    runs = frame_runs(results)
    if args.list:
        print("\n".join(runs) if runs else "no cloth runs with frames in this file")
        return 0
    if not runs:
        raise ConfigError(f"results: {str(results.path)!r} holds no cloth run with frames to animate")
    run_id = args.run_id or runs[0]
    if run_id not in runs:
        raise ConfigError(f"run_id: {run_id!r} is not a cloth run of this file; valid: " + ", ".join(runs))
    if args.fps < 1:
        raise ConfigError(f"--fps: must be >= 1, got {args.fps}")
    output = Path(args.output) if args.output else results.path.parent / "figures" / f"{run_id}.gif"
    print(f"animation: {write_gif(results, run_id, output, fps=args.fps)}")
    return 0
