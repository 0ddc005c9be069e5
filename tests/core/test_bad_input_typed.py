"""Bad-input catalogue, typed inputs and files: one clear error, no contents echoed.

Arrays that are not real numbers (complex, bool, strings, datetimes, objects,
structured or masked records), noise levels outside the representable range,
``.npy`` files that are not one numeric array or whose header lies about the
size, and text files whose contents must not appear in the message.
"""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.build import array_from_config
from olsbayes.config import load_config, parse_config, read_readings

RING = ob.Ring(30)
MODEL = ob.Model(RING, 0.01)
DATA = MODEL.simulate(ob.Scene(directions=[0.37, -2.0], intensities=[1.0, 0.2]), rng=0)
TWO = ob.Scene(directions=[0.1, 2.0], intensities=[1.0, 1.0])


def _select(data):
    from olsbayes.select import select_k

    return select_k(MODEL, data, 1)


def _sample(data):
    from olsbayes.posterior import sample

    return sample(MODEL, data, 1, progress=False)


NOT_REAL = [
    ("complex", DATA + 0j, "complex"),
    ("complex with imaginary part", DATA + 1j, "complex"),
    ("bool", DATA > 0, "bool"),
    ("strings", DATA.astype(str), "string"),
    ("bytes", DATA.astype(bytes), "bytes"),
    ("datetime", np.arange(30).astype("datetime64[s]"), "datetime"),
    ("timedelta", np.arange(30).astype("timedelta64[s]"), "timedelta"),
    ("object", DATA.astype(object), "object"),
    ("structured", np.zeros(30, dtype=[("a", float)]), "structured"),
    ("list of strings", ["1"] * 30, "string"),
    ("int beyond float", [10**400] * 30, "object"),
    ("masked entries", np.ma.masked_array(DATA, mask=DATA < 0.1), "masked"),
]


@pytest.mark.parametrize("label,value,match", NOT_REAL, ids=[c[0] for c in NOT_REAL])
def test_fit_refuses_arrays_that_are_not_real_numbers(label, value, match):
    with pytest.raises(ob.InputError, match=f"data .*{match}"):
        ob.fit_ml(MODEL, value, 2)


API_CASES = [
    ("select complex", lambda: _select(DATA + 1j), "complex"),
    ("posterior bool", lambda: _sample(DATA > 0), "bool"),
    ("image strings", lambda: ob.image(MODEL, DATA.astype(str), np.linspace(-3, 3, 8),
                                       "gaussian"), "string"),
    ("scene bool intensities", lambda: ob.Scene(directions=[0.1], intensities=[True]), "bool"),
    ("scene complex directions", lambda: ob.Scene(directions=[0.1 + 1j], intensities=[1.0]),
     "complex"),
    ("normals complex", lambda: ob.SensorArray(np.ones((3, 2)) + 1j), "complex"),
    ("normals bool", lambda: ob.SensorArray(np.eye(3, dtype=bool)), "bool"),
    ("response complex params", lambda: MODEL.response(np.array([0.1, 1.0 + 1j])), "complex"),
    ("simulate datetime params", lambda: MODEL.simulate(
        np.arange(2).astype("datetime64[s]"), rng=0), "datetime"),
    ("log-likelihood complex data", lambda: MODEL.log_likelihood(np.array([0.1, 1.0]),
                                                                DATA + 1j), "complex"),
    ("sigma denormal", lambda: ob.Model(RING, 1e-320), r"sigma must be in \[1e-100"),
    ("sigma tiny", lambda: ob.Model(RING, 1e-200), r"sigma must be in \[1e-100"),
    ("sigma 1e155", lambda: ob.Model(RING, 1e155), r"sigma must be in \[1e-100"),
    ("with_sigma 1e-320", lambda: MODEL.with_sigma(1e-320), "sigma must be in"),
    ("crlb intensity / sigma 1e162",
     lambda: ob.crlb(MODEL, ob.Scene(directions=[0.1, 2.0], intensities=[1e160, 1e160])),
     "Fisher information .* overflows"),
    ("readings 1e95 sigma", lambda: ob.fit_ml(MODEL, np.full(30, 1e93), 1),
     "within a factor 1e\\+90 of sigma"),
    ("readings 1e-93 sigma", lambda: ob.fit_ml(MODEL, np.full(30, 1e-95), 1),
     "within a factor 1e\\+90 of sigma"),
]


@pytest.mark.parametrize("label,call,match", API_CASES, ids=[c[0] for c in API_CASES])
def test_api_typed_bad_input(label, call, match):
    with pytest.raises(ob.InputError, match=match):
        call()


def test_sigma_at_the_ends_of_its_range_gives_finite_bounds():
    """sigma in [1e-100, 1e100], intensity / sigma 1e6 .. 1e13: finite CRLB and fits."""
    for sigma, inten in ((1e-100, 1e-94), (1e100, 1e106), (1e-3, 1e10)):
        model = ob.Model(RING, sigma)
        scene = ob.Scene(directions=[0.1, 2.0], intensities=[inten, inten])
        bound = ob.crlb(model, scene)
        assert np.all(np.isfinite(bound.std)) and np.all(bound.std > 0)
        fit = ob.fit_ml(model, model.simulate(scene, rng=1), 2)
        assert np.all(np.isfinite(fit.std))
        np.testing.assert_allclose(fit.params[1::2], inten, rtol=1e-4)  # SNR >= 1e6


def test_noise_below_the_rounding_of_the_readings_is_warned():
    """intensity / sigma = 1e80 is accepted, but float64 readings cannot carry that noise."""
    model = ob.Model(RING, 1e-3)
    scene = ob.Scene(directions=[0.1, 2.0], intensities=[1e77, 1e77])
    with pytest.warns(ob.ConvergenceWarning, match="do not describe the readings"):
        fit = ob.fit_ml(model, model.simulate(scene, rng=1), 2)
    np.testing.assert_allclose(fit.params[1::2], 1e77, rtol=1e-12)


def test_integer_and_low_precision_readings_are_numbers():
    ints = np.round(DATA * 1000).astype(np.int32)
    a = ob.fit_ml(MODEL.with_sigma(10.0), ints, 2, warn=False)
    b = ob.fit_ml(MODEL.with_sigma(10.0), ints.astype(float), 2, warn=False)
    np.testing.assert_array_equal(a.params, b.params)


# ---- files ----------------------------------------------------------------------------
def _npy_header(path, shape, descr="<f8", payload=b""):
    from numpy.lib import format as fmt

    with open(path, "wb") as f:
        fmt.write_array_header_1_0(f, {"descr": descr, "fortran_order": False, "shape": shape})
        f.write(payload)


def _files(tmp):
    """(label, path, regex) of data files that must be refused with one clear error."""
    out = []

    def npy(label, arr, match):
        p = tmp / f"{label.replace(' ', '_')}.npy"
        np.save(p, arr)
        out.append((label, p, match))

    npy("structured npy", np.zeros(30, dtype=[("a", float), ("b", int)]), "structured")
    npy("complex npy", np.ones(30) + 1j, "complex")
    npy("bool npy", np.ones(30, dtype=bool), "bool")
    npy("string npy", np.array(["1.0"] * 30), "string")
    npy("datetime npy", np.arange(30).astype("datetime64[s]"), "datetime")
    npy("3-D npy", np.zeros((2, 2, 30)), r"1-D or 2-D .*shape \(2, 2, 30\)")
    npy("empty npy", np.zeros((0, 30)), "non-empty")
    p = tmp / "archive.npy"
    np.savez(tmp / "archive.npz", a=np.zeros(30))
    (tmp / "archive.npz").rename(p)
    out.append(("npz named npy", p, r"\.npz archive"))
    np.savez(tmp / "archive.npz", a=np.zeros(30))
    out.append(("npz", tmp / "archive.npz", r"\.npz archive.*numpy\.save"))
    p = tmp / "huge.npy"
    _npy_header(p, (10**9, 30), payload=b"\0" * 800)
    out.append(("header claims 240 GB", p, r"header says shape \(1000000000, 30\).*800 bytes"))
    p = tmp / "huger.npy"
    _npy_header(p, (2**62, 2**62))
    out.append(("header shape beyond int64", p, "header says shape"))
    p = tmp / "short.npy"
    _npy_header(p, (1000, 30), payload=b"\0" * 800)
    out.append(("truncated npy", p, "240000 bytes.*800 bytes follow"))
    p = tmp / "code.npy"
    p.write_bytes(b"\x93NUMPY\x01\x00\x20\x00{'descr': __import__('os')}    \n")
    out.append(("code in npy header", p, "not a valid .npy file"))
    p = tmp / "text.npy"
    p.write_text("1 2 3\n")
    out.append(("text named npy", p, "not a valid .npy file"))
    return out


def test_data_files_refused_before_allocation(tmp_path):
    import tracemalloc

    tracemalloc.start()
    try:
        for label, path, match in _files(tmp_path):
            with pytest.raises(ob.ConfigError, match=match):
                read_readings(path, 30)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6  # nothing the headers claim was allocated


SECRET = "SECRET_TOKEN=hunter2"


@pytest.mark.parametrize(
    "content,match",
    [
        (f"{SECRET} 1 2\n", "line 1, field 1 is not a number"),
        ("0 " * 29 + f"0\n1 2 {SECRET}\n", "line 2, field 3 is not a number"),
        ("0," * 29 + "PASSWORD\n", "line 1, field 30 is not a number"),
        ("# header\n" + "1_0 " * 30 + "\n", "line 2, field 1 is not a number"),
        ("PATH=/usr/bin\0HOME=/root\0", "line 1, field 1 is not a number"),
    ],
)
def test_text_file_errors_give_positions_never_contents(tmp_path, content, match):
    p = tmp_path / "r.txt"
    p.write_text(content)
    with pytest.raises(ob.ConfigError, match=match) as info:
        read_readings(p, 30)
    for secret in ("hunter2", "SECRET", "PASSWORD", "/usr/bin", "1_0"):
        assert secret not in str(info.value)


def test_normals_file_contents_are_not_echoed(tmp_path):
    normals = tmp_path / "normals.txt"
    normals.write_text(f"1 0\n{SECRET} 1\n0 1\n")
    cfg = parse_config('[sensor]\ngeometry = "custom"\nsigma = 0.1\n'
                       'normals_file = "normals.txt"\n', base_dir=tmp_path)
    with pytest.raises(ob.ConfigError, match="line 2, field 1 is not a number") as info:
        array_from_config(cfg)
    assert "hunter2" not in str(info.value)


def test_special_files_are_not_read(tmp_path):
    import os

    fifo = tmp_path / "fifo.txt"
    os.mkfifo(fifo)
    with pytest.raises(ob.ConfigError, match="not a regular file"):
        read_readings(fifo, 30)  # would block forever if opened
    with pytest.raises(ob.ConfigError, match="not a regular file"):
        read_readings("/dev/zero", 30)


def test_deeply_nested_toml_file(tmp_path):
    p = tmp_path / "deep.toml"
    p.write_text("x = " + "{a = " * 100_000 + "1" + "}" * 100_000 + "\n")
    with pytest.raises(ob.ConfigError, match="nested too deeply"):
        load_config(p)


def test_fortran_and_integer_npy_files_are_read(tmp_path):
    table = np.arange(60, dtype=float).reshape(2, 30)
    np.save(tmp_path / "f.npy", np.asfortranarray(table))
    np.save(tmp_path / "i.npy", table.astype(np.int16))
    np.testing.assert_array_equal(read_readings(tmp_path / "f.npy", 30), table)
    np.testing.assert_array_equal(read_readings(tmp_path / "i.npy", 30), table)


def test_switch_name_and_path_checks_take_only_their_type():
    """The shared checks of switches, names and paths: the type itself, never a value
    that merely converts (0/1 or a string for a switch, an array for a name, bytes or
    a number for a path), each refused with one InputError naming the argument."""
    from pathlib import Path

    from olsbayes._validation import choice, file_path, flag

    assert [flag("s", v) for v in (True, False, np.True_, np.False_)] == [True, False,
                                                                         True, False]
    assert all(type(flag("s", v)) is bool for v in (np.True_, True))
    for bad in (0, 1, "yes", None, np.array([True])):
        with pytest.raises(ob.InputError, match="s must be True or False"):
            flag("s", bad)
    assert choice("m", "fast", ("fast", "exact")) == "fast"
    for bad in ("slow", ["fast"], np.array(["fast", "exact"]), None, b"fast"):
        with pytest.raises(ob.InputError, match="m must be one of"):
            choice("m", bad, ("fast", "exact"))
    assert file_path("p", "a/b.nc") == Path("a/b.nc") == file_path("p", Path("a/b.nc"))
    for bad in (b"a.nc", 3, 1.5, None, "", "a\0b", ["a"], np.ones(2)):
        with pytest.raises(ob.InputError, match="p must be a file path"):
            file_path("p", bad)
