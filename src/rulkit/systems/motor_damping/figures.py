"""Figures of the seed 002 reproduction (like the seed's Figs. 8-17), matplotlib Agg backend."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rulkit.systems.motor_damping.macro import predicted_damping
from rulkit.systems.motor_damping.motor import pullup_speed_exact

if TYPE_CHECKING:
    from rulkit.systems.motor_damping.reproduce import MotorDampingResult

__all__ = ["make_figures"]


def make_figures(res: MotorDampingResult, out: Path) -> list[Path]:
    """Write the figures into ``out`` and return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    paths: list[Path] = []
    for draw in (_fig08_micro_cycle, _fig09_damping, _fig10_curves, _fig11_12_curve_slope,
                 _fig13_15_predictions, _fig16_slope, _fig17_rul, _fig_macro_models):
        for fig, name in draw(res, plt):
            p = out / name
            fig.tight_layout()
            fig.savefig(p, dpi=110)
            plt.close(fig)
            paths.append(p)
    return paths


def _fig08_micro_cycle(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Fig. 8: micro EKF within one cycle."""
    figs: list[tuple[Any, str]] = []
    h = res.micro_history_run0
    t = h["time"]
    fig, ax = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    sw = np.sqrt(h["P"][:, 0, 0])
    ax[0].plot(t, h["speed"], ".", ms=1.5, color="0.6", label="measured speed")
    ax[0].plot(t, h["x"][:, 0], color="C0", label="EKF mean")
    ax[0].fill_between(t, h["x"][:, 0] - 1.96 * sw, h["x"][:, 0] + 1.96 * sw, color="C0",
                       alpha=0.3, label="95 % bounds")
    ax[0].set_ylabel("w [rad/s]")
    ax[0].legend()
    sc = np.sqrt(h["P"][:, 1, 1])
    ax[1].plot(t, h["x"][:, 1], color="C1", label="EKF mean")
    ax[1].fill_between(t, h["x"][:, 1] - 1.96 * sc, h["x"][:, 1] + 1.96 * sc, color="C1",
                       alpha=0.3, label="95 % bounds")
    ax[1].axhline(h["true_c"], color="k", ls="--", label="true c")
    mid = h["true_c"]
    ax[1].set_ylim(mid - 2e-5, mid + 2e-5)
    ax[1].set_ylabel("c [N m s]")
    ax[1].set_xlabel("t [s]")
    ax[1].legend()
    ax[0].set_title(f"Micro EKF, cycle {h['cycle']} of run 0 (seed Fig. 8)")
    figs.append((fig, "fig08_micro_cycle.png"))
    return figs


def _fig09_damping(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Fig. 9: damping over cycles."""
    lin = res.scenarios["linear"]
    figs: list[tuple[Any, str]] = []
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.errorbar(lin.cycles, lin.z[0], yerr=1.96 * np.sqrt(lin.r[0]), fmt="o", ms=3,
                label="micro EKF estimate (95 %)")
    ax.plot(lin.cycles, lin.damping[0], "k.", ms=3, label="true c of the cycle")
    ax.plot(lin.cycles, lin.trend, "k--", lw=1, label="true trend")
    ax.axhline(res.c_fail, color="r", ls=":", label="c_fail")
    ax.set_xlabel("cycle")
    ax.set_ylabel("c [N m s]")
    ax.set_title("Damping over cycles, run 0 (seed Fig. 9)")
    ax.legend()
    figs.append((fig, "fig09_damping_over_cycles.png"))
    return figs


def _fig10_curves(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Fig. 10: characteristic curves every 5 cycles."""
    cfg = res.config
    consts = cfg.life.consts
    lin = res.scenarios["linear"]
    lt0 = res.life_run0
    figs: list[tuple[Any, str]] = []
    fig, ax = plt.subplots(figsize=(7, 4.5))
    cyc = np.arange(0, cfg.life.n_cycles, 5)
    cmap = plt.get_cmap("viridis")
    for j, k in enumerate(cyc):
        col = cmap(j / max(1, len(cyc) - 1))
        ax.plot(lt0.speed[k], 1e3 * consts.J * lt0.acceleration[k], ",", color=col, alpha=0.3)
        w_model = pullup_speed_exact(lt0.time, lin.z[0, k], consts)
        tq = consts.K * consts.current(lt0.time) - consts.T_L - lin.z[0, k] * w_model
        ax.plot(w_model, 1e3 * tq, color=col, lw=1.2, label=f"cycle {k + 1}")
    ax.plot([300], [16], "r*", ms=12, label="design point")
    ax.axvline(300, color="r", ls=":", lw=0.8)
    ax.axhline(16, color="r", ls=":", lw=0.8)
    ax.set_xlabel("w [rad/s]")
    ax.set_ylabel("T_out = J dw/dt [mN m]")
    ax.set_ylim(0, 130)
    ax.set_title("Characteristic curves (dots: measured; lines: with micro-EKF c) (Fig. 10)")
    ax.legend(fontsize=7, ncol=2)
    figs.append((fig, "fig10_characteristic_curves.png"))
    return figs


def _fig11_12_curve_slope(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Figs. 11-12: curve slope over cycles and vs damping."""
    lin = res.scenarios["linear"]
    figs: list[tuple[Any, str]] = []
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(lin.cycles, 1e3 * res.curve_slopes_run0, "o", ms=3)
    ax[0].axhline(-1e3 * res.c_fail, color="r", ls=":", label="-c_fail")
    ax[0].set_xlabel("cycle")
    ax[0].set_ylabel("slope dT_out/dw [mN m s/rad]")
    ax[0].legend()
    ax[0].set_title("Curve slope (steady part, t >= 10 s) (Fig. 11)")
    ax[1].plot(lin.z[0], -res.curve_slopes_run0, "o", ms=3, label="run 0 cycles")
    lim = np.array([0, 1.6e-4])
    ax[1].plot(lim, lim, "k--", lw=1, label="identity")
    ax[1].axvline(res.c_fail, color="r", ls=":", label="c_fail")
    ax[1].set_xlabel("micro-EKF c [N m s]")
    ax[1].set_ylabel("-slope [N m s/rad]")
    ax[1].legend()
    ax[1].set_title("Slope vs damping (Fig. 12)")
    figs.append((fig, "fig11_12_curve_slope.png"))
    return figs


def _fig13_15_predictions(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Figs. 13-15: predictions from given cycles."""
    cfg = res.config
    lin = res.scenarios["linear"]
    figs: list[tuple[Any, str]] = []
    pcs = [n for n in cfg.prediction_cycles if n <= cfg.life.n_cycles]
    fig, axs = plt.subplots(1, len(pcs), figsize=(5 * len(pcs), 4), squeeze=False)
    for ax, n in zip(axs[0], pcs, strict=True):
        kn = int(np.flatnonzero(lin.cycles == n)[0])
        x = lin.track.x[kn, :1]
        P = lin.track.P[kn, :1]
        m = np.arange(0.0, 60.0)
        mu, v = predicted_damping(x, P, m, lin.track.q_a[kn, :1])
        sd = np.sqrt(v[0])
        ax.plot(lin.cycles[: kn + 1], lin.z[0, : kn + 1], "o", ms=3, label="micro estimates")
        ax.plot(n + m, mu[0], "b", label="macro EKF prediction")
        ax.plot(n + m, mu[0] + 1.645 * sd, "g", lw=1, label="90 % band")
        ax.plot(n + m, mu[0] - 1.645 * sd, "g", lw=1)
        ax.plot(lin.cycles, lin.trend, "k--", lw=1, label="true trend")
        ax.axhline(res.c_fail, color="r", ls=":", label="c_fail")
        ax.set_xlabel("cycle")
        ax.set_ylabel("c [N m s]")
        ax.set_ylim(0, 2.2e-4)
        ax.set_title(f"Prediction from cycle {n}")
        ax.legend(fontsize=7)
    figs.append((fig, "fig13_15_predictions.png"))
    return figs


def _fig16_slope(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Fig. 16: slope."""
    cfg = res.config
    lin = res.scenarios["linear"]
    figs: list[tuple[Any, str]] = []
    fig, ax = plt.subplots(figsize=(7, 4))
    a = lin.track.x[:, 0, 1]
    sa = np.sqrt(lin.track.P[:, 0, 1, 1])
    ax.plot(lin.cycles, a, "b", label="run 0 estimate")
    ax.fill_between(lin.cycles, a - 1.96 * sa, a + 1.96 * sa, alpha=0.3, label="95 %")
    ax.plot(lin.cycles, lin.track.x[:, :, 1].mean(axis=1), "C1", lw=1, label="mean over runs")
    ax.axhline(cfg.life.slope, color="k", ls="--", label="true slope")
    ax.set_ylim(-2e-6, 6e-6)
    ax.set_xlabel("cycle")
    ax.set_ylabel("a [N m s / cycle]")
    ax.set_title("Slope of the degradation model (Fig. 16)")
    ax.legend()
    figs.append((fig, "fig16_slope.png"))
    return figs


def _fig17_rul(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Fig. 17: RUL vs cycle."""
    lin = res.scenarios["linear"]
    figs: list[tuple[Any, str]] = []
    fig, ax = plt.subplots(figsize=(7, 4.5))
    _rul_panel(ax, lin, "RUL vs cycle, run 0 (seed Fig. 17)")
    figs.append((fig, "fig17_rul.png"))

    fig, axs = plt.subplots(1, 2, figsize=(11, 4.5))
    _rul_panel(axs[0], res.scenarios["accelerating"], "Accelerating c, linear macro (q_a = 0)")
    _rul_panel(axs[1], res.scenarios["accelerating-qa-ml"],
               "Accelerating c, random-walk slope (q_a by max. likelihood)")
    figs.append((fig, "fig_accelerating_rul.png"))
    return figs


def _fig_macro_models(res: MotorDampingResult, plt: Any) -> list[tuple[Any, str]]:
    """Linear vs quadratic macro law on both truths (run 0)."""
    cfg = res.config
    figs: list[tuple[Any, str]] = []
    fig, axs = plt.subplots(2, 2, figsize=(11, 8.5))
    for i, truth in enumerate(("linear", "accelerating")):
        for j, model in enumerate(("linear", "quadratic")):
            name = truth if cfg.macro.model == model else f"{truth}-{model}-macro"
            if name in res.scenarios:
                _rul_panel(axs[i, j], res.scenarios[name],
                           f"{truth.capitalize()} c, {model} macro law (run 0)")
    figs.append((fig, "fig_macro_models_rul.png"))
    return figs


def _rul_panel(ax: Any, sres: Any, title: str) -> None:
    """RUL of run 0 against the truth: covariance median and bounds, Monte Carlo bounds."""
    pc = sres.pred_cycles
    tr = sres.rul_true[0]
    ax.plot(pc, tr, "k", label="true RUL")
    ax.fill_between(pc, (1 - 0.2) * tr, (1 + 0.2) * tr, color="0.85", label="alpha = 0.2")
    ax.plot(pc, sres.cov_q[0, :, 1], "b", label="median (covariance)")
    ax.plot(pc, sres.cov_q[0, :, 0], "r", lw=1, label="90 % bounds (covariance)")
    ax.plot(pc, sres.cov_q[0, :, 2], "r", lw=1)
    ax.plot(pc, sres.mc_q[0, :, 0], "m:", lw=1, label="90 % bounds (Monte Carlo)")
    ax.plot(pc, sres.mc_q[0, :, 2], "m:", lw=1)
    top = np.nanmax(tr) * 1.8
    ax.set_ylim(0, top)
    ax.set_xlabel("cycle")
    ax.set_ylabel("RUL [cycles]")
    ax.set_title(title)
    ax.legend(fontsize=7)
