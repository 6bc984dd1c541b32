"""`simrun animate RESULTS [RUN_ID]`: an animated GIF of one run that keeps frames (any model with vertices, 2-D or
3-D: springs as lines, triangles shaded where the model has them), from the file alone."""

from __future__ import annotations

from pathlib import Path

from simrun.commands._options import load_results, writable_output, writing_file
from simrun.errors import ConfigError
from simrun.results.lock import FIGURES_NAME


def add_parser(commands) -> None:
    animate = commands.add_parser("animate", help="write an animated GIF of one run with frames",
                                  description="Write an animated GIF of one run's frames: a 2-D or 3-D model with its springs "
                                              "and triangles (from the results file alone).")
    animate.add_argument("results", help="a results file, e.g. results/cloth_hang/results.h5")
    animate.add_argument("run_id", nargs="?", help="the run to animate (default: the first run with frames); `simrun animate RESULTS --list` lists them")
    animate.add_argument("--output", help=f"GIF path (default: {FIGURES_NAME}/<run_id>.gif beside the results file)")
    animate.add_argument("--fps", type=int, default=20, help="frames per second (default 20)")
    animate.add_argument("--list", action="store_true", help="list the runs with frames that can be animated")
    animate.set_defaults(handler=handle)


def handle(args) -> int:
    from simrun.figures.frames import frame_runs, write_gif

    results = load_results(args.results)
    runs = frame_runs(results)
    if args.list:
        print("\n".join(runs) if runs else "no runs with frames in this file")
        return 0
    if not runs:
        raise ConfigError(f"results: {str(results.path)!r} holds no runs with frames to animate")
    run_id = args.run_id or runs[0]
    if run_id not in runs:
        raise ConfigError(f"run_id: {run_id!r} is not one of the runs with frames of this file; valid: " + ", ".join(runs))
    if args.fps < 1:
        raise ConfigError(f"--fps: must be >= 1, got {args.fps}")
    field = "--output" if args.output else "output"
    output = writable_output(Path(args.output) if args.output else results.path.parent / FIGURES_NAME / f"{run_id}.gif", field)
    with writing_file(output, field) as gif:
        write_gif(results, run_id, gif, fps=args.fps)
    print(f"animation: {output}")
    return 0
