"""What theory predicts for an integrator, and what a run measured: the numbers behind the analysis figures.

Predicted (from the integrators alone, no runs): on the undamped test spring q'' + w^2 q = 0 every
method's step is a linear map of its state (x_n, v_n, carried quantities), so its amplification
matrix A(h w) is found by stepping the unit vectors through the method itself; two-step methods
give their companion matrix (the state after one step holds the history). No method-specific
formula is used. From A:

- the spectral radius rho(h w), and the stability limit: the smallest h w at which rho exceeds 1;
- the artificial damping d_method = -2 ln(rho) / h (the energy decays like exp(-d_method t)),
  shown as d_method / w = -2 ln(rho) / (h w);
- the relative period error T_method / T - 1 = h w / phi - 1, phi = arg of the principal eigenvalue
  (the one that approximates e^{i h w}); defined for h w < pi (beyond, a step spans more than half
  a period and the phase cannot be told from the samples).

Measured (from recorded series, as arrays): the damping from a run's energy decay, the period from
its zero crossings, the observed order from errors against dt. Reference solutions for systems
without an exact one are in ``simrun.analysis.reference``.

Throughout, hw is the dimensionless step h w (time step times the test frequency). This module never
reads the results file and never imports the config, simulation or store modules: figures and
reports call it with what they read through ``simrun.results``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from simrun.integrators import INTEGRATORS, Integrator, State, plugins
from simrun.solvers import solver_params
from simrun.systems import SpringMassParams
from simrun.systems.base import System
from simrun.systems.compliant import ANCHORED, CompliantSprings
from simrun.systems.forms import ProjectiveForm
from simrun.systems.lanes import SpringMassLanes

# The probe's Newton solves a linear problem in one iteration; the tight tolerance only makes the
# convergence test insist on round-off (the problem's residual floor ends it there).
PROBE_SOLVER_PARAMS = solver_params(tolerance=1e-12)
PROBE_SOLVER = PROBE_SOLVER_PARAMS.build()
# The h w range (and resolution) of the predicted curves: two decades either side of h w = 1.
HW_RANGE = (1e-2, 1e2)
POINTS_PER_DECADE = 40
# rho above 1 + this counts as growth: below it the probe's round-off (about 1e-12 at h w = 1e3)
# could not be told from growth, and a growth of 1e-8 per step doubles the energy only after
# 3.5e7 steps.
GROWTH_TOLERANCE = 1e-8
# Deviations |rho - 1| above this are resolved (well above the probe's round-off) when deciding
# whether a method grows at every step size.
RESOLVED_DEVIATION = 1e-13
# How many of a step's unit round-offs the probed rho may miss by: a float32 engine's growth and deviations count
# above this many float32 round-offs (about 6e-5), float64's keep the tolerances above.
ROUNDOFF_MARGIN = 1e3
BISECTION_STEPS = 60
# Eigenvalues with |Im| below this fraction of their modulus are real: no oscillation, no period.
REAL_EIGENVALUE = 1e-9
PERIOD_HW_MAX = math.pi

# -- measured damping -------------------------------------------------------------------------------
# Energy below this fraction of E0 is near underflow (positions ~ 1e-150 of their start); not fitted.
ENERGY_FLOOR = 1e-200
# Samples skipped at the start of the fit: multistep starts and spurious roots decay within a few
# steps and would otherwise bias the slope.
SKIPPED_FRACTION, MIN_SKIPPED = 0.02, 2
MIN_FIT_SAMPLES = 5
# The energy ripples at twice the oscillation frequency; each harmonic of the ripple (2 w, 4 w) is
# fitted out when the samples resolve it: its phase advances by at most this fraction of pi
# (Nyquist) from one sample to the next.
RIPPLE_HARMONICS = (2.0, 4.0)
NYQUIST_MARGIN = 0.8
# The period is measured when a half period spans at least this many samples: the sign changes of a
# sampled oscillation then come at the mean rate phi / pi per sample, and the mean spacing of the
# interpolated crossings is accurate to about 2 dt / (number of crossings).
MIN_SAMPLES_PER_HALF_PERIOD = 1.5
# A fitted rate is resolved by the run when its standard error is at most this fraction of it, or
# (for methods without damping, whose rate is zero) at most RESOLVED_ABSOLUTE_ERROR w. The actual
# error of a fit is about one to two standard errors (the ripple is systematic, not noise), so a
# resolved rate is good to a few percent; runs of a handful of steps are not resolved.
RESOLVED_RELATIVE_ERROR, RESOLVED_ABSOLUTE_ERROR = 0.01, 1e-3

# -- observed order ---------------------------------------------------------------------------------
# Errors below this fraction of the length scale are round-off; above SATURATED_ERROR the error no
# longer follows dt^p (e.g. backward Euler has damped the motion away). Neither enters the fit.
ROUND_OFF_ERROR, SATURATED_ERROR = 1e-10, 0.1
# The fit uses the smallest time steps that remain (the asymptotic end), at most ORDER_FIT_POINTS
# and at least ORDER_MIN_POINTS of them (two points give a secant, not a fit).
ORDER_FIT_POINTS, ORDER_MIN_POINTS = 4, 3



# ==================================================================================================
# Integrators from names and parameters
# ==================================================================================================
def integrator_from_params(name: str, params: dict, class_path: str = "") -> Integrator:
    """The integrator of a run: its name and the ``integrator.*`` entries of its params (or plain keys); a plug-in
    by its recorded ``class_path`` (imported as installed or on PYTHONPATH, never from the current folder)."""
    method = _method_class(name, class_path)
    own = {key.removeprefix("integrator."): value for key, value in params.items()
           if key.startswith("integrator.") or "." not in key}
    own = {key: value for key, value in own.items() if key in method.model_fields}
    return method.model_validate(own)


def _method_class(name: str, class_path: str = "", current_folder: bool = False) -> type[Integrator]:
    """The class of a run's method: by its name, or, for a plug-in with a name of its own, by its class path. A
    whole-run peer (scipy's solve_ivp, a recorded trajectory) is no method of steps, and a method nonlinear by design
    (``linear = False``) has no amplification matrix: ValueError, as for a name that names nothing."""
    try:
        method = plugins.resolve(name if name in INTEGRATORS or not class_path else class_path, current_folder)
    except plugins.IntegratorTypeError as error:
        raise ValueError(str(error)) from None
    if method.whole_run:
        raise ValueError(f"{name} is a whole-run peer: another code takes its steps, so it has no amplification matrix")
    if not method.linear:
        raise ValueError(f"{name} declares linear = False: its step is not linear in the state, so it has no "
                         "amplification matrix (its runs are measured only)")
    return method


def parse_integrator(spec: str) -> Integrator:
    """An integrator from the command line: ``name``, ``name:key=value,key=value`` or a label ``name[key=value]``;
    the name may be a plug-in's path (``package.module:ClassName[key=value]``, ``package.module:ClassName:key=value``).

    Raises ValueError naming the valid integrators or the parameter's constraint.
    """
    text = spec.strip()
    if text.endswith("]") and "[" in text:
        name, _, rest = text[:-1].partition("[")
    else:
        name, _, rest = text.partition(":")
        if name.strip() not in plugins.names():  # a plug-in's path, package.module:ClassName[:key=value,...]
            head, _, tail = text.rpartition(":")
            name, rest = (head, tail) if ":" in head and "=" in tail else (text, "")
    name = name.strip()
    cls = _method_class(name, current_folder=True)  # a name the user typed, in their folder
    params = {}
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"{spec!r}: expected name:key=value[,key=value], e.g. generalized_alpha:rho_inf=0.5")
        params[key.strip()] = _number(value.strip())
    unknown = sorted(set(params) - set(cls.model_fields))
    if unknown:
        allowed = ", ".join(cls.model_fields) or "none"
        raise ValueError(f"{name}: unknown parameter {unknown[0]!r}; allowed: {allowed}")
    try:
        return cls.model_validate(params)
    except Exception as error:  # pydantic's ValidationError: keep its first line only
        detail = error.errors()[0] if hasattr(error, "errors") else {"loc": (), "msg": str(error)}
        where = ".".join(str(part) for part in detail["loc"])
        raise ValueError(f"{name}: {where}: {detail['msg']}") from None


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


# ==================================================================================================
# Predicted: the amplification matrix and what follows from it
# ==================================================================================================
def unit_spring(angular_frequency: float = 1.0):
    """The undamped test spring q'' + w^2 q = 0 with m = 1 kg, k = w^2 N/m, q0 = 1 m."""
    return SpringMassParams(stiffness=angular_frequency ** 2, mass=1.0, damping=0.0).build()


def amplification_matrix(integrator: Integrator, dt: float, system=None) -> np.ndarray:
    """The matrix of one step (s) of a linear system (default: the unit test spring, so dt = h w), found by stepping basis states.

    The state is (x, v, aux...) as the method carries it. Its layout is taken after one step from
    the system's initial state, so that two-step methods (whose history fills in their first
    step) give their companion matrix. Exact for linear systems: the implicit steps are solved by
    Newton, which converges in one iteration there.
    """
    system = unit_spring() if system is None else system
    state = integrator.start(system, State(0.0, system.x0.copy(), system.v0.copy()))
    state, _ = integrator.step(system, state, dt, PROBE_SOLVER)
    sizes = [state.x.size, state.v.size] + [part.size for part in state.aux]
    columns = []
    for unit in np.eye(sum(sizes)):
        x, v, *aux = np.split(unit, np.cumsum(sizes)[:-1])
        new, _ = integrator.step(system, State(0.0, x, v, tuple(aux)), dt, PROBE_SOLVER)
        columns.append(np.concatenate([new.x, new.v, *new.aux]))
    return np.column_stack(columns)


class SpringBank(System):
    """Uncoupled springs q_i'' + 2 zeta_i w_i q_i' + w_i^2 q_i = 0, m = 1 kg, w_i = h w_i (k_i = (h w_i)^2 N/m,
    d_i = 2 zeta_i h w_i N s/m), q_i(0) = 1 m: stepped at h = 1 s, the states of spring i are those of the test spring
    at h w_i and zeta_i. One step of a method on the bank is then one step at every point of a grid, for any method
    that takes a system (the lanes take only some)."""

    dim = 1
    quadratic_potential = True  # sum_i k_i q_i^2 / 2, every k_i > 0

    def __init__(self, hw: np.ndarray, damping_ratio: np.ndarray | None = None):
        hw = np.asarray(hw, dtype=float)
        self.stiffness = np.square(hw)
        self.dof_count = self.stiffness.size
        self.mass = np.ones(self.dof_count)
        self.x0, self.v0 = np.ones(self.dof_count), np.zeros(self.dof_count)
        self._hessian = scipy.sparse.diags_array(self.stiffness, format="csr")
        damping = np.zeros(hw.shape) if damping_ratio is None else 2.0 * np.broadcast_to(damping_ratio, hw.shape) * hw
        self.damping = damping  # N s/m per spring
        self._damping = scipy.sparse.diags_array(damping, format="csr") if np.any(damping != 0.0) else None

    def damping_matrix(self, x):
        return self._damping  # constant: D = diag(2 zeta_i w_i)

    @property
    def damping_is_constant(self) -> bool:
        return True

    def potential_energy(self, x):
        return 0.5 * float(self.stiffness @ (x * x))

    def gradient(self, x):
        return self.stiffness * x

    def hessian(self, x, project_spd=False):
        return self._hessian  # constant and SPD

    def projective_form(self):
        # zero-length Hookean springs to the origin, their rest stiffness the constant Hessian
        return ProjectiveForm(rest_stiffness=lambda: self._hessian)

    def compliant_form(self):
        """Spring i as a zero-length spring from vertex i to the origin, its damper along it (what XPBD projects)."""
        count = self.dof_count
        return CompliantSprings(first=np.arange(count), second=np.full(count, ANCHORED, dtype=np.intp),
                                anchor=np.zeros((count, 1)), rest_length=np.zeros(count), stiffness=self.stiffness.copy(),
                                damping=self.damping.copy(), vertex_count=count, other_forces=False)


def bank_matrices(integrator: Integrator, hw: np.ndarray, damping_ratio: np.ndarray | None = None) -> np.ndarray | None:
    """The one-step matrices (points, n, n) of the test spring at every h w of ``hw`` (and damping ratio, where given)
    from steps of a SpringBank: slot j of the state (x, v, then what the method carries) set to 1 in every spring at
    once gives column j of every matrix. None when the method carries something that is not one number per spring."""
    bank = SpringBank(hw, damping_ratio)
    count = bank.dof_count
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        state = integrator.start(bank, State(0.0, bank.x0.copy(), bank.v0.copy()))
        state, _ = integrator.step(bank, state, 1.0, PROBE_SOLVER)
        slots = 2 + len(state.aux)
        if any(part.shape != (count,) for part in (state.x, state.v, *state.aux)):
            return None
        matrices = np.empty((count, slots, slots))
        for column in range(slots):
            unit = [np.zeros(count) for _ in range(slots)]
            unit[column][:] = 1.0
            new, _ = integrator.step(bank, State(0.0, unit[0], unit[1], tuple(unit[2:])), 1.0, PROBE_SOLVER)
            matrices[:, :, column] = np.column_stack([new.x, new.v, *new.aux])
    return matrices


def amplification_matrices(integrator: Integrator, hw: np.ndarray, damping_ratio: np.ndarray) -> np.ndarray | None:
    """The one-step matrices (points, n, n) of the spring q'' + 2 zeta w q' + w^2 q = 0 at many (h w, zeta) at once:
    ``amplification_matrix`` with the points as lanes of one array (systems/lanes.py), probed by the method's own
    step on unit states; a method that does not step lanes is probed on a bank of springs, one per point (any method
    that takes a system). None only where neither applies (a method carrying more than a number per spring)."""
    from simrun.solvers.lanes import LaneNewton

    if not type(integrator).steps_lanes():
        return bank_matrices(integrator, hw, damping_ratio)
    # h = 1 s, so that w (rad/s) is h w; m = 1 kg, k = w^2
    springs = SpringMassLanes([SpringMassParams(stiffness=value * value, mass=1.0, damping_ratio=ratio).build()
                               for value, ratio in zip(np.asarray(hw, dtype=float).tolist(),
                                                       np.asarray(damping_ratio, dtype=float).tolist())])
    dt = np.ones((springs.lane_count, 1))
    solver = LaneNewton(PROBE_SOLVER_PARAMS)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        state = integrator.start(springs, State(0.0, springs.x0.copy(), springs.v0.copy()))
        state, _ = integrator.step(springs, state, dt, solver)
        sizes = [state.x.shape[1], state.v.shape[1]] + [part.shape[1] for part in state.aux]
        columns = []
        for unit in np.eye(sum(sizes)):
            x, v, *aux = np.split(np.tile(unit, (springs.lane_count, 1)), np.cumsum(sizes)[:-1], axis=1)
            new, _ = integrator.step(springs, State(0.0, x, v, tuple(aux)), dt, solver)
            columns.append(np.concatenate([new.x, new.v, *new.aux], axis=1))
    return np.stack(columns, axis=2)


def spectral_radius(matrix: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(matrix))))


def damping_over_frequency(rho, hw):
    """d_method / w = -2 ln(rho) / (h w): the energy of the test spring decays like exp(-d_method t)."""
    rho, hw = np.asarray(rho, dtype=float), np.asarray(hw, dtype=float)
    with np.errstate(divide="ignore"):
        return -2.0 * np.log(rho) / hw


@dataclass(frozen=True, eq=False)
class Prediction:
    """The predicted curves of one integrator on the test spring, against hw = h w (dimensionless)."""

    integrator: Integrator
    hw: np.ndarray  # (points,) h w
    rho: np.ndarray  # (points,) spectral radius
    damping: np.ndarray  # (points,) d_method / w
    period_error: np.ndarray  # (points,) T_method / T - 1; NaN for hw >= pi or where the root is real
    stability_limit: float  # h w where rho first exceeds 1 + growth_tolerance; 0: never stable; inf: none in range

    @property
    def growth_tolerance(self) -> float:
        return growth_tolerance(self.integrator)

    @property
    def label(self) -> str:
        return self.integrator.label

    def at(self, hw: float) -> tuple[float, float]:
        """(rho, d_method / w) at one hw, probed exactly (not interpolated)."""
        return probed_damping(self.integrator, hw)


def rho_resolution(integrator: Integrator) -> float:
    """|rho - 1| below which a probe in coarser arithmetic than float64 (a float32 engine's) reads no damping: its
    round-off, not its method; 0 for float64's probes, which resolve rho to about 1e-16."""
    unit_roundoff = integrator.unit_roundoff
    return ROUNDOFF_MARGIN * unit_roundoff if unit_roundoff > 2.0 ** -53 else 0.0


def probed_damping(integrator: Integrator, hw: float) -> tuple[float, float]:
    """(rho, d_method / w) of one probed step at h w; no damping where rho is within the probe's resolution of 1."""
    rho = spectral_radius(amplification_matrix(integrator, hw))
    if abs(rho - 1.0) <= rho_resolution(integrator):
        return rho, 0.0
    return rho, float(damping_over_frequency(rho, hw)) + 0.0


def hw_grid(low: float = HW_RANGE[0], high: float = HW_RANGE[1], per_decade: int = POINTS_PER_DECADE) -> np.ndarray:
    decades = math.log10(high) - math.log10(low)
    return np.logspace(math.log10(low), math.log10(high), max(2, int(round(decades * per_decade)) + 1))


@functools.lru_cache(maxsize=256)
def _predict_cached(integrator: Integrator, low: float, high: float, per_decade: int) -> Prediction:
    hw = hw_grid(low, high, per_decade)
    # every point of the grid in one step of a bank of springs (the same matrices up to the scaling of v, so the same
    # eigenvalues); point by point where the method carries more than a number per spring
    stacked = bank_matrices(integrator, hw)
    if stacked is None:
        stacked = np.stack([amplification_matrix(integrator, value) for value in hw])
    eigenvalues = list(np.linalg.eigvals(stacked))
    rho = np.array([float(np.max(np.abs(values))) for values in eigenvalues])
    principal = principal_eigenvalues(hw, eigenvalues)
    phase = np.abs(np.angle(principal))
    real = np.abs(principal.imag) <= REAL_EIGENVALUE * np.abs(principal)
    with np.errstate(divide="ignore", invalid="ignore"):
        period_error = np.where(real | (hw >= PERIOD_HW_MAX) | (phase == 0), np.nan, hw / phase - 1.0)
    for array in (hw, rho, period_error):
        array.setflags(write=False)
    damping = damping_over_frequency(rho, hw)
    damping.setflags(write=False)
    return Prediction(integrator, hw, rho, damping, period_error, _stability_limit(integrator, hw, rho))


def predict(integrator: Integrator, low: float = HW_RANGE[0], high: float = HW_RANGE[1],
            per_decade: int = POINTS_PER_DECADE) -> Prediction:
    """Spectral radius, damping, period error and stability limit of one integrator over h w in [low, high]."""
    if not 0 < low < high:
        raise ValueError(f"the h w range needs 0 < low < high, got [{low:g}, {high:g}]")
    return _predict_cached(integrator, float(low), float(high), int(per_decade))


def principal_eigenvalues(hw: np.ndarray, eigenvalues: list[np.ndarray]) -> np.ndarray:
    """The eigenvalue that approximates e^{i h w}, followed by continuation along the (increasing) hw grid.

    At the smallest hw it is the one nearest e^{i hw}; after that the one nearest the previous
    principal eigenvalue turned by the step in hw, so spurious roots of multistep methods (and the
    conjugate) are never picked up where the roots do not collide.
    """
    principal = np.empty(len(hw), dtype=complex)
    guess = np.exp(1j * hw[0])
    for number, values in enumerate(eigenvalues):
        if number:
            guess = principal[number - 1] * np.exp(1j * (hw[number] - hw[number - 1]))
        principal[number] = values[np.argmin(np.abs(values - guess))]
    return principal


def growth_tolerance(integrator: Integrator) -> float:
    """rho above 1 + this is growth for ``integrator``: GROWTH_TOLERANCE, or more where its steps round coarser."""
    return max(GROWTH_TOLERANCE, ROUNDOFF_MARGIN * integrator.unit_roundoff)


def _resolved_deviation(integrator: Integrator) -> float:
    return max(RESOLVED_DEVIATION, ROUNDOFF_MARGIN * integrator.unit_roundoff)


def _stability_limit(integrator: Integrator, hw: np.ndarray, rho: np.ndarray) -> float:
    """The h w at which rho first exceeds 1 + growth_tolerance(integrator), refined by bisection.

    0 when the method grows at every step size: rho > 1 already at the smallest hw, or the resolved
    deviations below the crossing are growth that shrinks like a power of hw (forward Euler, RK2).
    inf when rho stays <= 1 + growth_tolerance(integrator) over the whole grid.
    """
    tolerance = growth_tolerance(integrator)
    growing = np.nonzero(rho > 1.0 + tolerance)[0]
    if growing.size == 0:
        return math.inf
    first = int(growing[0])
    if first == 0:
        return 0.0
    low, high = math.log(hw[first - 1]), math.log(hw[first])
    for _ in range(BISECTION_STEPS):
        middle = 0.5 * (low + high)
        if spectral_radius(amplification_matrix(integrator, math.exp(middle))) > 1.0 + tolerance:
            high = middle
        else:
            low = middle
    crossing = math.exp(high)
    below = [spectral_radius(amplification_matrix(integrator, crossing * factor)) - 1.0 for factor in (0.5, 0.25)]
    if below[1] > _resolved_deviation(integrator) and below[0] > below[1]:
        return 0.0  # growth all the way down: no step is small enough
    return crossing


def growth_phrase(prediction: "Prediction") -> str | None:
    """Where the method grows on the undamped spring, in words, from the predicted curve: "grows at every h",
    "grows for h w < b" (BDF3 and BDF4: unstable as h w -> 0, damped beyond b), "stable for h w < a", "stable for
    h w < a and above b" (BDF5); None where it never grows on the grid."""
    limit = prediction.stability_limit
    if math.isinf(limit):
        return None
    tolerance = prediction.growth_tolerance
    growing = np.nonzero(prediction.rho > 1.0 + tolerance)[0]
    again = None
    if growing.size and growing[-1] + 1 < prediction.hw.size:  # damped again above the last point that grows
        low, high = math.log(prediction.hw[growing[-1]]), math.log(prediction.hw[growing[-1] + 1])
        for _ in range(BISECTION_STEPS):
            middle = 0.5 * (low + high)
            if spectral_radius(amplification_matrix(prediction.integrator, math.exp(middle))) > 1.0 + tolerance:
                low = middle
            else:
                high = middle
        again = math.exp(high)
    if limit == 0.0:
        return "grows at every h" if again is None else f"grows for h w < {again:.3g}"
    return f"stable for h w < {limit:.3g}" + ("" if again is None else f" and above {again:.3g}")


# h w at which the one-step map equals its limit h w -> infinity in double precision (its terms in 1/(h w)^2 are below round-off).
HW_INFINITY = 1e9
# Eigenvalues of the limit map closer than this belong to one cluster (a multiple root).
CLUSTER_DISTANCE = 1e-3


def high_frequency_radius(integrator: Integrator) -> float:
    """The spectral radius as h w -> infinity (rho_inf), from the probed limit map.

    Multiple roots are the rule there (generalized-alpha's three roots all meet at -rho_inf), and the
    eigenvalues of a defective matrix are only accurate to eps^(1/m) for an m-fold root; the mean
    of a cluster of eigenvalues is accurate to round-off all the same (it is the trace of the
    cluster's invariant subspace over its dimension; Golub & Van Loan, Matrix Computations, sec.
    7.2). So the eigenvalues are grouped into clusters and the radius is the largest |cluster mean|.
    """
    eigenvalues = list(np.linalg.eigvals(amplification_matrix(integrator, HW_INFINITY)))
    radius = 0.0
    while eigenvalues:
        seed = eigenvalues.pop(0)
        cluster = [seed] + [value for value in eigenvalues if abs(value - seed) <= CLUSTER_DISTANCE]
        eigenvalues = [value for value in eigenvalues if abs(value - seed) > CLUSTER_DISTANCE]
        radius = max(radius, abs(complex(np.mean(cluster))))
    return radius


def determinant(integrator: Integrator, dt: float, system) -> float:
    """det of the one-step map of a linear system: the factor by which a step scales phase-space area."""
    return float(np.linalg.det(amplification_matrix(integrator, dt, system)))


# ==================================================================================================
# Systems: a run's system rebuilt from its stored parameters
# ==================================================================================================
def build_system(system_type: str, system_params: dict):
    """Rebuild a run's system from its stored parameters (``system_params`` in the results file)."""
    from simrun.systems.plugins import resolve  # built-in names, package.module:Class, entry points

    # current_folder=False: reading a results file never imports code from the folder it is read in
    return resolve(system_type, current_folder=False).model_validate({**system_params, "type": system_type}).build()


# ==================================================================================================
# Measured: damping, period and order from recorded series
# ==================================================================================================
@dataclass(frozen=True)
class DampingFit:
    """The energy decay rate d (1/s) fitted to ln E(t) = a - d t (+ ripple), with its standard error."""

    rate: float  # 1/s; > 0 damping, < 0 growth; NaN when not measurable
    stderr: float  # 1/s
    samples: int  # used in the fit
    resolved: bool  # the run determines the rate: stderr <= RESOLVED_RELATIVE_ERROR |rate| (or the rate is round-off)

    @classmethod
    def unmeasurable(cls, samples: int = 0) -> "DampingFit":
        return cls(math.nan, math.nan, samples, False)


def measure_damping(t: np.ndarray, energy: np.ndarray, x: np.ndarray | None = None,
                    angular_frequency: float | None = None) -> DampingFit:
    """The artificial damping rate of an undamped linear run from its energy: least squares on ln E(t).

    E_n = rho^(2n) (a + b cos(2 n phi + c)) exactly for a one-step linear method, so ln E is a line
    of slope -d = 2 ln(rho)/h plus a ripple at twice the oscillation frequency. Where the samples
    resolve it, the ripple is fitted out with cos/sin columns at 2 and 4 times the frequency
    measured from the zero crossings of x (a recorded coordinate); otherwise the plain line is
    fitted. Samples at the start (multistep starts, spurious roots) and below ENERGY_FLOOR E0 are
    left out. Parameters: t (s), energy (J), x (m), all (samples,); angular_frequency w (rad/s),
    if known, lets a rate of zero count as resolved when its error is small against w.
    """
    t, energy = np.asarray(t, dtype=float), np.asarray(energy, dtype=float)
    count = min(t.size, energy.size)
    if count < MIN_FIT_SAMPLES or not np.isfinite(energy[0]) or energy[0] <= 0:
        return DampingFit.unmeasurable()
    t, energy = t[:count], energy[:count]
    keep = np.isfinite(energy) & np.isfinite(t) & (energy > ENERGY_FLOOR * energy[0])
    # the fit stops at the first sample that leaves the window (what follows is underflow or overflow)
    stop = int(np.argmin(keep)) if not keep.all() else count
    skip = max(MIN_SKIPPED, int(SKIPPED_FRACTION * stop))
    if stop - skip < MIN_FIT_SAMPLES:
        skip = max(0, stop - MIN_FIT_SAMPLES)
    window = slice(skip, stop)
    t_fit, log_energy = t[window], np.log(energy[window] / energy[0])
    if t_fit.size < MIN_FIT_SAMPLES:
        return DampingFit.unmeasurable(t_fit.size)
    columns = [np.ones_like(t_fit), t_fit - t_fit[0]]
    half_period = measure_half_period(t[:stop], None if x is None else np.asarray(x, dtype=float)[:stop])
    spacing = float(np.max(np.diff(t_fit)))
    if np.isfinite(half_period):
        frequency = math.pi / half_period  # rad/s of the oscillation; the energy ripples at twice it
        for harmonic in RIPPLE_HARMONICS:
            if harmonic * frequency * spacing <= NYQUIST_MARGIN * math.pi:
                columns += [np.cos(harmonic * frequency * t_fit), np.sin(harmonic * frequency * t_fit)]
    design = np.column_stack(columns)
    if design.shape[0] <= design.shape[1] + 1:
        design = design[:, :2]
    coefficients, _, rank, _ = np.linalg.lstsq(design, log_energy, rcond=None)
    residual = log_energy - design @ coefficients
    dof = design.shape[0] - design.shape[1]
    rate = -float(coefficients[1])
    if dof > 0 and rank == design.shape[1]:
        sigma2 = float(residual @ residual) / dof
        covariance = sigma2 * np.linalg.inv(design.T @ design)
        stderr = math.sqrt(max(float(covariance[1, 1]), 0.0))
    else:
        stderr = math.nan
    duration = float(t_fit[-1] - t_fit[0])
    # a rate indistinguishable from zero at round-off (energy-conserving methods) is resolved as zero
    small = stderr * duration < 1e-10 or (angular_frequency is not None and stderr <= RESOLVED_ABSOLUTE_ERROR * angular_frequency)
    resolved = bool(np.isfinite(stderr) and (stderr <= RESOLVED_RELATIVE_ERROR * abs(rate) or small))
    return DampingFit(rate, stderr, int(t_fit.size), resolved)


def measure_half_period(t: np.ndarray, x: np.ndarray | None) -> float:
    """Mean time (s) between sign changes of x (linearly interpolated), NaN with fewer than two."""
    if x is None or x.size < 3:
        return math.nan
    count = min(t.size, x.size)
    t, x = t[:count], x[:count]
    finite = np.isfinite(x) & np.isfinite(t)
    t, x = t[finite], x[finite]
    crossing = np.nonzero((x[:-1] > 0) != (x[1:] > 0))[0]
    crossing = crossing[x[crossing + 1] != x[crossing]]
    if crossing.size < 2:
        return math.nan
    times = t[crossing] - x[crossing] * (t[crossing + 1] - t[crossing]) / (x[crossing + 1] - x[crossing])
    return float((times[-1] - times[0]) / (crossing.size - 1))


def measure_period_error(t: np.ndarray, x: np.ndarray, angular_frequency: float) -> float:
    """T_measured / T - 1 from the zero crossings of x, T = 2 pi / w; NaN with too few crossings or samples per half period."""
    half = measure_half_period(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
    if not np.isfinite(half) or t.size < 2:
        return math.nan
    if half < MIN_SAMPLES_PER_HALF_PERIOD * float(np.median(np.diff(t))):
        return math.nan
    return 2.0 * half * angular_frequency / (2.0 * math.pi) - 1.0


@dataclass(frozen=True)
class OrderFit:
    """The slope of log(error) against log(dt) over the asymptotic points (``used``), and its line."""

    order: float  # NaN when fewer than ORDER_MIN_POINTS points qualify
    intercept: float
    used: np.ndarray  # (points,) bool, aligned with the sorted dts given
    exact: bool  # every error at round-off: the method is exact on this problem
    reason: str = ""  # why there is no slope (empty when there is one): what the errors were, what would help


def observed_order(dts, errors, scale: float = 1.0) -> OrderFit:
    """Least-squares slope of log(error) against log(dt) at the small-dt end.

    From the smallest dt up: points at round-off (error <= ROUND_OFF_ERROR scale) are skipped,
    then the consecutive points below saturation (error < SATURATED_ERROR scale) are taken, at
    most ORDER_FIT_POINTS; the first saturated point ends the range (a larger dt that happens to
    land near the exact phase is not asymptotic). ``dts`` (s) sorted ascending; errors (m)
    aligned; scale (m) is the problem's length scale. NaN order with fewer than ORDER_MIN_POINTS.
    """
    dts, errors = np.asarray(dts, dtype=float), np.asarray(errors, dtype=float)
    finite = np.isfinite(errors) & (dts > 0)
    used = np.zeros(dts.size, dtype=bool)
    started = False
    for index in np.nonzero(finite)[0]:
        if errors[index] <= ROUND_OFF_ERROR * scale and not started:
            continue
        if errors[index] >= SATURATED_ERROR * scale or errors[index] <= ROUND_OFF_ERROR * scale:
            break
        started = True
        used[index] = True
        if used.sum() == ORDER_FIT_POINTS:
            break
    exact = bool(finite.any() and np.all(errors[finite] <= ROUND_OFF_ERROR * scale))
    if used.sum() < ORDER_MIN_POINTS:
        return OrderFit(math.nan, math.nan, used, exact, _no_slope_reason(dts, errors, finite, used, exact, scale))
    slope, intercept = np.polyfit(np.log(dts[used]), np.log(errors[used]), 1)
    return OrderFit(float(slope), float(intercept), used, exact)


def _no_slope_reason(dts: np.ndarray, errors: np.ndarray, finite: np.ndarray, used: np.ndarray, exact: bool,
                     scale: float) -> str:
    """Why observed_order could not fit a slope, in the words a user can act on."""
    if not finite.any():
        return "no error known (no exact solution, and no reference asked for)"
    if exact:
        return "exact on this problem: every error is at round-off"
    saturated = finite & (errors >= SATURATED_ERROR * scale)
    asymptotic = int(used.sum())
    if asymptotic == 0 and saturated[finite].all():
        return (f"the error is saturated (at least {SATURATED_ERROR:g} of the length scale {scale:g} m) at every dt, "
                f"down to {dts[finite].min():.3g} s: smaller dts or an earlier record.error_time")
    where = f"{asymptotic} dt{'s' if asymptotic != 1 else ''}" if asymptotic else "no dt"
    return (f"{where} in the asymptotic range (error between {ROUND_OFF_ERROR:g} and {SATURATED_ERROR:g} of the "
            f"length scale), {ORDER_MIN_POINTS} needed: "
            + ("smaller dts (the larger ones are saturated)" if saturated.any() else "more dts"))
