"""The tensor container against Mitsuba 3's own reader and writer (``mitsuba.tensor_io``), and
malformed files: one line naming the file and the fault, exit 2 from ``gonio info``."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from goniometer.cli import main
from goniometer.files.rgl_tensor import MAGIC, TensorError, read_tensor, tensor_bytes, write_tensor

tensor_io = pytest.importorskip("mitsuba.tensor_io")

FIELDS = {
    "description": "a test file",
    "jacobian": np.array([1], dtype=np.uint8),
    "theta_i": np.radians([0.0, 30.0, 60.0]).astype(np.float32),
    "vndf": np.arange(2 * 3 * 4 * 5, dtype=np.float32).reshape(2, 3, 4, 5),
    "counts": np.array([[1, -2], [3, 4]], dtype=np.int64),
    "wide": np.linspace(0, 1, 7),
}


def test_our_file_reads_in_mitsuba_and_back(tmp_path):
    p = write_tensor(tmp_path / "a.bsdf", FIELDS)
    theirs = tensor_io.read(str(p))
    ours = read_tensor(p)
    assert set(theirs) == set(ours.fields) == set(FIELDS)
    for name, value in FIELDS.items():
        want = np.frombuffer(value.encode(), dtype=np.uint8) if isinstance(value, str) else value
        for got in (theirs[name], ours[name]):
            assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)
    assert ours.text() == "a test file"
    raw = p.read_bytes()
    pos = len(MAGIC) + 2 + 4
    for _ in FIELDS:
        (n,) = struct.unpack_from("<H", raw, pos)
        pos += 2 + n
        ndim, _, offset = struct.unpack_from("<HBQ", raw, pos)
        pos += 11 + 8 * ndim
        assert offset % 8 == 0


def test_mitsubas_file_reads_here(tmp_path):
    p = tmp_path / "m.bsdf"
    tensor_io.write(str(p), **{k: v for k, v in FIELDS.items()})
    ours = read_tensor(p)
    for name, value in FIELDS.items():
        if not isinstance(value, str):
            assert np.array_equal(ours[name], value) and ours[name].dtype == value.dtype


@pytest.mark.parametrize("mangle, needle", [
    (lambda b: b"tensor_flie\0" + b[12:], "not a tensor file"),
    (lambda b: b[:12] + b"\x02\x00" + b[14:], "version 2.0"),
    (lambda b: b[:30], "cut short"),
    (lambda b: b[:-16], "runs past the end"),
])
def test_malformed_files_are_one_line_errors(tmp_path, capsys, mangle, needle):
    good = tensor_bytes(FIELDS)
    p = tmp_path / "bad.bsdf"
    p.write_bytes(mangle(good))
    with pytest.raises(TensorError, match=needle):
        read_tensor(p)
    capsys.readouterr()
    assert main(["info", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    if needle == "not a tensor file":
        return  # not recognised as a tensor file: info says what it is not (slices or tabulated)
    assert len(err) == 1 and needle in err[0] and str(p) in err[0]


def test_a_bad_dtype_code_is_named(tmp_path):
    raw = bytearray(tensor_bytes({"x": np.zeros(2, dtype=np.float32)}))
    # header: magic, version, count, u16 len, "x", u16 ndim, u8 dtype
    raw[len(MAGIC) + 2 + 4 + 2 + 1 + 2] = 42
    p = tmp_path / "d.bsdf"
    p.write_bytes(bytes(raw))
    with pytest.raises(TensorError, match="dtype code 42"):
        read_tensor(p)
