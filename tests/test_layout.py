"""The package's layout: one folder per stage of the flow, imports that run one way, and no import cycles.

Data flows config -> runs -> simulate -> store -> results -> analysis -> figures / findings / report
(docs/architecture.md). Each stage folder of runner/ has a rank in that order; a module may import its own
stage and earlier ones, never a later one. Every import counts: at the top, inside a function, under
``TYPE_CHECKING``. The library packages (systems/, integrators/, solvers/) rank below every stage of the runner,
beside ``errors`` and ``version``. The parse reads the source tree, not the installed package, so a module that
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
    "errors": 0, "version": 0, "systems": 0, "integrators": 0, "solvers": 0,  # the library, and what all share
    "experiment": 1,  # the config's models and loading, the sweep expanded into runs
    "contracts": 1,  # the library's contracts as checks: they step a system with an integrator and a solver
    "format": 2,  # the results file's rows and names, which the stepping code, writer and readers share
    "execution": 3,  # simulate, lanes, executors, workers
    "results": 4,  # the file on disk: writer, reader, lane chunks, fits, older formats, the output lock
    "analysis": 5,  # amplification matrices, references, per-run derived data, the tables' rows
    "findings": 6,  # sentences with their numbers, one module per topic
    "figures": 7,
    "report": 8,  # the HTML page and the summary table as text
    "calibration": 9, "pipeline": 9,  # simrun.fit and simrun.run: the whole flow
    "commands": 10,  # one module per subcommand
    "cli": 11, "__main__": 11, "__init__": 11,  # the package face and the dispatch
}
MAX_ROOT_MODULES = 8


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
