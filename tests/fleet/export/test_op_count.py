"""The operation counter: hand-counted C lines, and the steady-state count of the tracker chain
against the operations of docs/systems/embedded-rul.md (EI-8) to (EI-10) counted by hand."""

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
