"""`simrun check-integrator METHOD`: a method measured against its own declaration, for its author.

    simrun check-integrator mypackage.bathe:Bathe                  # a plug-in, at its default parameters
    simrun check-integrator bathe --set gamma=0.586                # an installed plug-in (entry point), one override
    simrun check-integrator simrun.integrators.euler:BackwardEuler # a built-in, through the plug-in path

One line per check (PASS, FAIL or SKIP, with what was measured against which tolerance), the integrator card written
as card.png and card.json into the output folder; exit status 0 when every check passes, 1 when one fails, 2 when the
method cannot be resolved or its parameters are invalid (nothing written).
"""

from __future__ import annotations

import re
from pathlib import Path

from simrun.commands._options import add_svg_option

DEFAULT_OUTPUT = Path("results") / "integrators"
CARD_NAME = "card"


def add_parser(commands) -> None:
    check = commands.add_parser(
        "check-integrator", help="measure an integrator (a plug-in) against what it declares: order, linearity, "
                                 "the integrator card, momentum, determinism",
        description="Resolve a method (package.module:ClassName, an installed plug-in's name, or a built-in), build it "
                    "with its defaults plus --set, and measure it: the observed order on the undamped spring and on "
                    "Kepler's orbit against its declared order, superposition on the linear test problem, the "
                    "integrator card (amplification matrix over h w = 1e-3 ... 1e3 at zeta = 0 and 0.1: spectral "
                    "radius, rho_inf, stability limit, artificial damping, period error; against the method's closed "
                    "form where it declares one), linear momentum of a free system, determinism, and refusals. "
                    "Exit status 0: all pass; 1: a check fails; 2: the method cannot be resolved or built.")
    check.add_argument("method", metavar="METHOD",
                       help="what a config's integrators: entry may name: package.module:ClassName, an installed "
                            "plug-in's name, or a built-in method")
    check.add_argument("--set", dest="overrides", action="append", default=[], metavar="FIELD=VALUE",
                       help="a parameter of the method, value in YAML (repeatable), e.g. --set gamma=0.586")
    check.add_argument("--output", help=f"folder for {CARD_NAME}.png and {CARD_NAME}.json "
                                        f"(default: {DEFAULT_OUTPUT}/<the method's name>)")
    add_svg_option(check)
    check.set_defaults(handler=handle)


def handle(args) -> int:
    import json

    from simrun.commands._options import field_overrides, say, writable_output, writing_folder
    from simrun.contracts.integrator import run_checks
    from simrun.errors import ConfigError
    from simrun.experiment.config import build_integrator
    from simrun.figures.integrator_card import save_card
    from simrun.integrators import plugins

    spec = field_overrides(args.overrides, "integrator", args.method, "METHOD", "gamma=0.586")["integrator"]
    try:
        integrator = build_integrator(spec)
    except ValueError as error:
        raise ConfigError(f"METHOD {args.method}: {error}") from None
    if type(integrator).whole_run:
        raise ConfigError(f"METHOD {args.method}: {integrator.name} is a whole-run peer (another code chooses its "
                          "steps); check-integrator measures methods that simrun steps")
    field = "--output" if args.output else "output"
    folder_name = re.sub(r"[^A-Za-z0-9_.-]+", "_", integrator.label).strip("_") or "method"
    output = writable_output(Path(args.output) if args.output else DEFAULT_OUTPUT / folder_name, field, kind="folder")
    say(f"checking {integrator.label} ({plugins.provenance(type(integrator))['integrator_class']}) ...")
    report = run_checks(integrator)
    if report.card is not None:
        with writing_folder(output, field) as folder:
            save_card(report.card, folder / CARD_NAME, svg=args.svg)
            record = {"method": integrator.label, "parameters": integrator.model_dump(mode="json"),
                      "declared": {"order": integrator.order_of_accuracy, "explicit": integrator.explicit,
                                   "linear": integrator.linear, "summary": integrator.summary},
                      **plugins.provenance(type(integrator)), **report.card.as_dict(),
                      "checks": [{"name": check.name, "status": check.status, "detail": check.detail}
                                 for check in report.checks]}
            (folder / f"{CARD_NAME}.json").write_text(json.dumps(record, indent=1) + "\n")
    failed = [check for check in report.checks if check.passed is False]
    print(f"{integrator.label}: {len(report.checks)} checks of the Integrator contract (docs/integrators.md)")
    for check in report.checks:
        print(check)
    if report.card is not None:
        print(f"the integrator card: {output / (CARD_NAME + '.png')}, {output / (CARD_NAME + '.json')}")
    print(f"{len(failed)} of {len(report.checks)} checks failed" if failed else
          f"all {sum(check.passed is True for check in report.checks)} checks that apply passed")
    return 1 if failed else 0
