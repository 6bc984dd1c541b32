"""The shipped contact configs do what their comments say: cloth_drop.yaml never lets the cloth pass through itself
or a collider, and penalty_vs_ipc.yaml shows the penalty's penetration against IPC's positive distances."""

from __future__ import annotations

from pathlib import Path

import ipctk
import numpy as np
import yaml

import simrun
from simrun.systems.contact.mesh_contact import MeshContact

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _config(name: str, **changes) -> dict:
    document = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    document.update(changes)
    return document


def test_cloth_drop_never_intersects_itself_or_a_collider(tmp_path):
    """cloth_drop.yaml with backward Euler at dt = 0.01 s (its first method and step, the whole 1.5 s): on every
    recorded frame ipctk finds no intersecting pair of the cloth's triangles (self-contact on), every step's smallest
    distance to the sphere, the box and the ground is positive, the cloth ends folded onto itself (pairs of its own
    triangles within dhat: self-contact did act) and above the ground."""
    config = _config("cloth_drop", integrators=["backward_euler"], sweep={"dt": [0.01]})
    results = simrun.run(config, output=tmp_path / "drop", figures=False, progress=False, jobs=1)
    (run,) = results.runs.values()
    assert run.attrs["status"] == "ok", run.attrs["message"]
    frames, triangles = run["frames"], run["model_triangles"]
    assert frames.shape[0] >= 30
    mesh = ipctk.CollisionMesh(frames[0], ipctk.edges(triangles), triangles)
    for number, positions in enumerate(frames):
        assert not ipctk.has_intersections(mesh, positions), f"frame {number} intersects itself"
    distances = run["contact_distance"]
    assert np.all(distances > 0.0), f"smallest distance {distances.min():.3g} m"
    dhat = config["system"]["contact"]["dhat"]
    assert run.attrs["min_contact_distance"] < dhat  # the cloth did land
    ground = config["system"]["contact"]["colliders"][2]["point"][2]
    assert frames[-1][:, 2].min() > ground
    folded = MeshContact(frames[0], triangles, None, (), self_contact=True, dhat=dhat)
    assert folded.active_count(frames[-1].ravel()) > 100


def test_penalty_penetrates_where_ipc_keeps_a_positive_distance(tmp_path):
    """penalty_vs_ipc.yaml to t = 0.4 s (the cloth reaches the sphere at ~0.25 s): every penalty run's smallest
    distance is negative, deeper the softer the penalty (m g / k per vertex at rest, more while landing), and
    every IPC run's is positive at every step, whatever its barrier stiffness."""
    results = simrun.run(_config("penalty_vs_ipc", duration=0.4), output=tmp_path / "pvi", figures=False,
                         progress=False, jobs=1)
    depth = {}
    for run in results.runs.values():
        assert run.attrs["status"] == "ok", run.attrs["message"]
        params = run.attrs["system_params"]
        contact = (params if isinstance(params, dict) else __import__("json").loads(params))["contact"]
        if contact["method"] == "ipc":
            assert np.all(run["contact_distance"] > 0.0)
        else:
            assert run.attrs["min_contact_distance"] < 0.0
            depth[contact["stiffness"]] = -run.attrs["min_contact_distance"]
    assert len(depth) == 3
    stiffness = {1000.0: 1.0e3, 100000.0: 1.0e5, "auto": 1.0e4}
    ordered = sorted(depth, key=lambda key: stiffness[key])
    assert [depth[key] for key in ordered] == sorted(depth.values(), reverse=True)


def test_a_cloths_obstacle_file_is_found_beside_its_config_and_hashed(tmp_path, monkeypatch):
    """A cloth's obstacle mesh named relative to its config is found beside the config from any working folder
    (as a mass_spring model file is), made absolute for the workers, and its sha256 is part of the config's inputs."""
    import meshio

    from simrun.experiment.config import load_experiment

    folder = tmp_path / "scene"
    folder.mkdir()
    floor = np.array([[-1.0, -1.0, -0.2], [2.0, -1.0, -0.2], [2.0, 2.0, -0.2], [-1.0, 2.0, -0.2]])
    meshio.write(folder / "floor.obj", meshio.Mesh(floor, [("triangle", np.array([[0, 1, 2], [0, 2, 3]]))]))
    (folder / "scene.yaml").write_text(yaml.safe_dump({
        "name": "scene", "integrators": ["backward_euler"], "sweep": {"dt": [0.01]},
        "system": {"type": "cloth", "resolution": [4, 4], "pinned": [],
                   "contact": {"method": "ipc", "colliders": [{"shape": "mesh", "file": "floor.obj"}]}}}))
    monkeypatch.chdir(tmp_path)
    experiment, _ = load_experiment(folder / "scene.yaml")
    (path,) = [collider.file for collider in experiment.system.contact.colliders]
    assert Path(path).is_absolute() and Path(path).name == "floor.obj"
    assert list(experiment.system.input_files()) == ["contact.colliders[0].file"]


def test_spot_drop_lands_on_an_unstructured_mesh_in_few_newton_iterations(tmp_path):
    """spot_drop.yaml with backward Euler through its landing (to t = 0.15 s, the shell on the ground from
    t = 0.03 s): every step converges, every step's distance to the ground is positive and the shell is within
    dhat of it, the ground's friction has begun to slow the slide, each factorisation took the symmetric path, and
    the landing costs few Newton iterations a step (about 8; the damping in the config is why: docs/performance.md)."""
    results = simrun.run(CONFIGS / "spot_drop.yaml", output=tmp_path / "spot", figures=False, progress=False,
                         jobs=1, overrides=["duration=0.15", "integrators=[backward_euler]"])
    (run,) = results.runs.values()
    assert run.attrs["status"] == "ok", run.attrs["message"]
    distances = run["contact_distance"]
    assert np.all(distances > 0.0) and distances.min() < 1e-3
    landed = np.flatnonzero(distances < 1e-3)
    assert landed[0] <= 4
    iterations = run["newton_iterations"][landed[0]:]
    assert iterations.mean() <= 15 and iterations.max() < 60, iterations
    momentum = run["momentum"]
    assert momentum[-1, 0] < 0.75 * momentum[0, 0]  # 1 kg thrown at 0.8 m/s: friction slows it
    assert run.attrs["factorisations_symmetric"] > 0
    assert run.attrs["factorisations_threshold"] == run.attrs["factorisations_colamd"] == 0


def test_the_penetration_figure_shows_the_penalty_inside_and_ipc_outside(tmp_path):
    """penalty_vs_ipc.yaml's point, drawn: the contact-distance figure has a penalty panel whose lines go below 0 and
    an IPC panel whose lines never do, its note naming exactly the penalty runs as penetrating; the y axis is in mm."""
    import warnings

    import matplotlib.pyplot as plt

    from simrun.figures import figure_data
    from simrun.figures.contact import contact_distance

    results = simrun.run(_config("penalty_vs_ipc", duration=0.4), output=tmp_path / "pvi", figures=False,
                         progress=False, jobs=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure = contact_distance(figure_data(results))
        figure.canvas.draw()
    try:
        panels = {ax.get_ylabel().split("\n")[0]: ax for ax in figure.axes if ax.get_lines()}
        penalty, ipc = panels["system.contact.method = penalty"], panels["system.contact.method = ipc"]
        lowest = {name: min(float(np.min(line.get_ydata())) for line in ax.get_lines()[:-1])
                  for name, ax in (("penalty", penalty), ("ipc", ipc))}
        assert lowest["penalty"] < 0.0 < lowest["ipc"]
        assert "(mm)" in penalty.get_ylabel() or "(mm)" in " ".join(text.get_text() for text in figure.texts)
        note = next(text.get_text() for text in figure.texts if text.get_text().startswith("penetrating"))
        assert note.count("system.contact.method = penalty") == 3 and "ipc" not in note
    finally:
        plt.close(figure)
