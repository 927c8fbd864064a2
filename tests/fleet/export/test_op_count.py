"""The operation counter: hand-counted C lines, and the steady-state count of the tracker chain
against the operations of docs/systems/embedded-rul.md (EI-8) to (EI-10) counted by hand."""

import pytest

from rulkit.fleet.export.device_spec import DeviceSpec
from rulkit.fleet.export.op_count import line_operations, steady_state_operations
from rulkit.fleet.tracking.tracker_chain import TrackerConfig


def test_lines_counted_by_hand():
    types = {"rk_state"}
    assert line_operations("    double xp = s->fhi + s->dhi * dt;", types) == {"mul": 1, "add": 1}
    assert line_operations("    return -h * log(h) / dhi;  /* a * b */", types) == {
        "neg": 1, "mul": 1, "log": 1, "div": 1}
    assert line_operations("static void f(const rk_state *s, double *out)", types) == {}
    assert line_operations("    *fhi = x1 - (a - -b);", types) == {"add": 2, "neg": 1}
    assert line_operations("    y += (ci[i] - OFF[i]) * S[i][j];", types) == {"add": 2,
                                                                                 "mul": 1}
    assert line_operations("    if (x < lo && fabsf(v) >= 2.0f) {", types) == {
        "cmp": 2, "other_math": 1}


def test_tracker_chain_counts_match_the_equations(cc, tmp_path):
    ops = steady_state_operations(DeviceSpec("a", "t", TrackerConfig()), tmp_path, "double",
                                  n=500)
    # (EI-8): fHI += dHI dt; r = HI - fHI; fHI += alpha1 r; dHI += beta1 r / dt
    assert (ops["track_hi"]["mul"], ops["track_hi"]["div"], ops["track_hi"]["add"]) == (3, 1, 4)
    # (EI-9): RUL = -fHI ln(fHI) / dHI
    assert ops["paris_rul"] == {"mul": 1, "div": 1, "add": 0, "neg": 1, "cmp": 0, "log": 1,
                                "other_math": 0}
    # (EI-10) with adt = d2RUL dt and rdt = r / dt shared: 6 mul, 2 div, 7 add
    assert (ops["track_rul"]["mul"], ops["track_rul"]["div"], ops["track_rul"]["add"]) == (
        6, 2, 7)
    assert ops["total"]["log"] == 3  # RUL and its two confidence limits


def test_hi_noise_update_counts_match_eq_8_by_hand(cc, tmp_path):
    """paris-mixed: the iterated update of eq. (8) counted by hand per Gauss-Newton iteration
    (n of them per update, at most IEKF_ITERATIONS) and for the prediction and final step."""
    from rulkit.fleet.learned.growth_filter import IEKF_ITERATIONS
    from rulkit.fleet.learned.hi_noise import HiNoiseModel

    model = HiNoiseModel(noise="mixed", shape=-0.25, mean=(-2.4, 2.5), cov=(1e-4, -5e-3, 0.3),
                         hi_noise_sd=0.01, log_noise_sd=0.04, walk_sd=0.07, time_scale=300.0)
    spec = DeviceSpec("a", "t", TrackerConfig(), None, model)
    ops = steady_state_operations(spec, tmp_path, "double", n=200)
    inv = ops["growth_inverse"]  # g^-1 and dhi/dz: 1 + lam z, its pow and h / base
    n = inv["other_math"] - 1.0  # once per iteration and once for the final step
    assert 1.0 <= n <= IEKF_ITERATIONS
    assert (inv["mul"], inv["div"], inv["add"]) == pytest.approx((n + 1,) * 3)
    # z_i, g^-1's and each step's in the update (2 n + 2 calls); the RUL's first-step bound
    # g(H) adds as many calls as its search evaluates there
    assert ops["clip_z"]["cmp"] >= 2 * (2 * n + 2) - 1e-9
    upd = ops["learned_update"]
    # prediction: 7 mul, 2 div, 6 add; final step: S (4 mul, 2 add), nu (1, 3), gains (2 mul,
    # 2 div), means and covariances (8 mul, 5 add); an iteration: S, nu, the step (2 mul,
    # 1 div, 1 add), its convergence test (1 mul, 2 add)
    assert (upd["mul"], upd["div"], upd["add"]) == pytest.approx(
        (22 + 8 * n, 4 + n, 16 + 8 * n))
