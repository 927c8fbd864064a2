"""The T^ shortcut of step 2 (docs/systems/reaction-wheel.md §4): over months, the step-1
estimate is replaced by the true path plus an error process (bias + AR(1) held over blocks)
whose statistics are measured on real step-1 runs (:func:`fit_error_process`);
:func:`synthetic_estimate_quadrature` streams the window quadrature of such an estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import (
    WindowQuadrature,
    window_quadrature,
)
from rulkit.systems.reaction_wheel.lubrication import (
    SAMPLE_DT,
    T_MIN_C,
    WINDOW_SAMPLES,
    FloatArray,
    TemperaturePath,
    check_temperature,
)


@dataclass(frozen=True)
class EstimateErrorProcess:
    """Error of the step-1 estimate ``T^ - T`` as bias + stationary AR(1), held over blocks [R].

    ``e_i = bias + d_i``, ``d_i = rho d_{i-1} + std sqrt(1 - rho^2) eta_i`` with
    ``rho = exp(-hold_s / tau_s)``; the value is held for ``hold_samples`` 0.05 s samples (a
    step-1 estimate changes little within 2 s; the sample-to-sample jitter only adds a
    negligible convexity bias to window sums and is reported as ``white_std``, not simulated).
    The statistics come from measured step-1 runs (:func:`fit_error_process`); ``source`` says
    where they came from.
    """

    bias_c: float = 0.0
    std_c: float = 0.5
    tau_s: float = 60.0
    hold_samples: int = 40
    white_std_c: float = 0.0
    source: str = "placeholder [R] (not measured)"

    @property
    def hold_s(self) -> float:
        """Length of a hold block, s."""
        return self.hold_samples * SAMPLE_DT

    def estimate_blocks(self, path: TemperaturePath, k0: int, n_windows: int,
                        rngs: list[np.random.Generator], state: FloatArray | None = None
                        ) -> tuple[FloatArray, FloatArray]:
        """Synthetic ``T^`` per hold block for windows ``k0 .. k0+n_windows-1`` of every run.

        Returns ``(T_hat (R, n_windows, m), state (R,))`` with m = WINDOW_SAMPLES/hold_samples;
        ``state`` carries the AR(1) value into the next call (None starts from the stationary
        law). The true T of a block is taken at its middle sample.
        """
        if WINDOW_SAMPLES % self.hold_samples:
            raise ValueError(f"hold_samples must divide {WINDOW_SAMPLES}, got {self.hold_samples}")
        m = WINDOW_SAMPLES // self.hold_samples
        n_blocks = n_windows * m
        rho = float(np.exp(-self.hold_s / self.tau_s)) if self.tau_s > 0 else 0.0
        innov = self.std_c * np.sqrt(1.0 - rho * rho)
        R = len(rngs)
        if state is None:  # drawn before the innovations: chunking does not change the stream
            state = self.std_c * np.stack([g.standard_normal() for g in rngs])
        eta = np.stack([g.standard_normal(n_blocks) for g in rngs])
        d = _ar1(eta * innov, rho, np.asarray(state, dtype=np.float64))
        t_block = np.asarray((k0 * WINDOW_SAMPLES + (np.arange(n_blocks) + 0.5)
                              * self.hold_samples) * SAMPLE_DT, dtype=np.float64)
        T_hat = path(t_block)[None, :] + self.bias_c + d
        return T_hat.reshape(R, n_windows, m), d[:, -1].copy()


def _ar1(innovations: FloatArray, rho: float, d0: FloatArray) -> FloatArray:
    """``d_i = rho d_{i-1} + innovations_i`` along the last axis, starting from ``d_{-1} = d0``."""
    return _ar1_kernel(np.ascontiguousarray(innovations), float(rho),
                       np.ascontiguousarray(d0, dtype=np.float64))


@numba.njit(cache=True)
def _ar1_kernel(innov: FloatArray, rho: float, d0: FloatArray) -> FloatArray:  # pragma: no cover
    R, n = innov.shape
    out = np.empty((R, n))
    for r in range(R):
        d = d0[r]
        for i in range(n):
            d = rho * d + innov[r, i]
            out[r, i] = d
    return out


def fit_error_process(errors: FloatArray, *, hold_samples: int = 40, dt: float = SAMPLE_DT,
                      source: str = "measured") -> EstimateErrorProcess:
    """Fit :class:`EstimateErrorProcess` to step-1 errors ``T^ - T``, shape (R, n) at ``dt``.

    bias = mean error; the error is averaged over hold blocks; std = std of the block means;
    ``tau = -hold_s / ln(rho_1)`` from the pooled lag-1 autocorrelation of the block means (a
    lag-1 autocorrelation <= 0 gives tau = 0, i.e. independent blocks; tau is capped at the
    record length); ``white_std`` = std of the residual within blocks.
    """
    e = np.atleast_2d(np.asarray(errors, dtype=np.float64))
    if not np.all(np.isfinite(e)):
        raise ValueError("errors: non-finite values")
    n_blocks = e.shape[1] // hold_samples
    if n_blocks < 3:
        raise ValueError(f"errors: need at least 3 blocks of {hold_samples} samples per run")
    bias = float(e.mean())
    blocks = e[:, : n_blocks * hold_samples].reshape(e.shape[0], n_blocks, hold_samples)
    bm = blocks.mean(axis=-1)
    white = float((blocks - bm[..., None]).std())
    d = bm - bias
    std = float(d.std())
    num = float((d[:, 1:] * d[:, :-1]).mean())
    rho = num / max(float((d * d).mean()), 1e-300)
    hold_s = hold_samples * dt
    # rho <= 0: independent blocks (tau = 0); rho >= 1 (a trend-like error over the record,
    # end effects can push the estimate past 1): capped at the record length
    record_s = n_blocks * hold_s
    if rho <= 0.0:
        tau = 0.0
    elif rho >= 1.0:
        tau = record_s
    else:
        tau = min(float(-hold_s / np.log(rho)), record_s)
    return EstimateErrorProcess(bias_c=bias, std_c=std, tau_s=tau, hold_samples=hold_samples,
                                white_std_c=white, source=source)


def synthetic_estimate_quadrature(path: TemperaturePath, error: EstimateErrorProcess,
                                  n_windows: int, rngs: list[np.random.Generator], *,
                                  n_nodes: int = 5, chunk_windows: int = 1024
                                  ) -> WindowQuadrature:
    """Window quadrature of ``1/T^`` for each run with ``T^ = T + error`` over ``n_windows``.

    Streams the synthetic estimate in chunks (three months = 32,400 windows never exist in
    memory at once); returns a :class:`WindowQuadrature` with arrays of shape (R, W[, n]).
    """
    R = len(rngs)
    center = np.empty((R, n_windows))
    scale = np.empty((R, n_windows))
    nodes = np.empty((R, n_windows, n_nodes))
    weights = np.empty((R, n_windows, n_nodes))
    state = None
    for k0 in range(0, n_windows, chunk_windows):
        k1 = min(n_windows, k0 + chunk_windows)
        T_hat, state = error.estimate_blocks(path, k0, k1 - k0, rngs, state)
        # a synthetic estimate below 5 C (possible only for huge error statistics) is clipped
        # there [R]: the loss law is singular at 0 C and step-1 priors start at 15 C
        np.maximum(T_hat, T_MIN_C, out=T_hat)
        check_temperature(T_hat, "synthetic T^")
        q = window_quadrature(1.0 / T_hat, n_nodes, count=WINDOW_SAMPLES)
        center[:, k0:k1], scale[:, k0:k1] = q.center, q.scale
        nodes[:, k0:k1], weights[:, k0:k1] = q.nodes, q.weights
    return WindowQuadrature(center, scale, nodes, weights, float(WINDOW_SAMPLES))
