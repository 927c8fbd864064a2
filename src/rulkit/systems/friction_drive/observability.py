"""Observability of the friction drive's augmented state (seed 003; docs/systems/friction-drive.md
§6): output sensitivities by the linearisation and by finite differences, the Fisher information and
Cramer-Rao bound of a window, and the pointwise rank."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import expm

from rulkit.model import FloatArray
from rulkit.systems.friction_drive import drive as fd
from rulkit.systems.friction_drive.drive import SEED_R

if TYPE_CHECKING:
    from rulkit.systems.friction_drive.reproduce import Truth

def output_sensitivities_jacobian(
    X: FloatArray, dt: float, params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS
) -> FloatArray:
    """dy_k / dx_0 along a trajectory ``X`` (K+1, 4) by the product of ``expm(F_k dt)``
    (F the analytic Jacobian at the midpoint of each step, second order in dt); returns
    (K, 2, 4) for y_1..y_K."""
    J = fd.jacobian(0.5 * (X[:-1] + X[1:]), None, params) * dt
    Phi = expm(J)  # (K, 4, 4), batched
    K = X.shape[0] - 1
    out = np.empty((K, 2, 4))
    M = np.eye(4)
    for k in range(K):
        M = Phi[k] @ M
        out[k] = M[:2]
    return out


def output_sensitivities_fd(
    x0: FloatArray,
    currents: FloatArray,
    dt: float,
    n_sub: int = 4,
    rel: float = 1e-6,
    params: fd.FrictionDriveParams = fd.DEFAULT_PARAMS,
) -> FloatArray:
    """dy_k / dx_0 by central finite differences of the full model (an independent check of
    :func:`output_sensitivities_jacobian`); returns (K, 2, 4)."""
    x0 = np.asarray(x0, dtype=np.float64).reshape(4)
    h = rel * np.maximum(np.abs(x0), [1.0, 1.0, 1.0, 1e-2])
    batch = np.repeat(x0[None, :], 8, axis=0)
    for j in range(4):
        batch[2 * j, j] += h[j]
        batch[2 * j + 1, j] -= h[j]
    Y = fd.integrate_path(batch, currents, dt, n_sub=n_sub, params=params)[1:, :, :2]
    sens = np.empty((Y.shape[0], 2, 4))
    for j in range(4):
        sens[:, :, j] = (Y[:, 2 * j] - Y[:, 2 * j + 1]) / (2.0 * h[j])
    return sens


def fisher_information(sens: FloatArray, R: FloatArray) -> FloatArray:
    """Fisher information sum_k S_k^T R^-1 S_k of the window's initial state (the
    observability Gramian weighted by R^-1), (4, 4); ``sens`` (K, 2, 4)."""
    return np.einsum("kij,jl,klm->im", np.swapaxes(sens, 1, 2), np.linalg.inv(R), sens)


def cramer_rao(sens: FloatArray, R: FloatArray) -> FloatArray:
    """Cramer-Rao bound inv(sum_k S_k^T R^-1 S_k) of the window's initial state, (4, 4).

    The Fisher matrix (the observability Gramian weighted by R^-1) is inverted after a
    diagonal scaling (it spans many decades)."""
    fisher = fisher_information(sens, R)
    d = np.sqrt(np.clip(np.diag(fisher), 1e-300, None))
    scaled = fisher / np.outer(d, d)
    return np.linalg.pinv(scaled, rcond=1e-15) / np.outer(d, d)


@dataclass(frozen=True)
class Observability:
    """Windowed observability of alpha and m (Cramer-Rao sigmas over ``window`` seconds)."""

    input_kind: str
    t_start: float
    window: float
    sigma: tuple[float, float, float, float]
    fisher_condition: float
    pointwise_rank: int


def observability(
    truth: Truth, t_start: float, window: float = 2.0, R: FloatArray = SEED_R
) -> Observability:
    """Cramer-Rao sigmas of (w1, w2, alpha, m) from a ``window`` of measurements starting at
    ``t_start`` along ``truth`` (docs/systems/friction-drive.md §6), and the pointwise rank of the
    observability matrix [H; H F; H F^2; H F^3] at ``t_start`` (full whenever slip != 0)."""
    k0 = round(t_start / truth.dt)
    k1 = k0 + round(window / truth.dt)
    if k1 >= truth.X.shape[0]:
        raise ValueError(f"observability: window [{t_start}, {t_start + window}] s exceeds the "
                         f"truth ({truth.t[-1]} s)")
    sens = output_sensitivities_jacobian(truth.X[k0 : k1 + 1], truth.dt, truth.params)
    crb = cramer_rao(sens, R)
    fisher = fisher_information(sens, R)
    F = fd.jacobian(truth.X[k0 : k0 + 1])[0]
    H = np.eye(4)[:2]
    O = np.vstack([H, H @ F, H @ F @ F, H @ F @ F @ F])
    sv = np.linalg.svd(O, compute_uv=False)
    rank = int(np.sum(sv > sv[0] * 1e-14))
    d = np.sqrt(np.diag(fisher))
    return Observability(
        input_kind=truth.scenario.current,
        t_start=float(t_start),
        window=float(window),
        sigma=_four(np.sqrt(np.clip(np.diag(crb), 0, None))),
        fisher_condition=float(np.linalg.cond(fisher / np.outer(d, d))),
        pointwise_rank=rank,
    )




def _four(v: np.ndarray) -> tuple[float, float, float, float]:
    """The four entries of ``v`` (one per state) as floats."""
    a, b, c, d = (float(x) for x in v)
    return a, b, c, d
