"""The package's layout: one folder per stage of the flow, imports that run one way, and no import cycles.

Data flows config -> runs -> simulate -> store -> results -> analysis -> figures / findings / report
(docs/architecture.md). Each stage folder of runner/ has a rank in that order; a module may import its own
stage and earlier ones, never a later one. Every import counts: at the top, inside a function, under
``TYPE_CHECKING``. The library packages (systems/, integrators/, solvers/) rank below every stage of the runner,
beside ``errors`` and ``version``; inside the library, ``LIBRARY_RANKS`` and ``SYSTEMS_RANKS`` order the packages and
the parts of systems/ the same way. The parse reads the source tree, not the installed package, so a module that
could not even be imported is still checked.
"""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parents[1]
# folder -> the package it installs as (pyproject.toml's package-dir)
PACKAGES = {"runner": "simrun", "systems": "simrun.systems", "integrators": "simrun.integrators",
            "solvers": "simrun.solvers"}
# The rank of each stage (a subpackage of simrun, or a module at its root). Equal ranks may import each other
# (the no-cycle test still holds them apart); a lower rank never imports a higher one.
STAGE_RANKS = {
    "errors": 0, "version": 0, "plugins": 0, "systems": 0, "integrators": 0, "solvers": 0,  # the library, and what all share
    "experiment": 1,  # the config's models and loading, the sweep expanded into runs
    "format": 2,  # the results file's rows and names, which the stepping code, writer and readers share
    "execution": 3,  # simulate, lanes, executors, workers
    "results": 4,  # the file on disk: writer, reader, lane chunks, fits, older formats, the output lock
    "analysis": 5,  # amplification matrices, references, per-run derived data, the tables' rows
    "findings": 6,  # sentences with their numbers, one module per topic
    "contracts": 6,  # the plug-in points' contracts as checks: they step systems and methods, and probe amplification
    "figures": 7,
    "report": 8,  # the HTML page and the summary table as text
    "calibration": 9, "pipeline": 9,  # simrun.fit and simrun.run: the whole flow
    "commands": 10,  # one module per subcommand
    "cli": 11, "__main__": 11, "__init__": 11,  # the package face and the dispatch
}
MAX_ROOT_MODULES = 8
# The library's packages in the order they build on each other. A module imports its own part of the library and
# lower ranks only, so that two parts of one rank never import each other.
LIBRARY_RANKS = {
    "systems": 0,  # the mechanics: a system knows no solver and no integrator
    "solvers": 1,  # minimise (or zero) any problem that offers value, gradient and Hessian; never see dt
    "integrators": 2,  # a step: predictor, a solver's minimisation, the update
}
# The parts of systems/, by the same rule: a subpackage, the top-level modules, or the registry.
SYSTEMS_RANKS = {
    "modules": 0,  # the top-level modules: the System contract, patterns, constraints, compiled helpers, small systems
    "vertex": 1,  # what every system of vertices shares: model files, the grid, selectors, start state, constraints
    "contact": 2,  # contact of vertices with colliders and with themselves, for any system of vertices
    "mass_spring": 3, "fem": 3,  # the systems of vertices, each on its own: neither imports the other
    "registry": 4,  # SYSTEMS (simrun.systems), the cloth (a MassSpring), plugins (names resolved in SYSTEMS)
}
REGISTRY_MODULES = ("simrun.systems", "simrun.systems.cloth", "simrun.systems.plugins")


def package_modules(root: Path = REPOSITORY) -> dict[str, tuple[Path, bool]]:
    """Module name -> (file, is a package's __init__), for every module of the four folders."""
    modules = {}
    for folder, package in PACKAGES.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = list(path.relative_to(root / folder).with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            modules[".".join([package, *parts])] = (path, is_package)
    return modules


def import_graph(root: Path = REPOSITORY) -> dict[str, dict[str, int]]:
    """Module -> {module it imports: the line of the first such import}, every import statement included.

    ``from package import name`` is an import of the submodule when ``name`` is one, else of the package (its
    ``__init__``). The parent packages that Python imports before any module are not counted unless a module names
    them: then they are its imports like any other (``from simrun.findings import findings`` in a topic module).
    """
    modules = package_modules(root)

    def known(name: str) -> str:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name

    graph: dict[str, dict[str, int]] = {}
    for name, (path, is_package) in modules.items():
        package = name if is_package else name.rpartition(".")[0]
        imported: dict[str, int] = {}
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package
                    for _ in range(node.level - 1):
                        anchor = anchor.rpartition(".")[0]
                    base = f"{anchor}.{base}" if base else anchor
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
            else:
                continue
            for target in targets:
                target = known(target) if target.split(".")[0] == "simrun" else ""
                if target and target != name:
                    imported.setdefault(target, node.lineno)
        graph[name] = imported
    return graph


def stage_of(module: str) -> str:
    """The stage of ``simrun.<stage>...``; ``__init__`` for the package face itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def rank_violations(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every import of a later stage than the importer's own, as "importer:line imports module (stage rank)"."""
    found = []
    for importer, imported in sorted(graph.items()):
        own = STAGE_RANKS[stage_of(importer)]
        for target, line in sorted(imported.items()):
            rank = STAGE_RANKS[stage_of(target)]
            if rank > own:
                found.append(f"{importer}:{line} ({stage_of(importer)}, rank {own}) imports {target} "
                             f"({stage_of(target)}, rank {rank})")
    return found


def library_part(module: str, packages: set[str]) -> tuple[str, tuple[int, int]]:
    """(part, rank) of a module of the library: ``solvers``, ``integrators``, or ``systems/<part>`` (a subpackage of
    systems/, ``modules`` for its top-level modules, ``registry``); the rank orders by LIBRARY_RANKS first and then,
    inside systems/, by SYSTEMS_RANKS. ``packages``: the names of the packages (a top-level module is not one)."""
    package = stage_of(module)
    if package != "systems":
        return package, (LIBRARY_RANKS[package], 0)
    parts = module.split(".")
    if module in REGISTRY_MODULES:
        part = "registry"
    elif ".".join(parts[:3]) in packages:
        part = parts[2]
    else:
        part = "modules"
    return f"systems/{part}", (LIBRARY_RANKS["systems"], SYSTEMS_RANKS[part])


def library_violations(graph: dict[str, dict[str, int]], root: Path = REPOSITORY) -> list[str]:
    """Every import inside the library of a higher rank, or of another part of the same rank, as
    "file:line: importer (part, rank) imports module (part, rank)"."""
    modules = package_modules(root)
    packages = {name for name, (_, is_package) in modules.items() if is_package}
    found = []
    for importer, imported in sorted(graph.items()):
        if stage_of(importer) not in LIBRARY_RANKS:
            continue
        part, rank = library_part(importer, packages)
        for target, line in sorted(imported.items()):
            if stage_of(target) not in LIBRARY_RANKS:
                continue
            target_part, target_rank = library_part(target, packages)
            if target_rank > rank or (target_rank == rank and target_part != part):
                file = modules[importer][0].relative_to(root)
                found.append(f"{file}:{line}: {importer} ({part}, rank {rank}) imports {target} "
                             f"({target_part}, rank {target_rank})")
    return found


def import_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in graph.get(module, {}):
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == module:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(cycles)


def test_every_stage_has_a_rank():
    """A new folder or root module of runner/ must be given its place in the flow before anything can import it."""
    stages = {stage_of(module) for module in package_modules()}
    assert stages <= set(STAGE_RANKS), f"stages without a rank in STAGE_RANKS: {sorted(stages - set(STAGE_RANKS))}"


def test_imports_run_one_way():
    """No module imports a later stage than its own (lazy and TYPE_CHECKING imports included)."""
    violations = rank_violations(import_graph())
    assert not violations, "imports against the flow:\n" + "\n".join(violations)


def test_every_part_of_the_library_has_a_rank():
    """A new package of the library, or a new folder of systems/, must be given its rank before anything imports it."""
    modules = package_modules()
    packages = {name for name, (_, is_package) in modules.items() if is_package}
    unranked = set()
    for module in modules:
        if stage_of(module) in LIBRARY_RANKS:
            try:
                library_part(module, packages)
            except KeyError as error:
                unranked.add(str(error))
    assert not unranked, f"parts of the library without a rank in LIBRARY_RANKS or SYSTEMS_RANKS: {sorted(unranked)}"


def test_the_library_imports_run_by_rank():
    """systems < solvers < integrators, and inside systems/ the parts of SYSTEMS_RANKS: no module imports a higher
    rank or another part of its own rank (lazy and TYPE_CHECKING imports included)."""
    violations = library_violations(import_graph())
    assert not violations, "imports against the library's ranks:\n" + "\n".join(violations)


def test_no_import_cycles():
    """No import cycle anywhere in runner/, systems/, integrators/ or solvers/, within a stage or across."""
    cycles = import_cycles(import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(cycle) for cycle in cycles)


def test_the_runner_root_holds_only_the_package_face():
    """At most MAX_ROOT_MODULES modules at runner/'s root; every subfolder of runner/ is a stage (a package)."""
    root = REPOSITORY / "runner"
    modules = sorted(path.name for path in root.glob("*.py"))
    assert len(modules) <= MAX_ROOT_MODULES, modules
    folders = [path for path in root.iterdir() if path.is_dir() and path.name != "__pycache__"]
    assert folders and all((folder / "__init__.py").is_file() and folder.name in STAGE_RANKS for folder in folders)


# -- the checks can fail: each finds what is planted in a copy of the tree ----------------------------------
def _tree_with(tmp_path: Path, module: str, source: str) -> Path:
    """A copy of the four folders with ``source`` appended to ``module`` (a path under the repository)."""
    for folder in PACKAGES:
        for path in (REPOSITORY / folder).rglob("*.py"):
            target = tmp_path / path.relative_to(REPOSITORY)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(path.read_text())
    planted = tmp_path / module
    planted.write_text(planted.read_text() + "\n" + textwrap.dedent(source))
    return tmp_path


@pytest.mark.parametrize(("module", "source", "expected"), [
    ("runner/execution/lanes.py", "from simrun.results.writer import ResultsWriter\n",
     "simrun.execution.lanes:"),  # the stepping code on the writer
    ("runner/analysis/rows.py", "def f():\n    from simrun.figures import FigureData\n",
     "simrun.analysis.rows:"),  # the tables on the figures, lazily
    ("runner/format/summary.py", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from simrun.results import Results\n",
     "simrun.format.summary:"),  # under TYPE_CHECKING
    ("systems/base.py", "from simrun.experiment.config import Run\n", "simrun.systems.base:"),  # the library on the runner
])
def test_an_import_against_the_flow_is_found(tmp_path, module, source, expected):
    violations = rank_violations(import_graph(_tree_with(tmp_path, module, source)))
    assert len(violations) == 1 and violations[0].startswith(expected), violations


@pytest.mark.parametrize(("module", "source", "target"), [
    ("systems/fem/params.py", "from ..mass_spring import params\n",
     "simrun.systems.mass_spring.params"),  # one system of vertices on the other
    ("systems/patterns.py", "from simrun.integrators import INTEGRATORS\n", "simrun.integrators"),  # a system on a step
    ("systems/vertex/selectors.py", "def f():\n    from ..contact.params import ContactSpec\n",
     "simrun.systems.contact.params"),  # the shared vertex code on contact, lazily
    ("systems/contact/model.py",
     "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..fem.system import Fem\n",
     "simrun.systems.fem.system"),  # contact on a system of vertices, under TYPE_CHECKING
    ("solvers/newton.py", "from simrun.integrators.base import Integrator\n",
     "simrun.integrators.base"),  # a solver on a step
])
def test_an_import_against_the_library_ranks_is_found(tmp_path, module, source, target):
    """The one planted import is reported, with the file and the line it is on."""
    tree = _tree_with(tmp_path, module, source)
    planted = source.splitlines()[-1].strip()
    line = 1 + [text.strip() for text in (tree / module).read_text().splitlines()].index(planted)
    violations = library_violations(import_graph(tree), tree)
    assert len(violations) == 1, violations
    assert violations[0].startswith(f"{module}:{line}: ") and f" imports {target} (" in violations[0], violations


@pytest.mark.parametrize(("module", "source", "expected"), [
    ("runner/findings/base.py", "def f():\n    from simrun.findings import findings\n",
     ["simrun.findings", "simrun.findings.base"]),  # a topic's base back on the package that assembles the topics
    ("systems/contact/friction.py", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .model import ContactModel\n",
     ["simrun.systems.contact.friction", "simrun.systems.contact.model"]),  # the cycle this layout broke
])
def test_an_import_cycle_is_found(tmp_path, module, source, expected):
    cycles = import_cycles(import_graph(_tree_with(tmp_path, module, source)))
    assert len(cycles) == 1 and set(expected) <= set(cycles[0]), cycles


def test_relative_and_package_imports_resolve(tmp_path):
    """``from . import x``, ``from .x import y`` and ``from simrun import x`` name the modules they load."""
    graph = import_graph()
    assert "simrun.solvers.base" in graph["simrun.solvers.newton"]  # from .base import ...
    assert "simrun.analysis.oscillator" in graph["simrun.findings.integrators"]  # from simrun.analysis import oscillator
    assert "simrun.figures._layout" in graph["simrun.figures.energy"]  # from simrun.figures import _layout as layout


def test_pyproject_installs_every_package():
    """``pip install .`` (not editable) installs only the packages pyproject.toml lists: every folder with an
    __init__.py is one of them, mapped to its folder."""
    import tomllib

    setuptools = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = {name for name, (_, is_package) in package_modules().items() if is_package}
    assert set(setuptools["packages"]) == packages
    for name, folder in setuptools["package-dir"].items():
        assert (REPOSITORY / folder / "__init__.py").is_file() and name in packages
