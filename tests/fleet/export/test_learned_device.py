"""Which learned models the device runs, the refusal of the others by name, and the HI-noise
variants compiled and run beside their Python models."""

import dataclasses
import re
import struct

import numpy as np
import pandas as pd
import pytest

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError
from rulkit.fleet.export.generator import generate_c, template_context
from rulkit.fleet.export.learned_device import EXPORTERS, learned_device
from rulkit.fleet.export.verify import (
    ERROR_BOUNDS,
    LEARNED_COLUMNS,
    build,
    python_reference,
    relative_error,
    scaled_error,
    segments,
)
from rulkit.fleet.learned.datasets import GOAL_FLEETS, goal_fleet
from rulkit.fleet.learned.degradation import KINDS, DegradationModel
from rulkit.fleet.learned.hi_noise import NOISES, HiNoiseModel, fit_hi_noise
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.tracking.tracker_settings import fit_tracker_config


@pytest.mark.parametrize("kind", KINDS)
def test_every_learned_kind_is_exported_or_refused_by_name(kind):
    if kind not in EXPORTERS:
        with pytest.raises(ExportError, match=repr(kind)):
            learned_device(type("Model", (), {"kind": kind})())  # type: ignore[arg-type]
        return
    model = DegradationModel(kind, -0.5 if kind == "paris" else 0.0, (-1.0, 0.5),
                             (0.1, 0.0, 0.1), 0.02, 0.01, 10.0)
    dev = learned_device(model)
    assert dev.kind == kind and dev.state_fields
    assert dev.constants["threshold"] == model.threshold


def test_unknown_learned_model_type_is_refused_by_name():
    class Similarity:
        kind = "similarity"

    with pytest.raises(ExportError, match="'similarity' has no C export"):
        learned_device(Similarity())  # type: ignore[arg-type]


def test_a_model_setting_the_template_does_not_implement_is_refused():

    @dataclasses.dataclass(frozen=True)
    class Extended(DegradationModel):
        noise_scale: str = "transformed"

    base = dict(kind="linear", shape=0.0, mean=(0.1, 0.5), cov=(0.1, 0.0, 0.1),
                noise_sd=0.02, walk_sd=0.0, time_scale=10.0)
    assert learned_device(Extended(**base)).kind == "linear"  # default: the known model
    with pytest.raises(ExportError, match="noise_scale = 'hi' has no C export"):
        learned_device(Extended(**base, noise_scale="hi"))


# ---------------------------------------------------------------- the HI-noise variants in C
# Tolerances of the double build against Python. The posterior: 1e-12 of each field's range
# (the C runs the IEKF of filter_kernels.assimilate operation by operation; the same glibc
# pow/exp, so only the compiler's and numba's choices of instructions could differ). The RUL
# quantiles of eq. (5b): 1e-6 relative. The C runs the server's search (the same table, the
# same bracketing steps, stopping where two trials 1e-12 u apart straddle the root): measured
# within 4e-12 relative; the bound leaves room for a server search that stops earlier (within
# 1e-6 of a bisection). With one_measurement the C solves eq. (6), a quadratic whose
# discriminant cancels to ~eps of its terms where the level's normal quantile is near 0 (the
# median of a unit far from failure): ~sqrt(eps) = 1.5e-8 relative rounding times the spread
# of the terms, up to 3.8e-7 on these fleets, against Python's search of eq. (5).
POSTERIOR_TOL = 1e-12
QUANTILE_RTOL = 1e-6


def _with_a_unit_that_never_fails(frame):
    """``frame`` and one more unit whose HI stays at 0.1 (noise sd 0.005, 60 acquisitions a
    cadence of 5 apart): its rate's posterior straddles 0, so its median and 95 % quantile lie
    in the never-failing mass (+inf)."""
    rng = np.random.default_rng(5)
    t = 5.0 * np.arange(1, 61)
    flat = pd.DataFrame({"component": "flat", "time": t,
                         "hi": 0.1 + 0.005 * rng.standard_normal(t.size)})
    return pd.concat([frame, flat], ignore_index=True)


@pytest.fixture(scope="module")
def noise_fits():
    """Each variant fitted on a small fleet of its own noise kind (datasets.GOAL_FLEETS'
    settings; the shape fixed at the generator's m skips the profile-likelihood grid: the
    export does not care how the model was fitted). m = 2 gives the log form."""
    out = {}
    for noise in NOISES:
        frame, _ = goal_fleet(noise, np.random.default_rng(11), 8)
        hist = histories_from_frame(frame, "test")
        model = fit_hi_noise(hist, noise, shape=1.0 - float(GOAL_FLEETS[noise]["m"]) / 2.0)
        out[noise] = (DeviceSpec("g", "test", fit_tracker_config(hist), None, model),
                      _with_a_unit_that_never_fails(frame))
    return out


def _saved_posterior(lib, spec, t, hi):
    """(m_z, m_b, p_zz, p_zb, p_bb) of one component's saved state after ``t``, ``hi``."""
    ctx = template_context(spec, "double", "rk")
    layout = {f["name"]: f["offset"] for f in ctx["fields"]}
    status, saved = lib.state_bytes(t, hi, int(ctx["state_bytes"]))
    assert status == 0
    return [struct.unpack_from("<d", saved, layout[f])[0] for f in STATE_NAMES]


def _posterior_errors(lib, spec, frame, n_units=2):
    """scaled_error of each posterior field of the C (read from its saved state after every
    acquisition of the first ``n_units`` units) against the model's replay."""
    start, df = segments(frame)
    ref = spec.learned.replay(histories_from_frame(df, "test"))
    rows = np.arange(start[n_units])
    got = np.empty((rows.size, 5))
    for k in rows:
        u = np.searchsorted(start, k, side="right") - 1
        got[k] = _saved_posterior(lib, spec, df["time"].to_numpy()[start[u]:k + 1],
                                  df["hi"].to_numpy()[start[u]:k + 1])
    want = np.column_stack([ref.m[rows], ref.p[rows]])
    return {f: scaled_error(got[:, j], want[:, j]) for j, f in enumerate(STATE_NAMES)}


def _quantile_errors(lib, spec, frame):
    start, df = segments(frame)
    got = lib.run(start, df["time"], df["hi"], through_bytes=True)
    assert (got["status"] == 0).all()
    ref = python_reference(spec, start, df["time"].to_numpy(), df["hi"].to_numpy())
    return {c: float(relative_error(got[c], ref[c]).max()) for c in LEARNED_COLUMNS}, ref


STATE_NAMES = ("m_z", "m_b", "p_zz", "p_zb", "p_bb")


@pytest.mark.parametrize("noise", NOISES)
def test_hi_noise_variant_in_c_equals_its_python_model(cc, tmp_path, noise_fits, noise):
    spec, frame = noise_fits[noise]
    assert learned_device(spec.learned).kind == f"paris-{noise}"
    lib = build(spec, tmp_path / noise)
    for field, err in _posterior_errors(lib, spec, frame).items():
        assert err <= POSTERIOR_TOL, field
    errors, ref = _quantile_errors(lib, spec, frame)
    assert max(errors.values()) <= QUANTILE_RTOL, errors
    finite = np.isfinite(ref["rul_median"]) & (ref["rul_median"] > 0)
    assert finite.mean() > 0.8  # the comparison covers real quantiles, not 0 / inf only
    # ... and every other branch of eq. (5b)'s quantiles
    rows = _event_rows(spec, frame)
    assert rows["first cadence step"] >= 3 and rows["one reading"] >= 8
    assert np.sum(ref["rul_median"] == 0) >= 5  # failed units
    assert np.sum(np.isinf(ref["rul_median"])) >= 20 and np.sum(np.isinf(ref["rul_p95"])) >= 40


def _event_rows(spec, frame):
    """How many rows' 5 % quantile lies within the first cadence step (at most the first
    reading's probability F(d), eq. (5b)'s special case) and how many rows have one reading
    (no cadence yet: eq. (5) of one measurement)."""
    from rulkit.fleet.learned.degradation import rul_cdf

    _, df = segments(frame)
    st = spec.learned.replay(histories_from_frame(df, "test"))
    cadence = np.where(st.n >= 2, st.t / np.maximum(st.n, 1), 0.0)
    first = rul_cdf(spec.learned, st, cadence[:, None])[:, 0]
    return {"first cadence step": int(np.sum((first >= 0.05) & (st.hi < 1) & (st.n >= 2))),
            "one reading": int(np.sum(st.n == 1))}


MUTATIONS = {
    # one Gauss-Newton step instead of the iterations: the plain EKF
    "EKF instead of IEKF": (r"k < 8;", "k < 1;"),
    # eq. (5b) without its first cadence step (the interpolation from the last reading): only
    # the quantiles move
    "no first step": (r"isfinite\(delta\) && w < delta", "0"),
    # the table's step of log c 1e-3 relative off: mu*, sigma* read at the wrong rise
    "table grid": (r"L_DLOG_C = ([^;]+);", 1e-3),
    # the additive noise variance 1e-6 relative off: the posterior moves
    "L_R_HI": (r"L_R_HI = ([^;]+);", 1e-6),
    # the measurement variance at hi = 1, 1e-4 relative off: only the quantiles move
    "L_MEASURED_VAR": (r"L_MEASURED_VAR = ([^;]+);", 1e-4),
}


@pytest.mark.parametrize("mutation", sorted(MUTATIONS))
def test_the_comparison_fails_when_the_c_is_wrong(cc, tmp_path, noise_fits, monkeypatch,
                                                  mutation):
    import rulkit.fleet.export.verify as verify

    pattern, change = MUTATIONS[mutation]
    spec, frame = noise_fits["mixed"]

    def mutated(*args, **kwargs):
        files = generate_c(*args, **kwargs)
        text = files["rk.c"]
        if isinstance(change, str):
            new = re.sub(pattern, change, text)
        else:
            new = re.sub(pattern, lambda m: m.group(0).replace(
                m.group(1), repr(float(m.group(1)) * (1.0 + change))), text)
        assert new != text
        return {**files, "rk.c": new}

    monkeypatch.setattr(verify, "generate_c", mutated)
    lib = build(spec, tmp_path / "mutant")
    posterior = max(_posterior_errors(lib, spec, frame).values())
    quantiles = max(_quantile_errors(lib, spec, frame)[0].values())
    if mutation in ("L_MEASURED_VAR", "no first step", "table grid"):
        assert posterior <= POSTERIOR_TOL and quantiles > 10 * QUANTILE_RTOL
    else:
        assert posterior > 10 * POSTERIOR_TOL


def test_first_passage_quantiles_against_root_finding_of_the_cdf(cc, tmp_path, noise_fits):
    """The C's RUL quantiles of eq. (5b) against scipy's brentq on the server's CDF
    (degradation.rul_cdf, evaluated in numpy, not by the compiled search the server's
    quantiles use), mid-life and where the first cadence step holds the median."""
    from scipy.optimize import brentq

    from rulkit.fleet.learned.degradation import rul_cdf

    spec, frame = noise_fits["mixed"]
    lib = build(spec, tmp_path / "c")
    start, df = segments(frame)
    t, hi = df["time"].to_numpy(), df["hi"].to_numpy()
    states = spec.learned.replay(histories_from_frame(df, "test"))
    cadence = np.where(states.n >= 2, states.t / np.maximum(states.n, 1), 0.0)
    first = rul_cdf(spec.learned, states, cadence[:, None])[:, 0]
    late = int(np.flatnonzero((first >= 0.5) & (states.hi < 1))[0])
    mid = start[0] + (start[1] - start[0]) // 2
    for k in (mid, late):
        s0 = start[np.searchsorted(start, k, side="right") - 1]  # the unit's first row
        out = lib.run(np.array([0, k + 1 - s0]), t[s0:k + 1], hi[s0:k + 1])
        state = states.take(np.array([k]))
        for level, col in zip((0.5, 0.05, 0.95), LEARNED_COLUMNS, strict=True):
            def excess(r, lv=level, st=state):
                return rul_cdf(spec.learned, st, np.array([[r]]))[0, 0] - lv

            r = brentq(excess, 0.0, 50.0 * spec.learned.time_scale, xtol=1e-12, rtol=1e-13)
            assert out[col][-1] == pytest.approx(r, rel=QUANTILE_RTOL), (k, level)
    assert first[late] >= 0.5 and first[mid] < 0.05


def test_one_measurement_quantiles_against_root_finding_and_monte_carlo(cc, tmp_path,
                                                                      noise_fits):
    """``one_measurement``: one state's RUL quantiles from the C against eq. (5) solved by
    scipy's brentq on the survival ratio, and against a Monte Carlo of the model's predictive
    law: (z, b) from the posterior, the walk and the measurement noise at the threshold drawn,
    the event z + e >= 0."""
    from scipy.optimize import brentq
    from scipy.stats import norm

    spec, frame = noise_fits["mixed"]
    spec = dataclasses.replace(spec, one_measurement=True)
    model = spec.learned
    lib = build(spec, tmp_path / "c")
    start, df = segments(frame)
    k = start[0] + (start[1] - start[0]) // 2  # mid-life of the first unit
    out = lib.run(np.array([0, k + 1 - start[0]]), df["time"][start[0]:k + 1],
                  df["hi"][start[0]:k + 1])
    mz, mb, pzz, pzb, pbb = _saved_posterior(lib, spec, df["time"].to_numpy()[:k + 1],
                                             df["hi"].to_numpy()[:k + 1])
    q, r, tau = model.walk_sd**2, model.measured_var, model.time_scale

    def log_surv(w):
        var = pzz + r + 2 * w * pzb + w * w * pbb + q * w
        return norm.logcdf(-(mz + mb * w) / np.sqrt(var))

    c_quantiles = [out[c][-1] for c in LEARNED_COLUMNS]
    for level, got in zip((0.5, 0.05, 0.95), c_quantiles, strict=True):
        w = brentq(lambda w, lv=level: log_surv(w) - log_surv(0.0) - np.log1p(-lv), 0.0, 50.0,
                   xtol=1e-14, rtol=1e-14)
        assert got == pytest.approx(w * tau, rel=QUANTILE_RTOL)
    rng = np.random.default_rng(2)
    n = 100_000
    ab = rng.multivariate_normal([mz, mb], [[pzz, pzb], [pzb, pbb]], size=n)
    surv0 = np.mean(ab[:, 0] + np.sqrt(r) * rng.standard_normal(n) < 0)
    for level, got in zip((0.5, 0.05, 0.95), c_quantiles, strict=True):
        w = got / tau
        level_w = ab[:, 0] + ab[:, 1] * w + np.sqrt(q * w + r) * rng.standard_normal(n)
        cdf = 1.0 - np.mean(level_w < 0) / surv0
        assert abs(cdf - level) < 4.0 * np.sqrt(level * (1 - level) / n) + 1e-3


def test_hi_noise_settings_without_c_are_refused():

    @dataclasses.dataclass(frozen=True)
    class Extended(HiNoiseModel):
        onset_grid: tuple[float, ...] = ()

    base = dict(noise="additive", shape=0.0, mean=(-2.3, 1.5), cov=(0.01, 0.0, 0.2),
                hi_noise_sd=0.02, log_noise_sd=0.0, walk_sd=0.05, time_scale=300.0)
    assert learned_device(Extended(**base)).kind == "paris-additive"
    assert learned_device(HiNoiseModel(**{**base, "walk_sd": 0.0})).kind == "paris-additive-iid"
    with pytest.raises(ExportError, match=r"onset_grid = \(0.0, 0.5\) has no C export"):
        learned_device(Extended(**base, onset_grid=(0.0, 0.5)))
    with pytest.raises(ExportError, match="expected a HiNoiseModel"):
        EXPORTERS["paris-mixed"](DegradationModel("paris", 0.0, (-1.0, 0.5), (0.1, 0.0, 0.1),
                                                  0.02, 0.01, 10.0))


def test_hi_noise_variants_in_float_within_the_float_bounds(cc, tmp_path, noise_fits):
    """The float build (time stamps double, the IEKF in float: its iterations stop at the
    count, float rarely meets the 1e-9 step) within verify.ERROR_BOUNDS['float']."""
    for noise, (spec, frame) in noise_fits.items():
        start, df = segments(frame)
        got = build(spec, tmp_path / noise, "float").run(start, df["time"], df["hi"])
        ref = python_reference(spec, start, df["time"].to_numpy(), df["hi"].to_numpy())
        for col in LEARNED_COLUMNS:
            assert scaled_error(got[col], ref[col]) <= ERROR_BOUNDS["float"][col], (noise, col)


def test_hi_noise_variant_under_the_sanitizers(cc, tmp_path, noise_fits):
    """paris-mixed (pow form) compiled with -fsanitize=undefined,address, equal to the normal
    build on every output."""
    from rulkit.fleet.export.verify import run_sanitized

    spec, frame = noise_fits["mixed"]
    start, df = segments(frame)
    ref = build(spec, tmp_path / "lib").run(start, df["time"], df["hi"])
    got = run_sanitized(spec, tmp_path / "san", start, df["time"], df["hi"])
    for col in ref:
        np.testing.assert_array_equal(got[col], ref[col])
