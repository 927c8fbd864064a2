"""The generated C: what it includes, what it refuses, and its state file (layout, CRC-32,
round trip; foreign, truncated, corrupted, other-version and other-model buffers refused)."""

import re
import struct
import zlib

import numpy as np
import pytest

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError
from rulkit.fleet.export.generator import c_literal, generate_c
from rulkit.fleet.export.verify import build
from rulkit.fleet.learned.degradation import DegradationModel
from rulkit.fleet.tracking.health_index import HealthIndexModel
from rulkit.fleet.tracking.tracker_chain import TrackerConfig

MODEL = DegradationModel("paris", -1.0, (-1.0, 0.8), (0.2, 0.01, 0.05), 0.03, 0.01, 50.0)
HI_MODEL = HealthIndexModel.fit(np.random.default_rng(0).rayleigh(size=(300, 2)))


def _specs():
    cfg = TrackerConfig.safe(hi_sigma=0.02)
    return {"tracker": DeviceSpec("a", "t", cfg), "full": DeviceSpec("a", "t", cfg, HI_MODEL,
                                                                      MODEL)}


@pytest.mark.parametrize("number", ["double", "float", "fixed"])
def test_sources_need_only_math_and_stdint_and_no_heap(number):
    spec = _specs()["tracker" if number == "fixed" else "full"]
    files = generate_c(spec, number, "bearing")
    assert set(files) == {"bearing.h", "bearing.c"}
    for text in files.values():
        includes = set(re.findall(r'#include\s+[<"]([^>"]+)[>"]', text))
        assert includes <= {"math.h", "stdint.h", "bearing.h"}
        for word in ("malloc", "calloc", "realloc", "free(", "printf", "FILE"):
            assert word not in text, word
        # every file-scope variable is a const table
        for line in text.splitlines():
            if re.match(r"static (?!const)[a-z0-9_]+ [A-Za-z_0-9]+\s*(=|;|\[)", line):
                pytest.fail(f"mutable file-scope state: {line}")


def test_fixed_point_refuses_what_it_does_not_cover():
    specs = _specs()
    with pytest.raises(ExportError, match="learned paris model"):
        generate_c(specs["full"], "fixed")
    with pytest.raises(ExportError, match="m = 3"):
        generate_c(DeviceSpec("a", "t", TrackerConfig(paris_exponent=3.0)), "fixed")
    with pytest.raises(ExportError, match="prefix"):
        generate_c(specs["tracker"], "double", "9lives")


def test_literals_read_back_exactly():
    for x in (0.1, 1 / 3, 1e-300, -2.5e17, 12.0):
        assert float(c_literal(x, "double")) == x
    assert c_literal(float("inf"), "double") == "INFINITY"
    assert c_literal(0.5, "float") == "0.5f"


# ---- the state file ---------------------------------------------------------------------
def _acquisitions(n=30):
    t = np.arange(1.0, n + 1)
    return t, np.linspace(0.2, 0.9, n)


_LIBS: dict = {}


@pytest.fixture
def libs(cc, tmp_path_factory):
    if not _LIBS:  # built once per test session
        d = tmp_path_factory.mktemp("state")
        spec = _specs()["tracker"]
        _LIBS.update({n: build(spec, d / n, n) for n in ("double", "float", "fixed")})
    return _LIBS


@pytest.mark.parametrize("number", ["double", "float", "fixed"])
def test_state_file_layout_and_crc(libs, number):
    lib = libs[number]
    t, hi = _acquisitions()
    size = {"double": 88, "float": 56, "fixed": 56}[number]
    rc, buf = lib.state_bytes(t, hi, size)
    assert rc == 0
    assert buf[:4] == b"RKST" and struct.unpack_from("<H", buf, 4)[0] == 1
    assert buf[6] == {"double": 1, "float": 2, "fixed": 3}[number]
    assert struct.unpack_from("<I", buf, 12)[0] == len(t)  # n
    assert struct.unpack_from("<I", buf, size - 4)[0] == zlib.crc32(buf[:size - 4])
    assert lib.crc32(b"123456789") == 0xCBF43926  # the CRC-32 check value
    # the last HI, little-endian at its documented offset
    fmt, width = {"double": ("<d", 8), "float": ("<f", 4), "fixed": ("<i", 4)}[number]
    hi_off = 20 + (4 if number == "fixed" else width)
    last = struct.unpack_from(fmt, buf, hi_off)[0]
    expect = hi[-1] if number != "fixed" else round(hi[-1] * 2**27)
    assert last == pytest.approx(expect, rel=1e-7)


@pytest.mark.parametrize("number", ["double", "float", "fixed"])
def test_restored_state_continues_exactly(libs, number):
    lib = libs[number]
    t, hi = _acquisitions()
    size = {"double": 88, "float": 56, "fixed": 56}[number]
    _, buf = lib.state_bytes(t[:-1], hi[:-1], size)
    rc, after, row = lib.resume(buf, t[-1], hi[-1:])
    assert rc == 0
    straight = lib.run(np.array([0, len(t)]), t, hi)
    np.testing.assert_array_equal(row[:-1], [straight[c][-1] for c in lib.columns[:-1]])
    assert after[:size] == lib.state_bytes(t, hi, size)[1]


def test_bad_buffers_are_refused_with_their_error(libs):
    lib = libs["double"]
    t, hi = _acquisitions()
    _, buf = lib.state_bytes(t, hi, 88)
    e_size, e_foreign, e_crc, e_version, e_model = -5, -6, -7, -8, -9
    assert lib.resume(buf[:87], 31.0, hi[-1:])[0] == e_size  # truncated
    assert lib.resume(b"", 31.0, hi[-1:])[0] == e_size
    assert lib.resume(b"SQLite format 3\x00" + bytes(72), 31.0, hi[-1:])[0] == e_foreign
    for i in range(4, 88):  # every single corrupted byte after the magic
        bad = bytearray(buf)
        bad[i] ^= 0x10
        assert lib.resume(bytes(bad), 31.0, hi[-1:])[0] == e_crc, i
    other = bytearray(buf)
    other[4] = 2  # a future format version, with a valid checksum
    other[84:88] = struct.pack("<I", zlib.crc32(bytes(other[:84])))
    assert lib.resume(bytes(other), 31.0, hi[-1:])[0] == e_version
    _, foreign_model = libs["float"].state_bytes(t, hi, 56)
    assert lib.resume(foreign_model + bytes(32), 31.0, hi[-1:])[0] in (e_crc, e_model)
    retagged = bytearray(buf)
    retagged[8:12] = b"\0\0\0\0"  # another export's model fingerprint
    retagged[84:88] = struct.pack("<I", zlib.crc32(bytes(retagged[:84])))
    assert lib.resume(bytes(retagged), 31.0, hi[-1:])[0] == e_model
    assert lib.resume(buf, 30.0, hi[-1:])[0] == -4  # time not after the last acquisition
    assert lib.resume(buf, float("nan"), hi[-1:])[0] == -2
    assert lib.resume(buf, 31.0, np.array([11.0]))[0] == -3  # HI above hi_max


def test_the_worked_main_loop_of_the_docs_compiles_and_survives_a_power_cut(cc, tmp_path):
    """docs/rul-on-the-device.md section 6: the loop compiled as printed against an export
    with CIs, run with a power cut half-way; its alerts are those of the Python reference."""
    import subprocess
    from pathlib import Path

    from rulkit.fleet.export.verify import python_reference

    page = (Path(__file__).parents[3] / "docs" / "rul-on-the-device.md").read_text()
    loop = next(b for b in re.findall(r"```c\n(.*?)```", page, flags=re.S)
                if "int monitor(void)" in b)
    rng = np.random.default_rng(4)
    cfg = TrackerConfig.safe(hi_sigma=0.05)
    spec = DeviceSpec("bearing", "docs", cfg, HI_MODEL, None)
    for name, text in generate_c(spec, "double", "bearing").items():
        (tmp_path / name).write_text(text)
    (tmp_path / "monitor.c").write_text(loop)
    n = 80
    t = np.arange(1.0, n + 1)
    ci = rng.rayleigh(size=(n, 2)) + 0.05 * np.exp(0.07 * t)[:, None]
    np.savetxt(tmp_path / "acq.txt", np.column_stack([t, ci]), fmt="%.17g")
    stub = Path(__file__).parent / "c" / "platform_stub.c"
    strict = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]
    for src in ("monitor.c", "bearing.c"):
        subprocess.run([cc, *strict, "-c", src], cwd=tmp_path, check=True)
    subprocess.run([cc, "-O2", "-I", str(tmp_path), "-o", "loop", str(stub), "monitor.o",
                    "bearing.o", "-lm"], cwd=tmp_path, check=True)
    out = subprocess.run(["./loop", "acq.txt", "37"], cwd=tmp_path, capture_output=True,
                         text=True, check=True).stdout.split("\n")
    assert out[-2] == f"n {n}"
    alerts = np.array([[float(v) for v in line.split()[1:]] for line in out[:-2]])
    hi = HI_MODEL.health_index(ci)
    ref = python_reference(spec, np.array([0, n]), t, hi)
    new = ref["new_alert"] == 1
    assert new.any() and np.flatnonzero(new).min() > 37  # raised by the restored state
    np.testing.assert_array_equal(alerts[:, 0], ref["level"][new])
    np.testing.assert_allclose(alerts[:, 1:], np.column_stack(
        [ref["rul_low"][new], ref["rul_high"][new]]), rtol=1e-12)
