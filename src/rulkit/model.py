"""The model contract shared by every physical system (CONTRIBUTING.md, "Layout";
docs/engine-api.md).

A model is a vectorised discrete-time (or discretised continuous-time) state-space model over a
batch of states ``x`` of shape ``(N, n_x)``: N particles, N Monte Carlo samples or N fleet units.
One noise description per model, used by the simulator and by every filter.

The one calling convention (docs/engine-api.md, "The calling convention"): everything that
advances a batch of states is ``step(x (N, n_x), u, t, dt, rng) -> (N, n_x)``, with process noise
when ``rng`` is a Generator and none when it is None. Every algorithm takes a model (or such a
step) through ``from_model`` / ``model=``; the narrower forms some algorithms run on internally
(the particle filter's ``transition(x, k, rng)``, the EKF's ``f(x, u, k)``) are built from it by
:func:`transition_from_model` and friends, never written by hand.

Usage::

    sim = model.simulate(x0, n_steps=50, rng=np.random.default_rng(0))
    res = ParticleFilter.from_model(model).filter(sim.y, particles0, rng)
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
#: An input: None, a constant array (n_u,) / (N, n_u), or a callable ``u(t)`` returning one.
InputLike = None | np.ndarray | Callable[[float], Any]
#: The one calling convention: ``step(x (N, n_x), u, t, dt, rng) -> (N, n_x)``.
Step = Callable[[FloatArray, Any, float, float, "np.random.Generator | None"], FloatArray]


def plain(value: Any) -> str:
    """``repr`` of a value for an error message, numpy scalars and arrays as plain Python
    numbers and lists (``250.0``, not ``np.float64(250.0)``); long reprs are shortened."""
    if isinstance(value, list | tuple):  # a list of numpy numbers prints them as numpy too
        try:
            value = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            pass
    tolist = getattr(value, "tolist", None)
    text = repr(tolist() if callable(tolist) else value)
    return text if len(text) <= 80 else text[:77] + "..."


def as_batch(
    x: Any, n_x: int | None = None, name: str = "x", *, single: bool = True, batch: str = "N"
) -> FloatArray:
    """The engine's one validator of a batch of states: ``x`` as a float64 ``(N, n_x)`` array.

    A single state ``(n_x,)`` is read as ``N = 1`` when ``single`` (a model's step, a Kalman
    filter's one unit); with ``single=False`` a 1-D array is refused (particles of a scalar state
    must be ``(N, 1)``: a 1-D array would be ambiguous). ``n_x`` None accepts any positive
    number of columns; ``batch`` names the leading axis in messages (``"N"``, ``"B"``).
    Raises ``ValueError`` naming ``name``: a wrong shape (with the one expected), an empty
    batch, or a NaN / infinite value (its row and column).
    """
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 1 and single:
        arr = arr[None, :]
    cols = "n_x" if n_x is None else str(n_x)
    if arr.ndim != 2 or (n_x is not None and arr.shape[1] != n_x):
        alt = f" or ({cols},)" if single else ""
        hint = (" (use x.reshape(-1, 1) for a scalar state)"
                if np.ndim(x) == 1 and batch == "N" else "")
        raise ValueError(f"{name}: expected shape ({batch}, {cols}){alt}, got {np.shape(x)}{hint}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name}: need at least one row and one state, got shape {arr.shape}")
    if not np.isfinite(arr.sum()) and not np.all(np.isfinite(arr)):
        i, j = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}: non-finite value {arr[i, j]} at row {i}, column {j}")
    return arr


def check_covariance(
    cov: Any, n: int, name: str, *, units: bool | int = False, definite: bool = False,
    rtol: float = 1e-10,
) -> FloatArray:
    """The engine's one covariance check: shape, finite, symmetric, positive semi-definite.

    ``cov`` is ``(n, n)`` (a scalar when ``n == 1``) or, when ``units`` is True (any number of
    units) or an int ``B``, also a per-unit stack ``(B, n, n)``. Symmetric to a relative
    ``1e-10``; the smallest eigenvalue must be ``>= -rtol`` times the largest magnitude
    (``> 0`` with ``definite=True``; a filter checking its own propagated covariance passes a
    looser ``rtol`` for round-off). Raises ``ValueError`` naming ``name`` (and the unit of a
    stack) with what is wrong; returns the float64 array.
    """
    c = np.asarray(cov, dtype=np.float64)
    if c.ndim == 0 and n == 1:
        c = c.reshape(1, 1)
    stack = units is not False and c.ndim == 3 and c.shape[1:] == (n, n) and (
        units is True or c.shape[0] == units)
    if c.shape != (n, n) and not stack:
        per_unit = "" if units is False else (
            f" or ({'B' if units is True else units}, {n}, {n})")
        raise ValueError(f"{name}: expected shape ({n}, {n}){per_unit}, got {np.shape(cov)}")
    if not np.all(np.isfinite(c)):
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(c))[0])
        raise ValueError(f"{name}: NaN or infinite entry at index {idx}")
    def unit(bad: Any, form: str) -> str:  # which unit of a stack, for the message
        return form.format(int(np.flatnonzero(bad)[0])) if c.ndim == 3 else ""

    scale = max(1.0, float(np.abs(c).max(initial=0.0)))
    close = np.isclose(c, np.swapaxes(c, -1, -2), rtol=1e-10, atol=1e-13 * scale)
    if not close.all():
        raise ValueError(f"{name}: not symmetric{unit(~close.all(axis=(-1, -2)), ' (unit {})')}")
    eig = np.linalg.eigvalsh(0.5 * (c + np.swapaxes(c, -1, -2)))
    lo = eig[..., 0]
    tol = rtol * np.maximum(np.abs(eig).max(axis=-1), np.finfo(np.float64).tiny)
    bad = lo <= 0.0 if definite else lo < -tol
    if np.any(bad):
        what = "positive definite" if definite else "positive semi-definite"
        worst = float(np.min(lo))
        raise ValueError(f"{name}: not {what}{unit(bad, ' for unit {}')} (smallest eigenvalue "
                         f"{worst:.3g})")
    return c


def psd_sqrt(c: FloatArray) -> FloatArray:
    """A square root ``L`` with ``L L^T = c`` of a symmetric positive semi-definite ``c``.

    From the eigen-decomposition, so a singular ``c`` is fine: eigenvalues below
    ``n eps max|lambda|`` are round-off of a zero eigenvalue and are set to 0, so samples
    ``L z`` lie in the range of ``c`` only (no noise of relative size sqrt(eps) in the
    directions ``c`` says are noise-free).
    """
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    tol = c.shape[0] * np.finfo(np.float64).eps * float(np.abs(w).max(initial=0.0))
    return v * np.sqrt(np.where(w > tol, w, 0.0))


@dataclass(frozen=True)
class GaussianNoise:
    """Additive zero-mean Gaussian process and measurement noise of a model.

    ``Q`` is the process-noise covariance per step of length ``dt`` (n_x, n_x); ``R`` the
    measurement-noise covariance (n_y, n_y). Validated on construction.
    """

    Q: FloatArray
    R: FloatArray
    _chol_Q: FloatArray = field(init=False, repr=False)
    _chol_R: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("Q", "R"):
            shape = np.shape(getattr(self, name))
            if len(shape) > 2 or (len(shape) == 2 and shape[0] != shape[1]) or len(shape) == 1:
                raise ValueError(f"{name}: expected a square (n, n) matrix or a scalar, got "
                                 f"shape {shape}")
        Q = check_covariance(self.Q, np.atleast_2d(self.Q).shape[0], "Q")
        R = check_covariance(self.R, np.atleast_2d(self.R).shape[0], "R")
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "_chol_Q", psd_sqrt(Q))
        object.__setattr__(self, "_chol_R", psd_sqrt(R))

    def sample_process(self, n: int, rng: np.random.Generator) -> FloatArray:
        """Draw ``n`` process-noise vectors, shape (n, n_x)."""
        return rng.standard_normal((n, self.Q.shape[0])) @ self._chol_Q.T

    def sample_measurement(self, n: int, rng: np.random.Generator) -> FloatArray:
        """Draw ``n`` measurement-noise vectors, shape (n, n_y)."""
        return rng.standard_normal((n, self.R.shape[0])) @ self._chol_R.T


class StateSpaceModel(ABC):
    """Vectorised state-space model: ``x_{k+1} = step(x_k, u_k, t_k, dt, rng)``, ``y = output(x)``.

    Subclasses set ``state_names``, ``input_names`` and ``output_names`` and implement
    :meth:`step` (which adds process noise when ``rng`` is given and is deterministic when
    ``rng`` is None) and :meth:`output` (noise-free). :attr:`noise` is the single noise
    description used by the simulator and every filter. A failure event is given by
    :meth:`health` (a scalar per state) crossing :attr:`threshold` upward.
    """

    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    threshold: float = np.inf

    @property
    def n_x(self) -> int:
        return len(self.state_names)

    @property
    def n_y(self) -> int:
        return len(self.output_names)

    @property
    @abstractmethod
    def noise(self) -> GaussianNoise:
        """Process and measurement noise of the model."""

    @abstractmethod
    def step(
        self,
        x: FloatArray,
        u: FloatArray | None,
        t: float,
        dt: float,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """Advance a batch of states (N, n_x) by ``dt``; add process noise when ``rng`` is given."""

    @abstractmethod
    def output(self, x: FloatArray, u: FloatArray | None = None) -> FloatArray:
        """Noise-free measurement of a batch of states, shape (N, n_y)."""

    def health(self, x: FloatArray) -> FloatArray:
        """Scalar degradation indicator per state, shape (N,); failure when >= ``threshold``."""
        raise NotImplementedError(f"{type(self).__name__} defines no failure event")

    # -- optional parts of the contract -----------------------------------------------------
    def log_likelihood(self, x: FloatArray, y: Any, u: FloatArray | None = None) -> FloatArray:
        """``log p(y | x_i)`` per state, shape (N,): Gaussian ``N(y; output(x), noise.R)``.

        Override for a non-Gaussian sensor; the filters built by ``from_model`` use the override
        when there is one (called as ``log_likelihood(x, y)`` without inputs).
        """
        R = self.noise.R
        return gaussian_loglik(self.output(x, u), y, np.linalg.cholesky(R))

    def step_jacobian(self, x: FloatArray, u: Any, t: float, dt: float) -> FloatArray:
        """Optional analytic Jacobian ``d step(x, u, t, dt, None) / dx``, shape (N, n_x, n_x).

        Not defined by default: ``ExtendedKalmanFilter.from_model`` then uses central finite
        differences (:func:`rulkit.estimation.kalman.numerical_jacobian`).
        """
        raise NotImplementedError

    def output_jacobian(self, x: FloatArray, u: Any = None) -> FloatArray:
        """Optional analytic Jacobian ``d output(x, u) / dx``, shape (N, n_y, n_x)."""
        raise NotImplementedError

    def simulate(
        self,
        x0: np.ndarray,
        n_steps: int,
        rng: np.random.Generator,
        dt: float | None = None,
        *,
        u: InputLike = None,
        t0: float = 0.0,
    ) -> Simulation:
        """Simulate states and noisy measurements from ``x0`` for ``n_steps`` steps.

        ``x0`` is one state (n_x,) (then the result has no unit axis) or a batch (N, n_x).
        ``dt`` defaults to the model's ``dt`` attribute. Step k applies ``step(x_k, u(t_k),
        t_k, dt, rng)`` (process noise included) and measures the new state,
        ``y_k = output(x_{k+1}) + v_k`` with ``v_k ~ N(0, noise.R)``: the filters' convention
        (a transition before every measurement), so ``sim.y`` goes straight into ``filter``.
        Measurement noise is drawn after all steps. Returns a :class:`Simulation`.
        """
        h = model_dt(self, dt)
        if isinstance(n_steps, bool) or int(n_steps) != n_steps or n_steps < 1:
            raise ValueError(f"n_steps: expected a positive integer, got {plain(n_steps)}")
        n_steps = int(n_steps)
        single = np.ndim(x0) == 1
        x = as_batch(x0, self.n_x, "x0")
        xs = np.empty((n_steps + 1, *x.shape))
        xs[0] = x
        t = t0 + h * np.arange(n_steps + 1, dtype=np.float64)
        outs = []
        for k in range(n_steps):
            xs[k + 1] = check_step_output(
                self.step(xs[k], input_at(u, float(t[k])), float(t[k]), h, rng), x.shape, k
            )
            outs.append(self.output(xs[k + 1], input_at(u, float(t[k + 1]))))
        y = np.stack(outs)
        y = y + self.noise.sample_measurement(y.shape[0] * y.shape[1], rng).reshape(y.shape)
        event = _event_times(self, t, xs)
        if single:
            return Simulation(t, xs[:, 0], y[:, 0], None if event is None else float(event[0]),
                              self.state_names, self.output_names)
        return Simulation(t, xs, y, event, self.state_names, self.output_names)


def _event_times(model: StateSpaceModel, t: FloatArray, xs: FloatArray) -> Any:
    """First upward crossing of ``model.threshold`` by ``model.health`` per unit (linear
    interpolation within the step, as :func:`rulkit.prognosis.rul.propagate_to_threshold`);
    NaN where it never crosses; None when the model defines no failure event."""
    if not math.isfinite(model.threshold):
        return None
    try:
        g = np.stack([model.health(xk) for xk in xs])  # (T+1, N)
    except NotImplementedError:
        return None
    over = g >= model.threshold
    out = np.full(g.shape[1], np.nan)
    for i in np.flatnonzero(over.any(axis=0)):  # loop over units, not samples of a batch
        k = int(np.argmax(over[:, i]))
        if k == 0:
            out[i] = t[0]
            continue
        frac = (model.threshold - g[k - 1, i]) / (g[k, i] - g[k - 1, i])
        out[i] = t[k - 1] + frac * (t[k] - t[k - 1])
    return out


@dataclass(frozen=True, eq=False)
class Simulation:
    """States and measurements of :meth:`StateSpaceModel.simulate`.

    ``t`` (T+1,) times of the states; ``x`` (T+1, n_x) (one unit) or (T+1, N, n_x); ``y``
    (T, n_y) or (T, N, n_y) where ``y[k]`` measures ``x[k+1]`` at time ``t[k+1]``;
    ``event_time`` the first crossing of the failure threshold (float for one unit, (N,) array
    for a batch, NaN if it never crosses within the run, None if the model has no failure
    event). Unpacks as ``t, x, y = sim``. :meth:`to_pandas` gives a tidy table.
    """

    t: FloatArray
    x: FloatArray
    y: FloatArray
    event_time: Any
    state_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def __iter__(self) -> Iterator[FloatArray]:
        return iter((self.t, self.x, self.y))

    @property
    def t_y(self) -> FloatArray:
        """Times of the measurements, ``t[1:]``."""
        return self.t[1:]

    def to_pandas(self) -> Any:
        """A DataFrame with one row per time (and unit): ``t`` [``unit``], the states, and the
        measurements (NaN at the initial time, which has none)."""
        import pandas as pd

        x = self.x if self.x.ndim == 3 else self.x[:, None, :]
        y = self.y if self.y.ndim == 3 else self.y[:, None, :]
        n_t, n_u, _ = x.shape
        y_full = np.full((n_t, n_u, y.shape[2]), np.nan)
        y_full[1:] = y
        sn = self.state_names or tuple(f"x{j}" for j in range(x.shape[2]))
        on = self.output_names or tuple(f"y{j}" for j in range(y.shape[2]))
        cols: dict[str, Any] = {"t": np.repeat(self.t, n_u)}
        if self.x.ndim == 3:
            cols["unit"] = np.tile(np.arange(n_u), n_t)
        for j, name in enumerate(sn):
            cols[name] = x[:, :, j].ravel()
        for j, name in enumerate(on):
            cols[name] = y_full[:, :, j].ravel()
        return pd.DataFrame(cols)


# ---------------------------------------------------------------------------------------------
# Adapters: from the one calling convention to the narrower forms algorithms run on
# ---------------------------------------------------------------------------------------------


def model_dt(model: Any, dt: float | None) -> float:
    """The step length: ``dt`` when given, else the model's ``dt`` attribute; validated."""
    h = getattr(model, "dt", None) if dt is None else dt
    if h is None:
        raise ValueError(f"dt: {type(model).__name__} has no 'dt' attribute; pass dt=...")
    h = float(h)
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"dt: expected a positive finite step, got {plain(h)}")
    return h


def input_at(u: InputLike, t: float) -> Any:
    """The input at time ``t``: None, the constant array, or ``u(t)``."""
    if u is None:
        return None
    return u(t) if callable(u) else u


def check_step_output(x: Any, shape: tuple[int, ...], k: int, name: str = "step") -> FloatArray:
    """A step's output must be a float array of ``shape``; errors name the step."""
    if getattr(x, "shape", None) != shape:
        raise ValueError(f"{name} at step {k}: returned shape {np.shape(x)}, expected {shape}")
    return x  # type: ignore[no-any-return]


def gaussian_loglik(yhat: FloatArray, y: Any, chol_R: np.ndarray) -> FloatArray:
    """``log N(y; yhat_i, R)`` per row of ``yhat`` (N, n_y), ``chol_R`` the Cholesky factor of R.

    ``y`` may be (n_y,) or a scalar when n_y = 1.
    """
    n_y = chol_R.shape[0]
    yy = np.asarray(y, dtype=np.float64).reshape(n_y)
    log_norm = -0.5 * n_y * math.log(2 * math.pi) - float(np.log(np.diag(chol_R)).sum())
    if n_y == 1:
        r = (yy[0] - yhat[:, 0]) / chol_R[0, 0]
        return log_norm - 0.5 * r * r  # type: ignore[no-any-return]
    import scipy.linalg

    r = scipy.linalg.solve_triangular(chol_R, (yy - yhat).T, lower=True)
    return log_norm - 0.5 * np.einsum("ij,ij->j", r, r)  # type: ignore[no-any-return]


def _overrides(model: Any, name: str) -> bool:
    """True when ``model``'s class overrides the contract's default method ``name``."""
    return getattr(type(model), name, None) is not getattr(StateSpaceModel, name)


def transition_from_model(
    model: StateSpaceModel, dt: float | None = None, t0: float = 0.0, u: InputLike = None
) -> Callable[[FloatArray, int, np.random.Generator], FloatArray]:
    """The particle filter's ``transition(x, k, rng)``: ``model.step(x, u(t_k), t_k, dt, rng)``
    with ``t_k = t0 + k dt`` (step k leads to measurement k at ``t0 + (k + 1) dt``)."""
    h = model_dt(model, dt)
    step = model.step
    if u is None:
        def transition(x: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
            return step(x, None, t0 + k * h, h, rng)
    else:
        def transition(x: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
            t = t0 + k * h
            return step(x, input_at(u, t), t, h, rng)
    return transition


def loglik_from_model(
    model: StateSpaceModel,
    dt: float | None = None,
    t0: float = 0.0,
    u: InputLike = None,
    R: np.ndarray | None = None,
) -> Callable[[FloatArray, Any, int], FloatArray]:
    """The particle filter's ``log_likelihood(x, y, k)`` of measurement k (time ``t0 + (k+1)
    dt``): the model's own ``log_likelihood`` when it overrides the contract's, else the
    Gaussian ``N(y; output(x, u), R)`` with ``R = model.noise.R`` unless given (Cholesky
    factor computed once here)."""
    if R is None and u is None and _overrides(model, "log_likelihood"):
        own = model.log_likelihood

        def loglik_own(x: FloatArray, y: Any, k: int) -> FloatArray:
            return own(x, y)
        return loglik_own
    if R is None and _overrides(model, "log_likelihood"):
        own_u = model.log_likelihood
        h_u = model_dt(model, dt)

        def loglik_own_u(x: FloatArray, y: Any, k: int) -> FloatArray:
            return own_u(x, y, input_at(u, t0 + (k + 1) * h_u))
        return loglik_own_u
    Rm = model.noise.R if R is None else check_covariance(R, model.n_y, "R")
    L = np.linalg.cholesky(Rm)
    output = model.output
    h = model_dt(model, dt) if u is not None else 1.0

    def loglik(x: FloatArray, y: Any, k: int) -> FloatArray:
        uk = None if u is None else input_at(u, t0 + (k + 1) * h)
        return gaussian_loglik(output(x, uk), y, L)
    return loglik


def check_measurements(ys: Any, n_y: int, name: str = "ys") -> FloatArray:
    """Measurements of one unit as a float (T, n_y) array: (T,) is accepted when n_y = 1.

    Raises ``ValueError`` naming ``name``, the shape received and the shape expected (before
    any user code runs), or the first row holding an infinite value (NaN means missing).
    """
    arr = np.asarray(ys, dtype=np.float64)
    if arr.ndim == 1 and n_y == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != n_y or arr.shape[0] == 0:
        extra = " or (T,)" if n_y == 1 else ""
        raise ValueError(f"{name}: expected shape (T, {n_y}){extra} for a model with {n_y} "
                         f"output(s), got {np.shape(ys)}")
    inf_rows = np.isinf(arr).any(axis=1)
    if inf_rows.any():
        raise ValueError(f"{name}: infinite value in row {int(np.flatnonzero(inf_rows)[0])} "
                         "(use NaN for a missing measurement)")
    return arr


@dataclass(frozen=True)
class KalmanFunctions:
    """A model in the Kalman filters' form: ``f(x, u, k)`` (the noise-free step k, from
    ``t_k = t0 + k dt``), ``h(x, u, k)`` (the output at ``t_{k+1}``), the analytic Jacobians
    ``jac_f``, ``jac_h`` or None, and the per-step covariances ``Q``, ``R``."""

    f: Callable[[FloatArray, Any, int], FloatArray]
    h: Callable[[FloatArray, Any, int], FloatArray]
    jac_f: Callable[[FloatArray, Any, int], FloatArray] | None
    jac_h: Callable[[FloatArray, Any, int], FloatArray] | None
    Q: FloatArray
    R: FloatArray


def kalman_functions_from_model(
    model: StateSpaceModel,
    dt: float | None = None,
    t0: float = 0.0,
    u: InputLike = None,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    jacobian: str = "auto",
) -> KalmanFunctions:
    """Adapt ``model`` to the EKF/UKF form (:class:`KalmanFunctions`).

    An input given to the filter's ``filter(..., us=...)`` takes precedence over ``u``.
    ``jacobian``: ``"auto"`` uses the model's ``step_jacobian`` / ``output_jacobian`` when it
    defines them (finite differences otherwise), ``"numerical"`` always finite differences.
    ``model.noise.Q`` is the covariance of one step of the model's own ``dt``: a different
    ``dt`` needs an explicit ``Q`` (a ``ValueError`` says so).
    """
    if jacobian not in ("auto", "numerical"):
        raise ValueError(f"jacobian: expected 'auto' or 'numerical', got {jacobian!r}")
    h = model_dt(model, dt)
    own_dt = getattr(model, "dt", None)
    if Q is None and own_dt is not None and not math.isclose(float(own_dt), h, rel_tol=1e-12):
        raise ValueError(f"Q: model.noise.Q is the covariance of one step of the model's dt = "
                         f"{plain(own_dt)}; filtering with dt = {plain(h)} needs Q=... for "
                         "that step")
    Qm = model.noise.Q if Q is None else check_covariance(Q, model.n_x, "Q")
    Rm = model.noise.R if R is None else check_covariance(R, model.n_y, "R")
    step, output = model.step, model.output

    def f(x: FloatArray, uk: Any, k: int) -> FloatArray:
        t = t0 + k * h
        return step(x, input_at(u, t) if uk is None else uk, t, h, None)

    def hh(x: FloatArray, uk: Any, k: int) -> FloatArray:
        return output(x, input_at(u, t0 + (k + 1) * h) if uk is None else uk)

    jac_f = jac_h = None
    if jacobian == "auto" and _overrides(model, "step_jacobian"):
        sj = model.step_jacobian

        def jac_f(x: FloatArray, uk: Any, k: int) -> FloatArray:
            t = t0 + k * h
            return sj(x, input_at(u, t) if uk is None else uk, t, h)
    if jacobian == "auto" and _overrides(model, "output_jacobian"):
        oj = model.output_jacobian

        def jac_h(x: FloatArray, uk: Any, k: int) -> FloatArray:
            return oj(x, input_at(u, t0 + (k + 1) * h) if uk is None else uk)
    return KalmanFunctions(f, hh, jac_f, jac_h, Qm, Rm)
