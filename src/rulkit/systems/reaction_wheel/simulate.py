"""Simulated wheel telemetry with known truth (docs/systems/reaction-wheel.md §1, §3): the wheel
run by the compiled RK4 of :mod:`rulkit.systems.reaction_wheel.wheel_kernels` along any
temperature and command path, for any wheel, in the file format of
:mod:`rulkit.systems.reaction_wheel.telemetry`, and the corruptions a real record carries
(spikes in any channel, dropouts, stuck sensors, time gaps, a shifted time origin).

Used to test and benchmark the estimators on records the tests make (the paths of a battery,
three months at 20 Hz); the truth rides along as the column ``T_lub_C``.

Example::

    t = np.arange(0, 600, 0.05)
    df = simulate_telemetry(30 + 0.01 * t, np.full(t.size, 2.0), np.random.default_rng(0))
    bad = corrupt(df, "spike_speed", np.random.default_rng(1), events=3)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.telemetry import COLUMNS, CURRENT, SPEED, TIME, VOLT
from rulkit.systems.reaction_wheel.wheel import NOISE_LEVELS, IthacoParams, ReactionWheel
from rulkit.systems.reaction_wheel.wheel_kernels import pack_params, simulate_states

FloatArray = np.ndarray

#: The corruptions :func:`corrupt` makes.
CORRUPTIONS = ("spike_speed", "spike_current", "spike_command", "dropout", "stuck", "gap",
               "shift")
#: The time origin of ``corrupt(df, "shift")``: epoch seconds of late 2023.
SHIFT_S = 1.7e9


def simulate_telemetry(
    T: FloatArray, V: FloatArray, rng: np.random.Generator, *,
    params: IthacoParams | None = None, sigma: tuple[float, float] = NOISE_LEVELS["low"],
    dt: float = 0.05, t0: float = 0.0, initial: str = "equilibrium",
) -> Any:
    """A telemetry frame (columns :data:`rulkit.systems.reaction_wheel.telemetry.COLUMNS` plus
    the true ``T_lub_C``) of the wheel ``params`` driven by ``V`` (K,) volts at the lubricant
    temperature ``T`` (K,) deg C, sampled every ``dt`` s from ``t0`` (the torque disturbance
    runs on the time since ``t0``). ``initial``: "equilibrium" (the steady state of ``V[0]``,
    ``T[0]``) or "rest". Measurement noise ``sigma = (sigma_w, sigma_I)`` from ``rng``."""
    import pandas as pd

    T = np.ascontiguousarray(T, dtype=np.float64)
    V = np.ascontiguousarray(V, dtype=np.float64)
    if T.shape != V.shape or T.ndim != 1 or T.size < 2:
        raise ValueError(f"T and V: expected equal shapes (K >= 2,), got {T.shape}, {V.shape}")
    p = params or IthacoParams()
    if initial == "equilibrium":
        x0 = ReactionWheel(p).steady_state(float(V[0]), float(T[0]))
    elif initial == "rest":
        x0 = np.zeros(2)
    else:
        raise ValueError(f"initial: expected 'equilibrium' or 'rest', got {initial!r}")
    x = simulate_states(np.asarray(x0, dtype=np.float64), V, T, 0.0, float(dt), pack_params(p))
    noise = rng.standard_normal((T.size, 2)) * np.asarray(sigma, dtype=np.float64)
    t = t0 + dt * np.arange(T.size)
    return pd.DataFrame({TIME: t, VOLT: V, SPEED: x[:, 1] + noise[:, 0],
                         CURRENT: x[:, 0] + noise[:, 1], "T_lub_C": T})


def corrupt(df: Any, kind: str, rng: np.random.Generator, *, events: int = 3,
            keep_s: float = 10.0) -> Any:
    """A copy of telemetry ``df`` with ``events`` corruptions of ``kind`` (one of
    :data:`CORRUPTIONS`) at random rows after the first ``keep_s`` seconds:

    - ``spike_speed`` / ``spike_current`` / ``spike_command``: one sample off by 1-50 rad/s,
      0.3-2 A or 0.5-2 V (either sign);
    - ``dropout``: 1-20 consecutive empty (NaN) cells in a random channel;
    - ``stuck``: a random channel repeats one value for 2-30 s;
    - ``gap``: 1-60 s of rows missing;
    - ``shift``: the time origin moved to :data:`SHIFT_S` (``events`` ignored).
    """
    if kind not in CORRUPTIONS:
        raise ValueError(f"kind: expected one of {CORRUPTIONS}, got {kind!r}")
    out = df.copy()
    if kind == "shift":
        out[TIME] = out[TIME] + SHIFT_S
        return out
    t = out[TIME].to_numpy()
    dt = float(t[1] - t[0])
    first = int(np.searchsorted(t, t[0] + keep_s))
    rows = np.sort(rng.integers(first, len(out) - 1, size=events))
    sign = rng.choice([-1.0, 1.0], size=events)
    drop: list[np.ndarray] = []
    for i, r in enumerate(rows):
        if kind.startswith("spike_"):
            col, lo, hi = {"spike_speed": (SPEED, 1.0, 50.0),
                           "spike_current": (CURRENT, 0.3, 2.0),
                           "spike_command": (VOLT, 0.5, 2.0)}[kind]
            out.iloc[r, out.columns.get_loc(col)] += sign[i] * rng.uniform(lo, hi)
        elif kind == "dropout":
            col = rng.choice([SPEED, CURRENT, VOLT])
            n = int(rng.integers(1, 21))
            out.iloc[r:r + n, out.columns.get_loc(col)] = np.nan
        elif kind == "stuck":
            col = rng.choice([SPEED, CURRENT])
            n = round(rng.uniform(2.0, 30.0) / dt)
            j = out.columns.get_loc(col)
            out.iloc[r:r + n, j] = out.iloc[r, j]
        else:  # gap
            n = round(rng.uniform(1.0, 60.0) / dt)
            drop.append(np.arange(r, min(r + n, len(out) - 1)))
    if drop:
        out = out.drop(index=out.index[np.unique(np.concatenate(drop))])
    return out.reset_index(drop=True)


def telemetry_columns(df: Any) -> Any:
    """The telemetry columns of a simulated frame (without the truth)."""
    return df[list(COLUMNS)]


def simulate_record(out_dir: str | Path, days: float, rng: np.random.Generator, *,
                    scenario: int = 1, v_comm: float = 2.0, file_days: float = 1.0,
                    t0: float = 1.7e9, dt: float = 0.05, loss_noise_rel: float = 0.01,
                    sigma: tuple[float, float] = NOISE_LEVELS["low"],
                    params: IthacoParams | None = None) -> dict[str, Any]:
    """A wheel directory for ``rulkit rw pipeline`` with known truth: ``telemetry/`` holds
    ``days`` of telemetry at ``dt`` in Parquet files of ``file_days`` each (epoch-second times
    from ``t0``), the wheel at ``v_comm`` along the temperature path of fault ``scenario``
    (docs/systems/reaction-wheel.md §4), simulated file by file (memory: one file);
    ``losses.csv`` the loss of every 4-minute window (the true increments plus noise of
    ``loss_noise_rel`` of the healthy window loss); ``params`` the wheel (default the seed's).
    Returns the truth: the path, the scenario,
    the loss noise, the files and their rows."""
    import pandas as pd

    from rulkit.systems.reaction_wheel.lubrication import (
        PATHS,
        SCENARIOS,
        WINDOW_S,
        LubricationSetup,
        true_window_increments,
    )

    out = Path(out_dir)
    (out / "telemetry").mkdir(parents=True, exist_ok=True)
    path, p = PATHS[scenario], params or IthacoParams()
    P = pack_params(p)
    n_total = round(days * 86400.0 / dt)
    per_file = round(file_days * 86400.0 / dt)
    x0 = np.asarray(ReactionWheel(p).steady_state(v_comm, float(path(0.0))), dtype=np.float64)
    files = []
    for i, a in enumerate(range(0, n_total, per_file)):
        k = np.arange(a, min(a + per_file, n_total) + 1)  # one extra: the next file's start
        t_rel = k * dt
        T = np.asarray(path(t_rel.astype(np.float64)), dtype=np.float64)
        x = simulate_states(x0, np.full(k.size, v_comm), T, t_rel[0], dt, P)
        x0 = x[-1].copy()
        n = k.size - 1
        noise = rng.standard_normal((n, 2)) * np.asarray(sigma)
        f = out / "telemetry" / f"day{i:03d}.parquet"
        pd.DataFrame({TIME: t0 + t_rel[:n], VOLT: np.full(n, v_comm),
                      SPEED: x[:n, 1] + noise[:, 0], CURRENT: x[:n, 0] + noise[:, 1]}
                     ).to_parquet(f, index=False)
        files.append(f)
    W = int(n_total * dt // WINDOW_S)
    y_true = true_window_increments(path, SCENARIOS[scenario], W)
    sigma_y = LubricationSetup(scenario, noise_rel=loss_noise_rel, path=path).sigma_y
    y = y_true + sigma_y * rng.standard_normal(W)
    pd.DataFrame({TIME: t0 + (np.arange(W) + 1) * WINDOW_S, "loss_mL": y}).to_csv(
        out / "losses.csv", index=False)
    return {"path": path, "scenario": SCENARIOS[scenario], "sigma_y": sigma_y,
            "files": files, "rows": n_total, "y_true": y_true, "t0": t0}
