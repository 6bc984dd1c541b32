"""`mass_spring` configs: every bad input is one line naming the config path and the problem,
exit status 2, nothing written; and the config forms that must work (files beside the config, generators,
per-kind and per-region stiffness, mass rules, initial shapes) build the system they describe."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import simrun
import pytest

from simrun.cli import main
from simrun.experiment.config import load_experiment
from simrun.systems import MassSpringParams


def _npz(path: Path, **arrays) -> Path:
    base = {"vertices": np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), "springs": np.array([[0, 1], [1, 2], [2, 0]])}
    base.update(arrays)
    np.savez(path, **{key: value for key, value in base.items() if value is not None})
    return path


def _write_config(tmp_path: Path, system: str) -> Path:
    config = tmp_path / "config.yaml"
    config.write_text("name: bad\nsystem:\n" + textwrap.indent(system, "  ")
                      + f"integrators: [backward_euler]\nduration: 0.01\nsweep: {{dt: [0.005]}}\noutput: {tmp_path / 'never'}\n")
    return config


def _bad_inputs(tmp_path: Path) -> list[tuple[str, str]]:
    """(the system block, what the one line must say) for every bad input a user can write."""
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    (tmp_path / "garbage.ply").write_text("this is not a mesh\n")
    nan = _npz(tmp_path / "nan.npz", vertices=np.array([[0.0, 0.0], [np.nan, 0.0], [0.0, 1.0]]))
    zero = _npz(tmp_path / "zero.npz", vertices=np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0]]))
    outside = _npz(tmp_path / "outside.npz", springs=np.array([[0, 1], [1, 7]]))
    duplicate = _npz(tmp_path / "duplicate.npz", springs=np.array([[0, 1], [1, 2], [1, 0]]))
    short = _npz(tmp_path / "short.npz", masses=np.array([1.0, 2.0]))
    no_springs = _npz(tmp_path / "nosprings.npz", springs=None)
    square = "model: {square: {segments: 2}}\n"
    return [
        (f"type: mass_spring\nmodel: {tmp_path / 'missing.npz'}\n", "model: file"),
        (f"type: mass_spring\nmodel: {tmp_path / 'garbage.ply'}\n", "garbage.ply"),
        (f"type: mass_spring\nmodel: {tmp_path / 'points.obj'}\n", "has no triangles or quads"),
        (f"type: mass_spring\nmodel: {nan}\n", "non-finite"),
        (f"type: mass_spring\nmodel: {zero}\n", "rest length 0"),
        (f"type: mass_spring\nmodel: {outside}\n", "vertex indices must be in 0..2"),
        (f"type: mass_spring\nmodel: {duplicate}\n", "more than one spring"),
        (f"type: mass_spring\nmodel: {short}\nmass: file\n", "masses"),
        (f"type: mass_spring\nmodel: {no_springs}\n", "springs"),
        ("type: mass_spring\n" + square + "pinned: [9]\n", "system.pinned: vertex 9 does not exist; the model has vertices 0..8"),
        ("type: mass_spring\n" + square + "pinned: [-1]\n", "system.pinned: vertex -1 does not exist; the model has vertices 0..8"),

        ("type: mass_spring\n" + square + "initial: {rotate: {axis: [1, 0, 0], degrees: 10}}\n", "a 2-D model turns about z only"),
        ("type: mass_spring\n" + square + "initial: {spin: [1, 0, 0]}\n", "a 2-D model spins about z only"),
        ("type: mass_spring\n" + square + "pinned: [middle]\n", "pinned: the model has no vertex set 'middle'"),
        ("type: mass_spring\n" + square + "constraints: [{vertices: [12], normal: [0, 1]}]\n", "system.constraints[0].vertices: vertex 12 does not exist"),
        ("type: mass_spring\n" + square + "constraints: [{vertices: [1], normal: [0, 0]}]\n", "the normal [0.0, 0.0] is zero"),
        ("type: mass_spring\n" + square + "constraints: [{vertices: [1], direction: [0.0, 0.0]}]\n", "the direction [0.0, 0.0] is zero"),
        ("type: mass_spring\n" + square + "pinned: [1]\nprescribed: [{vertices: [1], velocity: [1, 0]}]\n",
         "prescribed[0]: vertex 1 is already constrained by pinned"),
        ("type: mass_spring\n" + square + "gravity: [0, 0, -9.81]\n", "gravity: 3 components given, but the model is 2-D"),
        ("type: mass_spring\n" + square + "stiffness: {stretch: 10}\n", "stiffness: no stiffness for the spring kinds shear"),
        ("type: mass_spring\n" + square + "stiffness: {strech: 10, shear: 1}\n", "no spring kind 'strech'"),
        ("type: mass_spring\n" + square + "stiffness: file\n", "stiffness: file, but the model file has no 'stiffness' array"),
        ("type: mass_spring\nmodel: {grd: {}}\n", "expected a file path or one of {grid: ...}"),
        ("type: mass_spring\n" + square + "mass: {total: 1, per_vertex: 2}\n", "give one of per_vertex, total, density"),
        ("type: mass_spring\nmodel: {rope: {count: 4, direction: [1, 0]}}\nmass: {density: 1}\n", "needs a model with triangles"),
        ("type: mass_spring\n" + square + "prescribed: [{vertices: [0], rotation: {center: [0, 0], axis: [1, 0, 0], rate: 10}}]\n",
         "a 2-D model turns about z only"),
        ("type: mass_spring\n" + square + "regions: [{box: [[5, 5], [6, 6]], stiffness: 3}]\n", "regions[0].box: no spring has both ends in"),
    ]


def test_every_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys):
    failures = []
    for number, (system, expected) in enumerate(_bad_inputs(tmp_path)):
        folder = tmp_path / f"case{number}"
        folder.mkdir()
        config = _write_config(folder, system)
        status = main([str(config)])
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        ok = (status == 2 and len(lines) == 1 and lines[0].startswith("simrun: error: system") and expected in lines[0]
              and "Traceback" not in captured.err and not (folder / "never").exists())
        if not ok:
            failures.append((system, expected, status, captured.err))
    assert not failures, "\n\n".join(f"{system!r}: wanted {expected!r}, got {status}: {err}" for system, expected, status, err in failures)


def test_a_model_file_is_found_from_the_current_folder_and_stored_absolute(tmp_path, monkeypatch):
    _npz(tmp_path / "triangle.npz")
    monkeypatch.chdir(tmp_path)
    params = MassSpringParams(model="triangle.npz", gravity=[0.0, 0.0])
    monkeypatch.chdir("/")  # a worker that starts elsewhere still finds the file
    system = params.build()
    assert system.dof_count == 6 and system.spring_count == 3
    assert params.model == "triangle.npz"  # the config keeps what the user wrote (its hash does not move with the folder)


def test_stiffness_per_kind_per_region_and_the_mass_rules():
    params = MassSpringParams(model={"grid": {"resolution": [5, 4], "size": [1.0, 0.6]}},
                              stiffness={"stretch": 100.0, "stretch_y": 150.0, "shear": 10.0, "bend": 1.0},
                              regions=[{"box": [[-0.01, -0.01, -1.0], [0.51, 0.61, 1.0]], "stiffness": {"stretch_x": 900.0}}],
                              mass={"density": 2.0})
    system = params.build()
    model = params.spring_model()
    kinds = np.array(model.kind_names)[model.kinds]
    rest = model.vertices
    in_region = np.all(rest[model.springs] [..., 0] <= 0.51, axis=1)
    expected = np.select([(kinds == "stretch_x") & in_region, kinds == "stretch_x", kinds == "stretch_y", kinds == "shear"],
                         [900.0, 100.0, 150.0, 10.0], default=1.0)
    np.testing.assert_array_equal(system.stiffness, expected)
    # density 2 kg/m^2 over a 1 m x 0.6 m sheet: 1.2 kg, the corners a sixth of a cell, inner vertices a full cell
    assert np.sum(system.vertex_masses) == pytest.approx(1.2, rel=1e-12)
    cell = 0.25 * 0.2
    assert system.vertex_masses[6] == pytest.approx(2.0 * cell, rel=1e-12)


def test_initial_shape_scale_rotate_translate_and_spin_about_the_centroid():
    params = MassSpringParams(model={"square": {"segments": 2, "size": 2.0}}, gravity=[0.0, 0.0],
                              initial={"scale": [1.5, 1.0], "rotate": 90.0, "translate": [1.0, 2.0], "spin": 3.0})
    system = params.build()
    rest = params.spring_model().vertices
    x0 = system.x0.reshape(-1, 2)
    stretched = rest * [1.5, 1.0]
    np.testing.assert_allclose(x0, np.stack([-stretched[:, 1], stretched[:, 0]], axis=1) + [1.0, 2.0], atol=1e-14)
    offset = x0 - x0.mean(axis=0)
    np.testing.assert_allclose(system.v0.reshape(-1, 2), 3.0 * np.stack([-offset[:, 1], offset[:, 0]], axis=1), atol=1e-14)


def test_the_shipped_configs_load(monkeypatch):
    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    for name in ("course_square", "rope", "mixed_stiffness", "curtain", "twist"):
        experiment, _ = load_experiment(str(root / "configs" / f"{name}.yaml"), [])
        system = experiment.system.build()
        assert system.dof_count > 0, name


def test_a_driven_damped_model_reports_and_its_reference_follows_the_paths(tmp_path, capsys):
    """End to end on a strip with a list of damping models and a turning end: the run, the report (its
    findings read the damping and the prescribed work from the data), and the DOP853 reference, whose
    prescribed vertices stay on their rotating path (they accelerate with it)."""
    from simrun.analysis.reference import reference_positions

    config = {"name": "driven", "output": str(tmp_path / "out"),
              "system": {"type": "mass_spring", "model": {"grid": {"resolution": [5, 2], "size": [0.4, 0.1]}},
                         "stiffness": {"stretch": 200.0, "shear": 20.0, "bend": 1.0}, "mass": {"total": 0.02},
                         "gravity": [0.0, 0.0, 0.0], "pinned": ["left"],
                         "damping": [{"model": "relative", "coefficient": 0.001}, {"model": "drag", "coefficient": 0.001}],
                         "prescribed": [{"vertices": ["right"], "rotation": {"center": [0.4, 0.05, 0.0], "axis": [1, 0, 0], "rate": 180.0}}]},
              "integrators": ["backward_euler", "implicit_midpoint"], "duration": 0.1, "sweep": {"dt": [0.01, 0.005]}}
    results = simrun.run(config, progress=False, jobs=1)
    assert set(results.summary["status"]) == {"ok"}
    assert main(["report", str(tmp_path / "out" / "results.h5")]) == 0
    page = (tmp_path / "out" / "report.html").read_text()
    assert "it includes the physical damping" in page and "it includes the work of the prescribed vertices" in page
    experiment, _ = load_experiment(config, [])
    system = experiment.system.build()
    constraints = system.constraints
    for t, x in reference_positions(system, [0.05, 0.1]).items():
        np.testing.assert_allclose(x[constraints.moving_dofs], constraints.path(t)[0], atol=1e-12)


def test_a_model_beside_the_config_is_found_and_a_changed_file_is_a_changed_experiment(tmp_path, monkeypatch):
    from simrun.experiment.sweep import config_hash

    folder = tmp_path / "experiment"
    folder.mkdir()
    _npz(folder / "triangle.npz")
    config = folder / "triangle.yaml"
    config.write_text("name: triangle\nsystem: {type: mass_spring, model: triangle.npz, gravity: [0, 0], pinned: [0]}\n"
                      "integrators: [backward_euler]\nduration: 0.01\nsweep: {dt: [0.005]}\n")
    monkeypatch.chdir(tmp_path)  # not the config's folder
    experiment, _ = load_experiment(str(config), [])
    assert experiment.system.build().dof_count == 6
    before = config_hash(experiment)
    assert config_hash(load_experiment(str(config), [])[0]) == before
    _npz(folder / "triangle.npz", vertices=np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]]))
    assert config_hash(load_experiment(str(config), [])[0]) != before
    results = simrun.run(str(config), output=tmp_path / "out", progress=False, jobs=1, figures=False)
    assert set(results.summary["status"]) == {"ok"}


def test_what_a_model_file_brings_is_used_unless_the_config_says_otherwise(tmp_path):
    """An npz with per-spring stiffness and per-vertex masses: used by default (stiffness: auto, mass: {}); a
    number in the config wins. A triangle mesh shares a total mass by area unless `by: equal`."""
    path = _npz(tmp_path / "triangle.npz", stiffness=np.array([7.0, 8.0, 9.0]), masses=np.array([1.0, 2.0, 3.0]))
    system = MassSpringParams(model=str(path), gravity=[0.0, 0.0]).build()
    np.testing.assert_array_equal(system.stiffness, [7.0, 8.0, 9.0])
    np.testing.assert_array_equal(system.vertex_masses, [1.0, 2.0, 3.0])
    system = MassSpringParams(model=str(path), gravity=[0.0, 0.0], stiffness=5.0, mass={"per_vertex": 0.5}).build()
    np.testing.assert_array_equal(system.stiffness, 5.0)
    np.testing.assert_array_equal(system.vertex_masses, 0.5)
    grid = {"grid": {"resolution": [3, 3], "size": [1.0, 1.0]}}
    by_area = MassSpringParams(model=grid, mass={"total": 1.0}).build().vertex_masses
    assert by_area.sum() == pytest.approx(1.0, rel=1e-12) and by_area[4] == pytest.approx(0.25, rel=1e-12)  # the centre: a quarter
    np.testing.assert_array_equal(MassSpringParams(model=grid, mass={"total": 1.0, "by": "equal"}).build().vertex_masses, 1.0 / 9.0)
    tiny = MassSpringParams(model={"square": {"segments": 2}}, constraints=[{"vertices": [1], "normal": [1.0e-320, 0.0]}]).build()
    assert 2 in tiny.fixed_dofs  # a normal of length 1e-320 still has a direction: x, removed exactly
    rope = MassSpringParams(model={"rope": {"count": 4, "direction": [1.0, 0.0]}}, mass={"total": 1.0}).build()
    np.testing.assert_array_equal(rope.vertex_masses, 0.25)  # no triangles: equal shares


def test_the_force_on_prescribed_vertices_from_their_springs_alone_is_the_full_force_there():
    """driven_force (only the springs that touch the prescribed vertices) = -dP/dx - D v on their dofs, with
    every damping model and contact; and their acceleration is the path's, omega x v for a rotation."""
    params = MassSpringParams(model={"grid": {"resolution": [5, 4], "size": [0.4, 0.3]}}, stiffness={"stretch": 90.0, "shear": 9.0, "bend": 1.0},
                              damping=[{"model": "spring", "coefficient": 0.3}, {"model": "relative", "coefficient": 0.1},
                                       {"model": "drag", "coefficient": 0.05}, {"model": "rayleigh", "alpha": 0.2, "beta": 0.01}],
                              contact={"ground": {"height": 0.01, "stiffness": 500.0}},
                              prescribed=[{"vertices": [0, 6], "velocity": [0.1, 0.0, 0.2]},
                                          {"vertices": [19], "rotation": {"center": [0.2, 0.15, 0.0], "axis": [0, 1, 1], "rate": 40.0}}])
    system = params.build()
    rng = np.random.default_rng(3)
    x = system.x0 + 0.01 * rng.standard_normal(system.dof_count)
    v = rng.standard_normal(system.dof_count)
    moving = system.constraints.moving_dofs
    full = -system.gradient(x) - system.damping_matrix(x) @ v
    np.testing.assert_allclose(system.driven_force(x, v), full[moving], rtol=0, atol=1e-12 * np.abs(full).max())
    acceleration = system.acceleration(x, v)
    motion = system.constraints.prescribed[1]
    omega = motion.rotation[1] * motion.rotation[2]
    np.testing.assert_allclose(acceleration.reshape(-1, 3)[19], np.cross(omega, v.reshape(-1, 3)[19]), rtol=1e-14)
    np.testing.assert_array_equal(acceleration.reshape(-1, 3)[[0, 6]], 0.0)


def test_the_readme_example_of_a_mass_spring_system_builds():
    """The `type: mass_spring` block of README.md is a config that loads and builds (it cannot drift)."""
    import yaml

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = next(part.split("```")[0] for part in readme.split("```yaml\n")[1:] if "type: mass_spring" in part.split("```")[0])
    system = yaml.safe_load(block)["system"]
    experiment, _ = load_experiment({"name": "readme", "system": system, "integrators": ["backward_euler"], "sweep": {"dt": [0.01]}}, [])
    assert experiment.system.build().dof_count == 3 * 16 * 12


def test_start_positions_from_a_file_of_vertices_and_empty_selections(tmp_path):
    """initial.file may hold the vertices alone; a constraint that selects nothing is refused, naming it."""
    moved = np.array([[0.0, 0.0], [1.1, 0.0], [0.0, 0.9]])
    np.savez(tmp_path / "start.npz", vertices=moved)
    model = _npz(tmp_path / "triangle.npz")
    system = MassSpringParams(model=str(model), gravity=[0.0, 0.0], initial={"file": str(tmp_path / "start.npz")}).build()
    np.testing.assert_array_equal(system.x0, moved.ravel())
    with pytest.raises(ValueError, match=r"constraints\[0\].vertices: selects no vertex"):
        MassSpringParams(model=str(model), constraints=[{"vertices": [], "normal": [0.0, 1.0]}])
