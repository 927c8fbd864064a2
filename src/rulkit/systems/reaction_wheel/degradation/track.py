"""Step 2 on a user's record: the lubricant-loss parameters b and beta0 tracked over the
measured loss windows by the one-step and two-step particle filters of the seeds and the
Rao-Blackwellised PF (docs/systems/reaction-wheel.md §4, §7.2).

What the reproduction knows and a user does not is estimated from the record [R]:

- the noise of one loss measurement (wheel file ``[degradation] loss_sd_mL``, or, when 0, the
  robust spread of the residuals of the best constant law ``beta0 exp(-b / T^)`` fitted to the
  first :data:`FIT_WINDOWS` windows: the fault, if any, comes later);
- the scale of the beta0 prior: the prior is ``beta0_prior_rel`` times the beta0 of that fit.

Every tracker runs once over the windows (a single unit of the batched trackers of
:mod:`rulkit.systems.reaction_wheel.degradation.trackers`); the tracks carry mean +- z sd
intervals of the particle posterior per window; the posterior at the last window (particles
and weights) is what step 3 propagates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.degradation.quadrature import WindowQuadrature
from rulkit.systems.reaction_wheel.degradation.trackers import (
    DegradationConfig,
    one_step_pf,
    rbpf,
    two_step_pf,
)
from rulkit.systems.reaction_wheel.degradation.windows import LossRecord, WindowSums
from rulkit.systems.reaction_wheel.lubrication import SAMPLE_DT

FloatArray = np.ndarray
#: The trackers, by name.
TRACKERS = ("two_step", "one_step", "rbpf")
#: Windows of the constant-law fit that sets the noise and the beta0 scale [R].
FIT_WINDOWS = 360


@dataclass(frozen=True)
class LawFit:
    """The constant law ``beta0 exp(-b / T^)`` fitted by least squares to the first windows:
    ``b``, ``beta0``, the residuals' robust standard deviation ``resid_sd`` (1.4826 MAD), and
    the number of windows ``n``."""

    b: float
    beta0: float
    resid_sd: float
    n: int


def fit_constant_law(y: FloatArray, quad: WindowQuadrature, b_range: tuple[float, float],
                     n_fit: int = FIT_WINDOWS) -> LawFit:
    """Least squares of ``y_k = beta0 S_k(b) dt`` over the first ``n_fit`` windows: beta0 in
    closed form for each b of a 400-point grid over ``b_range``, the b with the least squared
    residual; ``quad`` of one unit (arrays (1, W, n))."""
    n = min(n_fit, y.size)
    if n < 3:
        raise ValueError(f"step 2 needs at least 3 loss windows with a temperature, got {n}")
    b_grid = np.linspace(b_range[0], b_range[1], 400)
    H = np.exp(quad.log_sums(np.broadcast_to(b_grid, (1, b_grid.size)), slice(0, n)))[0]
    H = H * SAMPLE_DT  # (n, grid)
    beta = (H * y[:n, None]).sum(axis=0) / (H * H).sum(axis=0)
    sse = ((y[:n, None] - beta * H) ** 2).sum(axis=0)
    j = int(np.argmin(sse))
    r = y[:n] - beta[j] * H[:, j]
    mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return LawFit(float(b_grid[j]), float(beta[j]), mad if mad > 0 else float(np.std(r)), n)


@dataclass
class DegradationTracks:
    """Step 2 on a record: ``table`` (a DataFrame, one row per window used: start_s, end_s,
    loss_mL, T_mean_C, and per tracker b, b_lo, b_hi, beta0, beta0_lo, beta0_hi), the
    ``posteriors`` at the last window (tracker -> (particles (N, 2) of [b, beta0], weights
    (N,))), the cumulative loss ``X_end`` and time ``t_end`` of the last window, the measurement
    noise ``sigma_y`` (mL) and where it came from, the constant-law ``fit``, the windows left
    out (no temperature estimate), and ``level``."""

    table: Any
    posteriors: dict[str, tuple[FloatArray, FloatArray]]
    X_end: float
    t_end: float
    sigma_y: float
    noise_source: str
    fit: LawFit
    n_missing: int
    level: float
    settings: DegradationConfig


def track_degradation(losses: LossRecord, sums: WindowSums, settings: DegradationConfig, *,
                      loss_sd_mL: float = 0.0, seed: int = 0, level: float = 0.9,
                      trackers: tuple[str, ...] = TRACKERS) -> DegradationTracks:
    """Run the step-2 trackers over the windows of ``losses`` that have a temperature estimate
    in ``sums`` (module docstring); generators from ``SeedSequence([seed, tracker index])``."""
    import pandas as pd

    unknown = sorted(set(trackers) - set(TRACKERS))
    if unknown:
        raise ValueError(f"trackers: unknown {unknown}; expected some of {TRACKERS}")
    keep = np.flatnonzero(sums.present)
    q = sums.quad
    quad = WindowQuadrature(q.center[:, keep], q.scale[:, keep], q.nodes[:, keep],
                            q.weights[:, keep], np.asarray(q.count)[..., keep])
    y = losses.loss_mL[keep]
    fit = fit_constant_law(y, quad, settings.b_prior)
    if loss_sd_mL > 0:
        sigma_y, src = float(loss_sd_mL), "wheel file [degradation] loss_sd_mL"
    else:
        sigma_y = fit.resid_sd
        src = (f"estimated: robust sd of the residuals of the constant law fitted to the first "
               f"{fit.n} windows")
    if not sigma_y > 0:
        raise ValueError("the loss measurements leave no residual spread to set their noise: "
                         "give [degradation] loss_sd_mL in the wheel file")
    z = NormalDist().inv_cdf(0.5 + level / 2)
    cols: dict[str, Any] = {"start_s": losses.start_s[keep], "end_s": losses.end_s[keep],
                            "loss_mL": y, "T_mean_C": sums.T_mean[keep]}
    posteriors: dict[str, tuple[FloatArray, FloatArray]] = {}
    last = (int(keep.size) - 1,)
    for i, name in enumerate(trackers):
        rngs = [np.random.default_rng(np.random.SeedSequence([seed, i, 0]))]
        kw: dict[str, Any] = {"beta_ref": fit.beta0, "snapshot_windows": last}
        if name == "two_step":
            out = two_step_pf(y[None], quad, sigma_y, settings, rngs,
                              [np.random.default_rng(np.random.SeedSequence([seed, i, 1]))], **kw)
        elif name == "one_step":
            out = one_step_pf(y[None], quad, sigma_y, settings, rngs, **kw)
        else:
            out = rbpf(y[None], quad, sigma_y, settings, rngs, **kw)
        for v, m, s in (("b", out.b_mean[0], out.b_std[0]),
                        ("beta0", out.beta0_mean[0], out.beta0_std[0])):
            cols[f"{v}_{name}"] = m
            cols[f"{v}_lo_{name}"] = m - z * s
            cols[f"{v}_hi_{name}"] = m + z * s
        parts, w = out.snapshots[last[0]]
        posteriors[name] = (parts[0], w[0] / w[0].sum())
    X_end = float(np.sum(losses.loss_mL[:keep[-1] + 1]))  # every measured loss up to the end
    return DegradationTracks(pd.DataFrame(cols), posteriors, X_end,
                             float(losses.end_s[keep[-1]]), sigma_y, src, fit,
                             int(losses.n_windows - keep.size), level, settings)


def save_step2(out: Path, tracks: DegradationTracks, losses: LossRecord,
               sums: WindowSums) -> list[Path]:
    """What step 3 needs later (``rulkit rw rul DIR``): ``posterior.csv`` (tracker, b, beta0,
    weight at the last window), ``step2.json`` (the cumulative loss and time at the end, the
    noise, the level) and ``step2.npz`` (the window rules of the step-1 estimate, to repeat
    the last days)."""
    import json

    import pandas as pd

    out = Path(out)
    rows = [pd.DataFrame({"tracker": k, "b": p[:, 0], "beta0": p[:, 1], "weight": w})
            for k, (p, w) in tracks.posteriors.items()]
    pd.concat(rows).to_csv(out / "posterior.csv", index=False)
    q = sums.quad
    np.savez(out / "step2.npz", start_s=losses.start_s, end_s=losses.end_s,
             present=sums.present, center=q.center, scale=q.scale, nodes=q.nodes,
             weights=q.weights, count=np.broadcast_to(np.asarray(q.count), q.center.shape))
    meta = {"X_end_mL": tracks.X_end, "t_end_s": tracks.t_end, "sigma_y_mL": tracks.sigma_y,
            "noise_source": tracks.noise_source, "level": tracks.level,
            "trackers": list(tracks.posteriors), "losses": losses.source}
    (out / "step2.json").write_text(json.dumps(meta, indent=1))
    return [out / "posterior.csv", out / "step2.json", out / "step2.npz"]


@dataclass(frozen=True)
class Step2State:
    """Step 2 as saved by :func:`save_step2`: the ``posteriors`` (tracker -> (particles (N, 2),
    weights)), the cumulative loss ``X_end`` (mL) at ``t_end`` (s), the windows
    (``losses`` start/end only) and their ``sums``, and ``meta`` (the json)."""

    posteriors: dict[str, tuple[FloatArray, FloatArray]]
    X_end: float
    t_end: float
    losses: LossRecord
    sums: WindowSums
    meta: dict[str, Any]


def load_step2(directory: Path) -> Step2State:
    """The step-2 results in ``directory`` (:func:`save_step2`); a missing or foreign file is
    refused naming it."""
    import json

    import pandas as pd

    d = Path(directory)
    need = [d / n for n in ("posterior.csv", "step2.json", "step2.npz")]
    missing = [p.name for p in need if not p.exists()]
    if missing:
        raise ValueError(f"{d}: not the output of step 2 (missing {', '.join(missing)}); run "
                         "`rulkit rw degradation` or `rulkit rw pipeline` into it first")
    meta = json.loads(need[1].read_text())
    post = pd.read_csv(need[0])
    posteriors = {str(k): (g[["b", "beta0"]].to_numpy(), g["weight"].to_numpy())
                  for k, g in post.groupby("tracker", sort=False)}
    with np.load(need[2]) as z:
        a = {k: z[k] for k in z.files}
    quad = WindowQuadrature(a["center"], a["scale"], a["nodes"], a["weights"], a["count"])
    sums = WindowSums(quad, np.full(a["end_s"].size, np.nan), np.zeros(a["end_s"].size),
                      a["present"].astype(bool))
    losses = LossRecord(a["start_s"], a["end_s"], np.zeros(a["end_s"].size), "saved",
                        str(meta.get("losses", "")))
    return Step2State(posteriors, float(meta["X_end_mL"]), float(meta["t_end_s"]), losses, sums,
                      meta)
