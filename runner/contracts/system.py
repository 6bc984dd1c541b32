"""The contract of a system (systems/base.py, docs/systems.md) as checks that measure it.

Each check takes a built system and returns a ``Check``: its name, whether it passed (None where it does not
apply) and what it measured against which tolerance. tests/test_systems.py asserts every check for every
registered system (built-in and plug-in); ``simrun check-system`` prints them for a user's system. The short
run (``check_short_run``) steps the system with an integrator and a solver, which is why the checks live in the
runner and not in systems/.

Derivatives are compared at the generic state x = x0 + 0.05 L z (L = ``length_scale``, z ~ N(0, I), seeded),
where no symmetry of x0 hides a wrong sign or a missing term, by central differences with the step h = 1e-6 L:
their error is h^2/6 |P'''| (about 1e-12 relative) plus the round-off eps |P| / h (about 1e-10 relative), so a
relative error above 1e-6 is a wrong derivative, not a numerical one.

The state, the probe directions and the matrix measures are in runner/contracts/probes.py; this module stays
the import point of the checks and of the helpers that tests use (``generic_state``, ``held_dofs``, ``max_abs``).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from simrun.systems.base import ENERGY_ROUND_OFF, Capabilities, System, SystemParams
from simrun.systems.forms import VertexForm

from .probes import (asymmetry, dense, free_dofs, generic_state, generic_velocity, held_dofs, max_abs, negativity,
                     probes, relative_error, restricted)

FD_STEP = 1e-6  # of the length scale
# central differences err by h^2/6 |P'''| (1e-12 relative) plus round-off eps |P|/h (1e-10 relative):
# 1e-6 of the largest entry leaves room for stiff penalty terms next to soft springs
FD_TOLERANCE = 1e-6
# The Hessian against the energy alone (where it is not dg/dx: is the gradient or the Hessian wrong?): second central
# differences of P with a step of 1e-4 of the length scale err by about h^2/12 |P^(4)| / |P''| (3e-7 relative on the
# hardening chain of docs/systems.md) plus round-off eps |P| / (h^2 |P''|) (~1e-12): within 1e-5 they tell a right
# Hessian from one 0.1 % wrong by two orders.
SECOND_DIFFERENCE_STEP = 1e-4  # of the length scale
SECOND_DIFFERENCE_TOLERANCE = 1e-5
PSD_TOLERANCE = 1e-9  # eigenvalues >= -1e-9 max|eigenvalue|: round-off of a projected (or exactly singular) matrix
ROUND_OFF = 1e-12  # the same formulas on the same numbers, in another order
SOLVE_ROUND_OFF = 1e-10  # a sparse solve: round-off times the condition number of a (well-conditioned) mass matrix
# The short run: STEP_COUNT steps of each RUN_INTEGRATORS method at a tenth of the fastest rate's stable step.
STEP_COUNT = 20
RUN_INTEGRATORS = ("symplectic_euler", "backward_euler")
STABLE_FRACTION = 0.1  # dt = 0.1 / w_max
# |E - E0| <= 10 E_ref over the short run: a sound system moves its energy by at most about E_ref in 20 steps at a
# tenth of its stable step (all of E0 only when strongly damped); the runner's divergence bound is 1e6 E_ref.
RUN_ENERGY_TOLERANCE = 10.0  # of energy_scale()
# E_ref = energy_scale() below ENERGY_ROUND_OFF = 1e-8 of the work W0 = L sum_free |f(x0, v0)| that the initial
# forces do over the length scale (the floor System.energy_scale() itself applies) is the round-off of terms that
# cancel (|KE0| + |PE0| of a start whose energy is zero by construction), not an energy of the motion: every
# relative energy error, and the divergence bound, would be measured against noise. (A pendulum released 1e-3 rad
# from the bottom has E_ref / W0 = 5e-4.)


# The forms (systems/forms.py): a system's own vertex form is the generic one's numbers, summed another way (1e-9 of the
# largest block: each block sums the same terms in another order, and the generic one reads them off an assembled
# Hessian); its energy changes are P's own (1e-6 of the largest: the generic form differences P, whose round-off is
# eps |P| over changes of a 1e-3 L step)
VERTEX_BLOCK_TOLERANCE = 1e-9
VERTEX_CHANGE_TOLERANCE = 1e-6
VERTEX_STEP = 1e-3  # of the length scale


@dataclass(frozen=True)
class Check:
    """One clause of the contract, measured: passed is True, False, or None where it does not apply."""

    name: str
    passed: bool | None
    detail: str

    @property
    def status(self) -> str:
        return {True: "PASS", False: "FAIL", None: "SKIP"}[self.passed]

    def __str__(self) -> str:
        return f"{self.status}  {self.name:<18} {self.detail}"


def _verdict(name: str, measured: str, problems: list[str]) -> Check:
    """PASS with what was measured, or FAIL with every problem found."""
    return Check(name, True, measured) if not problems else Check(name, False, "; ".join(problems))


# -- the checks --------------------------------------------------------------------------------------------
def check_params(params: SystemParams) -> tuple[Check, System | None]:
    """The parameter model builds its ``system_class``: a System with params.dof_count dofs; the class and the
    instance agree on records_state_per_sample. Returns the check and the system (None if it was not built)."""
    model = type(params)
    problems = []
    system_class = getattr(model, "system_class", None)
    if not (isinstance(system_class, type) and issubclass(system_class, System)):
        return _verdict("params", "", [f"{model.__name__}.system_class is {system_class!r}, not a System subclass"]), None
    system = params.build()
    if type(system) is not system_class:
        problems.append(f"build() gave a {type(system).__name__}, not its system_class {system_class.__name__}")
    if params.dof_count != system.dof_count:
        problems.append(f"params.dof_count = {params.dof_count} but the system has dof_count = {system.dof_count}")
    if system_class.records_state_per_sample != system.records_state_per_sample:
        problems.append("records_state_per_sample differs between the class and the built system")
    return _verdict("params", f"type {params.type!r} builds {type(system).__name__} with {system.dof_count} dofs",
                    problems), system


def check_state(system: System) -> Check:
    """dof_count an integer >= 1, dim in (1, 2, 3) dividing it; mass > 0, x0, v0 finite, each of shape (dof_count,);
    fixed_dofs integer indices in range; v0 = 0 on them."""
    n = system.dof_count
    problems = []
    if not isinstance(n, numbers.Integral) or n < 1:
        return _verdict("state", "", [f"dof_count is {n!r}, not an integer >= 1"])
    dim = getattr(system, "dim", None)
    if dim not in (1, 2, 3) or n % dim:
        problems.append(f"dim is {dim!r}: give the spatial dimension (1, 2 or 3), a divisor of dof_count = {n}")
    for name in ("mass", "x0", "v0"):
        array = np.asarray(getattr(system, name, None))
        if array.shape != (n,):
            problems.append(f"{name} has the shape {array.shape}, not (dof_count,) = ({n},)")
        elif not np.all(np.isfinite(array)):
            problems.append(f"{name} is not finite")
    if np.shape(system.mass) == (n,) and not np.all(np.asarray(system.mass) > 0):
        problems.append("mass has entries <= 0")
    fixed = np.asarray(system.fixed_dofs)
    if fixed.ndim != 1 or (fixed.size and (fixed.dtype.kind not in "iu" or fixed.min() < 0 or fixed.max() >= n)):
        problems.append(f"fixed_dofs must be integer indices in 0..{n - 1}, got {fixed!r}")
    elif np.shape(system.v0) == (n,) and np.any(np.asarray(system.v0)[held_dofs(system)] != 0.0):
        problems.append("v0 is not 0 on the fixed dofs (those not on a prescribed path)")
    return _verdict("state", f"{n} dofs in {dim}-D, {fixed.size} fixed", problems)


def check_gradient(system: System) -> Check:
    """g(x) . e = (P(x + h e) - P(x - h e)) / (2 h) + O(h^2) along every probe e, h = 1e-6 L; relative error <= 1e-6."""
    x = generic_state(system)
    h = FD_STEP * system.length_scale
    directions = probes(system)
    gradient = np.asarray(system.gradient(x))
    if gradient.shape != (system.dof_count,):
        return _verdict("gradient", "", [f"gradient(x) has the shape {gradient.shape}, not ({system.dof_count},)"])
    expected = gradient @ directions
    differences = np.array([(system.potential_energy(x + h * e) - system.potential_energy(x - h * e)) / (2 * h)
                            for e in directions.T])
    error = relative_error(differences - expected, expected)
    measured = (f"relative FD error of dP/dx {error:.1e} <= {FD_TOLERANCE:g} (h = {h:.1e} m, "
                f"{directions.shape[1]} directions)")
    problems = [] if error <= FD_TOLERANCE else [f"gradient(x) is not dP/dx: relative FD error {error:.1e} > {FD_TOLERANCE:g}"]
    return _verdict("gradient", measured, problems)


def check_hessian(system: System) -> Check:
    """H(x) e = (g(x + h e) - g(x - h e)) / (2 h) + O(h^2) along every probe e (relative error <= 1e-6); H = H^T."""
    x = generic_state(system)
    h = FD_STEP * system.length_scale
    directions = probes(system)
    hessian = system.hessian(x)
    if hessian.shape != (system.dof_count, system.dof_count):
        return _verdict("hessian", "", [f"hessian(x) has the shape {hessian.shape}, not ({system.dof_count}, {system.dof_count})"])
    expected = np.asarray(hessian @ directions)
    differences = np.array([(system.gradient(x + h * e) - system.gradient(x - h * e)) / (2 * h) for e in directions.T]).T
    error = relative_error(differences - expected, expected)
    skew = asymmetry(hessian)
    kind = "sparse" if scipy.sparse.issparse(hessian) else "dense"
    problems = []
    measured = f"relative FD error of dg/dx {error:.1e} <= {FD_TOLERANCE:g}"
    if error > FD_TOLERANCE:
        # the gradient may be what is wrong: is H the second derivative of the energy itself?
        energy_error = second_difference_error(system, x, hessian, directions)
        if energy_error <= SECOND_DIFFERENCE_TOLERANCE:
            measured = (f"not dg/dx of this gradient (relative FD error {error:.1e}), but d2P/dx2 of the energy: "
                        f"relative error of its second differences {energy_error:.1e} <= {SECOND_DIFFERENCE_TOLERANCE:g}"
                        " (the gradient is what is wrong)")
        else:
            problems.append(f"hessian(x) is not dg/dx (relative FD error {error:.1e} > {FD_TOLERANCE:g}) nor d2P/dx2 "
                            f"(relative error of the energy's second differences {energy_error:.1e} > "
                            f"{SECOND_DIFFERENCE_TOLERANCE:g})")
    if skew > ROUND_OFF:
        problems.append(f"hessian(x) is not symmetric: max|H - H^T| = {skew:.1e} max|H|")
    return _verdict("hessian", f"{measured}, asymmetry {skew:.1e} <= {ROUND_OFF:g} ({kind})", problems)


def second_difference_error(system: System, x: np.ndarray, hessian, directions: np.ndarray) -> float:
    """The relative error of e_i^T H e_j against the energy's second central differences, for every probe e_i (i = j)
    and each pair of neighbouring probes (i, i + 1): what H is held to without the gradient."""
    h = SECOND_DIFFERENCE_STEP * system.length_scale
    energy = system.potential_energy
    count = directions.shape[1]
    pairs = [(i, i) for i in range(count)] + [(i, (i + 1) % count) for i in range(count) if count > 1]
    expected, differences = [], []
    for i, j in pairs:
        a, b = directions[:, i], directions[:, j]
        expected.append(float(a @ np.asarray(hessian @ b)))
        differences.append((energy(x + h * (a + b)) - energy(x + h * (a - b)) - energy(x - h * (a - b))
                            + energy(x - h * (a + b))) / (4.0 * h * h))
    return relative_error(np.array(differences) - np.array(expected), np.array(expected))


def check_projected_hessian(system: System) -> Check:
    """hessian(x, project_spd=True) is symmetric and PSD on the free dofs at x0 and at the test state. (Not
    required: that a PSD hessian(x) comes back unchanged. The lectures project per element, each spring's
    block, and a sum of blocks can be PSD while some of its blocks are not.)"""
    problems, worst = [], -math.inf
    free = free_dofs(system)
    for where, x in (("x0", system.x0), ("the test state", generic_state(system))):
        projected = system.hessian(x, project_spd=True)
        skew = asymmetry(projected)
        if skew > ROUND_OFF:
            problems.append(f"hessian(x, project_spd=True) at {where} is not symmetric ({skew:.1e})")
        negative, smallest = negativity(restricted(projected, free))
        worst = max(worst, negative)
        if negative > PSD_TOLERANCE:
            problems.append(f"hessian(x, project_spd=True) at {where} has the eigenvalue {smallest:.3g} on the free dofs")
    return _verdict("projected hessian", f"smallest eigenvalue on the free dofs {-worst:.1e} x max|eigenvalue| "
                                         f">= -{PSD_TOLERANCE:g}", problems)


def check_hessian_pattern(system: System) -> Check:
    """pattern_matrix(hessian_data(x, p)) = hessian(x, p) for p in (False, True); every nonzero of D(x) and every
    diagonal entry lies in hessian_pattern, and diagonal_positions point at the diagonal."""
    pattern = system.hessian_pattern
    if pattern is None:
        return Check("hessian pattern", None, "none declared (hessian_pattern is None): implicit methods add sparse matrices")
    n = system.dof_count
    x = generic_state(system)
    problems = []
    for project_spd in (False, True):
        data = system.hessian_data(x, project_spd)
        if data.shape != (pattern.nnz,):
            problems.append(f"hessian_data has {data.shape} values for a pattern of {pattern.nnz}")
            continue
        difference = system.pattern_matrix(data) - scipy.sparse.csr_matrix(system.hessian(x, project_spd))
        if max_abs(difference.data) > ROUND_OFF * max_abs(data):
            problems.append(f"pattern_matrix(hessian_data(x, {project_spd})) differs from hessian(x, {project_spd})")
    rows = np.repeat(np.arange(n), np.diff(pattern.indptr))
    positions = system.diagonal_positions
    if not (np.array_equal(rows[positions], np.arange(n)) and np.array_equal(pattern.indices[positions], np.arange(n))):
        problems.append("diagonal_positions do not point at the diagonal")
    in_pattern = scipy.sparse.csr_matrix((np.ones(pattern.nnz), pattern.indices, pattern.indptr), shape=pattern.shape)
    for matrix, what in ((system.hessian(x), "the Hessian"), (system.damping_matrix(x), "the damping matrix")):
        if matrix is None:
            continue
        nonzero = scipy.sparse.csr_matrix(matrix, copy=True)
        nonzero.data = (nonzero.data != 0).astype(float)
        if (nonzero - nonzero.multiply(in_pattern)).count_nonzero():
            problems.append(f"{what} has nonzeros outside hessian_pattern")
    return _verdict("hessian pattern", f"{pattern.nnz} entries hold the Hessian, the damping and the diagonal", problems)


def check_damping(system: System) -> Check:
    """D(x) = D^T >= 0 (damping only dissipates: v . f_d = -v^T D v <= 0) and damping_force(x, v) = -D(x) v."""
    x, v = generic_state(system), generic_velocity(system)
    damping = system.damping_matrix(x)
    if damping is None:
        if system.is_damped or system.damping_force(x, v) is not None:
            return _verdict("damping", "", ["damping_matrix(x) is None at the test state but not at x0"])
        return Check("damping", None, "undamped (damping_matrix is None)")
    problems = []
    if not system.is_damped:
        problems.append("damping_matrix(x0) is None but damping_matrix(x) is not")
    if damping.shape != (system.dof_count, system.dof_count):
        return _verdict("damping", "", [f"damping_matrix(x) has the shape {damping.shape}"])
    skew = asymmetry(damping)
    negative, smallest = negativity(damping)
    if skew > ROUND_OFF:
        problems.append(f"damping_matrix(x) is not symmetric ({skew:.1e})")
    if negative > PSD_TOLERANCE:
        problems.append(f"damping_matrix(x) has the eigenvalue {smallest:.3g}: it would add energy")
    expected = -np.asarray(damping @ v)
    error = relative_error(system.damping_force(x, v) - expected, expected)
    if error > ROUND_OFF:
        problems.append(f"damping_force(x, v) differs from -D(x) v by {error:.1e}")
    return _verdict("damping", f"asymmetry {skew:.1e}, smallest eigenvalue {-negative:.1e} x max|eigenvalue|", problems)


def check_force(system: System) -> Check:
    """f(x, v) = -g(x) - D(x) v on the free dofs, exactly 0 on the fixed ones; acceleration = f / m, kick = v + dt f / m."""
    x, v = generic_state(system), generic_velocity(system)
    damping = system.damping_matrix(x)
    expected = -system.gradient(x) - (np.asarray(damping @ v) if damping is not None else 0.0)
    expected[system.fixed_dofs] = 0.0
    if getattr(system, "sliding", None) is not None:  # oblique sliding filters: the force along the allowed directions
        system.sliding.apply(expected)
    force = system.force(x, v)
    problems = []
    error = relative_error(force - expected, expected)
    if error > ROUND_OFF:
        problems.append(f"force(x, v) differs from -g(x) - D(x) v by {error:.1e}")
    if np.any(force[system.fixed_dofs] != 0.0):
        problems.append("force(x, v) is not 0 on the fixed dofs")
    if system.mass_correction is None:
        acceleration = expected / system.mass
        if relative_error(system.acceleration(x, v) - acceleration, acceleration) > ROUND_OFF:
            problems.append("acceleration(x, v) is not force / mass")
    else:  # a consistent M: M a = f on the free dofs, by a solve (round-off times M's condition number, ~10)
        acceleration = system.acceleration(x, v)
        free = np.setdiff1d(np.arange(system.dof_count), system.fixed_dofs)
        if relative_error((system.mass_times(acceleration) - expected)[free], expected[free]) > SOLVE_ROUND_OFF:
            problems.append("acceleration(x, v) does not solve M a = force on the free dofs")
    dt = 1e-3
    kicked = v + dt * acceleration
    if relative_error(system.kick(x, v, dt) - kicked, kicked) > ROUND_OFF:
        problems.append("kick(x, v, dt) is not v + dt force / mass")
    return _verdict("force", f"-g - D v to {error:.1e}, 0 on {len(system.fixed_dofs)} fixed dofs", problems)


def check_observables(system: System) -> Check:
    """observables(x, v) has the keys and shapes of observable_layout at every state; KE = 1/2 v^T M v, P(x),
    E = KE + P = total_energy(x, v), p = sum_i m_i v_i; write_observables puts them into row[:observable_width]
    (flattened, in layout order), touches nothing after it, and returns the energy."""
    x, v = generic_state(system), generic_velocity(system)
    observed = system.observables(x, v)
    layout = [(key, np.shape(value)) for key, value in observed.items()]
    problems = []
    if layout != list(system.observable_layout):
        problems.append(f"the observables' keys or shapes change with the state: {layout} at the test state, "
                        f"{list(system.observable_layout)} at x0")
    kinetic, potential = 0.5 * float(system.mass_times(v) @ v), system.potential_energy(x)
    energy_scale = system.energy_scale()
    for key, expected in (("kinetic_energy", kinetic), ("potential_energy", potential),
                          ("energy", kinetic + potential)):
        value = observed.get(key)
        if value is None or abs(value - expected) > ROUND_OFF * max(abs(expected), energy_scale):
            problems.append(f"observables {key} is {value!r}, not {expected!r}")
    total = system.total_energy(x, v)
    if abs(total - (kinetic + potential)) > ROUND_OFF * max(abs(kinetic + potential), energy_scale):
        problems.append(f"total_energy(x, v) = {total!r} is not KE + P = {kinetic + potential!r}")
    dim = getattr(system, "dim", 1)
    momenta = system.mass_times(v).reshape(-1, dim)
    if "momentum" not in observed or np.shape(observed["momentum"]) != (dim,) or \
            max_abs(observed["momentum"] - momenta.sum(axis=0)) > ROUND_OFF * max_abs(momenta) * len(momenta):
        problems.append("observables momentum is not sum_i m_i v_i")
    values = np.concatenate([np.ravel(value) for value in observed.values()])
    if values.size != system.observable_width:
        problems.append(f"observable_width is {system.observable_width}, the observables hold {values.size} numbers")
    else:
        row = np.full(system.observable_width + 2, np.nan)
        energy = system.write_observables(x, v, row)
        if relative_error(row[:-2] - values, values) > ROUND_OFF or not np.isnan(row[-2:]).all():
            problems.append("write_observables(x, v, row) does not write the observables in layout order")
        if abs(energy - observed["energy"]) > ROUND_OFF * max(abs(observed["energy"]), energy_scale):
            problems.append("write_observables returns another energy than observables")
    names = ", ".join(key for key, _ in system.observable_layout)
    return _verdict("observables", f"{len(layout)} observables ({names}), E = KE + P", problems)


def check_capabilities(system: System) -> Check:
    """length_scale = max|x0| (1 when 0) > 0, 0 < energy_scale = energy_scale() < inf, dof_count, frame_shape None
    iff x and v are sampled (else vertex_dim prod(frame_shape) = dof_count); planar: one body of dim >= 2 with x0,
    v0 and the force at in-plane states in the x-y plane; as_attrs() has exactly the fields' names."""
    capabilities = system.capabilities
    problems = []
    if not isinstance(capabilities, Capabilities) or system.capabilities is not capabilities:
        problems.append("capabilities is not a Capabilities built once (a cached_property)")
    start = max_abs(system.x0)
    if not (capabilities.length_scale > 0 and math.isfinite(capabilities.length_scale)):
        problems.append(f"length_scale is {capabilities.length_scale!r}, not a finite length > 0")
    elif type(system).length_scale is System.length_scale and capabilities.length_scale != (start if start > 0 else 1.0):
        problems.append(f"length_scale is {capabilities.length_scale!r}, not max|x0| = {start!r}")
    if not (0 < capabilities.energy_scale < math.inf) or capabilities.energy_scale != system.energy_scale():
        problems.append(f"energy_scale is {capabilities.energy_scale!r}: it must be energy_scale(), finite and > 0")
    if capabilities.dof_count != system.dof_count:
        problems.append(f"capabilities.dof_count is {capabilities.dof_count}, the system has {system.dof_count}")
    frame_shape = capabilities.frame_shape
    if system.records_state_per_sample and frame_shape is not None:
        problems.append("frame_shape is given although x and v are recorded in every sample")
    if frame_shape is not None:
        vertex_dim = getattr(system, "vertex_dim", 3)
        if not all(isinstance(size, int) for size in frame_shape) or vertex_dim * math.prod(frame_shape) != system.dof_count:
            problems.append(f"frame_shape {frame_shape} x {vertex_dim} coordinates is not dof_count = {system.dof_count}")
    if capabilities.planar:
        if not (system.dim >= 2 and system.dof_count == system.dim):
            problems.append("planar, but not one body in 2-D or 3-D")
        elif system.x0[2:].any() or system.v0[2:].any():
            problems.append("planar, but x0 or v0 leaves the x-y plane")
        else:
            x, v = generic_state(system), generic_velocity(system)
            x[2:], v[2:] = 0.0, 0.0
            if system.force(x, v)[2:].any():
                problems.append("planar, but the force at an in-plane state leaves the x-y plane")
    if set(capabilities.as_attrs()) != Capabilities.attribute_names():
        problems.append("as_attrs() does not name exactly the fields of Capabilities")
    frequency = "none" if capabilities.test_frequency is None else f"{capabilities.test_frequency:.6g} rad/s"
    return _verdict("capabilities", f"length_scale {capabilities.length_scale:.3g} m, energy_scale "
                                    f"{capabilities.energy_scale:.3g} J, test_frequency {frequency}, frame_shape "
                                    f"{frame_shape}, planar {capabilities.planar}", problems)


def check_test_frequency(system: System) -> Check:
    """With a test frequency w the system is uncoupled copies of q'' + w^2 q = 0: undamped, H(x) = w^2 M at x0
    and the test state, and (where an exact solution is known) back at (x0, v0) after one period 2 pi / w."""
    w = system.capabilities.test_frequency
    if w is None:
        return Check("test frequency", None, "none declared (not the test equation q'' + w^2 q = 0)")
    problems = []
    if not w > 0 or system.is_damped:
        problems.append(f"test_frequency {w!r} needs w > 0 and no damping")
    for x in (system.x0, generic_state(system)):
        hessian = dense(system.hessian(x))
        if relative_error(hessian - w * w * np.diag(system.mass), hessian) > ROUND_OFF:
            problems.append("hessian(x) is not w^2 M")
            break
    exact = system.exact_solution(np.array([2 * math.pi / w])) if w > 0 else None
    if exact is not None:
        scale = max(system.length_scale, max_abs(system.v0) / w)
        if max_abs(exact[0][0] - system.x0) > 1e-12 * scale or max_abs(exact[1][0] - system.v0) > 1e-12 * scale * w:
            problems.append("exact_solution after one period 2 pi / w is not (x0, v0)")
    return _verdict("test frequency", f"w = {w:.6g} rad/s, H = w^2 M", problems)


def check_forms(system: System) -> Check:
    """The forms the system offers beyond the generic vertex form (systems/forms.py), against what they stand for:
    its own vertex form's blocks and energy changes against the generic form's (read off the gradient, the Hessian and
    P) at the test state, and its colours (every vertex once, no two of a colour joined by a Hessian entry); the
    projective form's K_r symmetric and PSD on the free dofs; a compliant form whose springs are the whole force
    (``other_forces`` False): their force and energy are the system's."""
    x, v = generic_state(system), generic_velocity(system)
    measured, problems = [], []
    if type(system).vertex_form is not System.vertex_form:
        measured.append(_vertex_form_problems(system, x, problems))
    form = system.projective_form()
    if form:
        stiffness = restricted(form.rest_stiffness(), free_dofs(system))
        negative, _ = negativity(stiffness)
        asymmetric = asymmetry(stiffness)
        measured.append(f"K_r symmetric to {asymmetric:.1e}, smallest eigenvalue {-negative:.1e} x max")
        if asymmetric > ROUND_OFF:
            problems.append(f"projective form: K_r is not symmetric ({asymmetric:.2g} of its largest entry)")
        if negative > PSD_TOLERANCE:
            problems.append(f"projective form: K_r has an eigenvalue {-negative:.2g} x max|eigenvalue| < -{PSD_TOLERANCE:g}")
    springs = system.compliant_form()
    if springs and not springs.other_forces:
        # at rest (v = 0) the springs' force is -dP/dx less the constant field's M g, which XPBD applies apart
        expected = -np.asarray(system.gradient(x), dtype=float)
        if system.external_acceleration is not None:
            expected = expected - system.mass * system.external_acceleration
        force_error = relative_error(springs.force(x, np.zeros_like(x)) - expected, expected)
        measured.append(f"the springs' force to {force_error:.1e}")
        if force_error > SOLVE_ROUND_OFF:
            problems.append(f"compliant form: the springs' force differs from -dP/dx by {force_error:.2g} "
                            f"(> {SOLVE_ROUND_OFF:g}), though other_forces is False")
    if not measured:
        return Check("forms", None, "none offered beyond the generic vertex form")
    return _verdict("forms", "; ".join(measured), problems)


def _vertex_form_problems(system: System, x: np.ndarray, problems: list[str]) -> str:
    d = system.dim
    own, generic = system.vertex_form(), VertexForm(system)
    vertices = np.arange(system.dof_count // d)
    gradient, hessian = own.blocks(x, vertices)
    expected_gradient, expected_hessian = generic.blocks(x, vertices)
    block_error = max(relative_error(gradient - expected_gradient, expected_gradient),
                      relative_error(hessian - expected_hessian, expected_hessian))
    if block_error > VERTEX_BLOCK_TOLERANCE:
        problems.append(f"vertex form: its blocks differ from the gradient's and the Hessian's by {block_error:.2g} "
                        f"(> {VERTEX_BLOCK_TOLERANCE:g})")
    colouring = own.colouring()
    counts = np.bincount(np.concatenate(colouring), minlength=vertices.size) if colouring else np.zeros(vertices.size)
    colour_of = np.empty(vertices.size, dtype=np.intp)
    for number, colour in enumerate(colouring):
        colour_of[colour] = number
    if np.any(counts != 1):
        problems.append(f"vertex form: its colours hold {int(np.sum(counts == 0))} vertices no time and "
                        f"{int(np.sum(counts > 1))} more than once")
    else:
        matrices = [system.hessian(x), system.damping_matrix(x)]
        coupled = scipy.sparse.coo_array(sum(abs(scipy.sparse.csr_array(matrix)) for matrix in matrices if matrix is not None))
        first, second = coupled.row // d, coupled.col // d
        shared = (first != second) & (colour_of[first] == colour_of[second]) & (coupled.data != 0.0)
        if shared.any():
            problems.append(f"vertex form: {int(shared.sum())} Hessian entries join two vertices of one colour")
    steps = VERTEX_STEP * system.length_scale * np.random.default_rng(3).standard_normal((colouring[0].size, d))
    changes = own.energy_changes(x, colouring[0], steps)
    expected_changes = generic.energy_changes(x, colouring[0], steps)
    change_error = relative_error(changes - expected_changes, expected_changes)
    if change_error > VERTEX_CHANGE_TOLERANCE:
        problems.append(f"vertex form: its energy changes differ from P's by {change_error:.2g} (> {VERTEX_CHANGE_TOLERANCE:g})")
    return f"vertex blocks to {block_error:.1e}, {len(colouring)} colours, energy changes to {change_error:.1e}"


def work_scale(system: System) -> float:
    """W0 = L sum_free |f(x0, v0)| (J): the work the initial forces do over the length scale."""
    force = system.force(system.x0, system.v0)
    return system.length_scale * float(np.sum(np.abs(force[free_dofs(system)])))


def check_energy_reference(system: System) -> Check:
    """energy_scale() (E_ref: drift, divergence and the energy figures are relative to it) is an energy of the
    motion: at least 1e-8 of W0 = L sum_free |f(x0, v0)|, not the round-off of cancelling terms."""
    reference, work = system.energy_scale(), work_scale(system)
    measured = f"E_ref = {reference:.3g} J, W0 = L sum|f(x0)| = {work:.3g} J"
    if reference >= ENERGY_ROUND_OFF * work:
        return _verdict("energy reference", f"{measured}, E_ref/W0 = {reference / work if work else math.inf:.2g} "
                                            f">= {ENERGY_ROUND_OFF:g}", [])
    return _verdict("energy reference", measured, [
        f"energy_scale() = {reference:.3g} J is round-off next to W0 = {work:.3g} J (|KE0| + |PE0| of terms that "
        f"cancel): every run would be 'diverged' at once; override energy_scale() with an energy of the motion, e.g. W0"])


def stable_dt(system: System) -> float:
    """0.1 / (the fastest rate of the system): w_max^2 <= max_i sum_j |H_ij| / m_i (Gershgorin on M^-1 H) and the
    damping rate max_i sum_j |D_ij| / m_i, both at x0 and at the test state (where contacts may touch)."""
    rate = 0.0
    for x in (system.x0, generic_state(system)):
        for matrix, power in ((system.hessian(x, project_spd=True), 0.5), (system.damping_matrix(x), 1.0)):
            if matrix is not None:
                row_sums = np.asarray(abs(scipy.sparse.csr_matrix(matrix)).sum(axis=1)).ravel()
                rate = max(rate, float((row_sums / system.mass).max()) ** power)
    return STABLE_FRACTION / rate if rate > 0 else 0.01


def check_short_run(system: System) -> Check:
    """20 steps of symplectic Euler and of backward Euler (Newton) at dt = 0.1 / w_max: the states stay finite,
    the fixed dofs do not move, every Newton solve converges, and |E - E0| <= E_ref (energy_scale()) at every step."""
    from simrun.integrators import INTEGRATORS, State  # here: the other checks need no integrator or solver
    from simrun.solvers import NewtonParams

    dt = stable_dt(system)
    reference = system.energy_scale()
    energy0 = system.total_energy(system.x0, system.v0)
    problems, worst = [], 0.0
    for name in RUN_INTEGRATORS:
        integrator, solver = INTEGRATORS[name].model_validate({}), NewtonParams().build()
        state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
        with np.errstate(all="ignore"):
            for step in range(1, STEP_COUNT + 1):
                state, stats = integrator.step(system, state, dt, solver)
                energy = system.total_energy(state.x, state.v)
                if not (np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v)) and math.isfinite(energy)):
                    problems.append(f"{name}: the state is not finite after step {step}")
                    break
                held = held_dofs(system)
                if np.any(state.x[held] != system.x0[held]):
                    problems.append(f"{name}: fixed dofs moved at step {step}")
                    break
                if not getattr(stats, "converged", True):
                    problems.append(f"{name}: Newton did not converge at step {step} (residual {stats.residual:.3g})")
                    break
                change = abs(energy - energy0) / reference
                worst = max(worst, change)
                if change > RUN_ENERGY_TOLERANCE:
                    problems.append(f"{name}: |E - E0| = {change:.3g} E_ref after step {step} (E_ref = {reference:.3g} J)")
                    break
    return _verdict("short run", f"{STEP_COUNT} steps of {' and '.join(RUN_INTEGRATORS)} at dt = {dt:.3g} s: "
                                 f"max |E - E0| = {worst:.2g} E_ref <= {RUN_ENERGY_TOLERANCE:g}", problems)


# name -> check of a built system, in the order they are reported
CHECKS: dict[str, Callable[[System], Check]] = {
    "state": check_state,
    "gradient": check_gradient,
    "hessian": check_hessian,
    "projected hessian": check_projected_hessian,
    "hessian pattern": check_hessian_pattern,
    "damping": check_damping,
    "force": check_force,
    "observables": check_observables,
    "capabilities": check_capabilities,
    "test frequency": check_test_frequency,
    "energy reference": check_energy_reference,
    "forms": check_forms,
    "short run": check_short_run,
}


def run_checks(params: SystemParams) -> list[Check]:
    """Every check of the contract on the system ``params`` builds; a check that raises is a FAIL naming the error."""
    try:
        check, system = check_params(params)
    except Exception as error:  # noqa: BLE001 - a user's system may raise anything
        return [Check("params", False, f"build() raised {type(error).__name__}: {error}")]
    results = [check]
    if system is None:
        return results
    for name, function in CHECKS.items():
        try:
            results.append(function(system))
        except Exception as error:  # noqa: BLE001
            results.append(Check(name, False, f"raised {type(error).__name__}: {_first_line(error)}"))
    return results


def _first_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return lines[0] if lines else ""
