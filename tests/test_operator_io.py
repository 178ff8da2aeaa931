"""Operator files: the format (d, version), files of 7c4dc5f, atomic saves, and untrusted files checked before work.

Every bad file must give a ValueError (or an OSError) whose message names the file and says what is wrong, never
another exception type (issue 26): a .npy named .npz, a deeply nested JSON header, declared sizes and degrees
beyond the limits, a zip bomb, object (pickle) arrays, truncations and random damage.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.operator import io as opio
from defop.operator.defop import DefOp

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def op_file(tmp_path_factory):
    """A small trained 2D operator (bar, TPS), compressed, saved once: (op, path, Q)."""
    s = dop.shapes.load("bar", n_vertices=40)
    solver = dop.variational.Solver(s.mesh, s.handles, "arap")
    Q = dop.training.sampling.sample_shape(s, 8, np.random.default_rng(0))
    X = np.array([solver.solve(s.targets(q)).X for q in Q])
    op = dop.operator.fit.fit_shape(s, Q, X, "tps", meta={"energy": "arap"}).compress(rank=3)
    path = tmp_path_factory.mktemp("op") / "op.npz"
    op.save(path)
    return op, path, Q


def _zip(path, members):
    """Write a zip of raw members {name: bytes} (deflated)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, raw in members.items():
            zf.writestr(name, raw)
    return path


def _npy(array=None, shape=None, dtype=None, data=b""):
    """The bytes of a .npy member: a real array, or a header declaring ``shape``/``dtype`` followed by ``data``."""
    buf = io.BytesIO()
    if array is not None:
        np.save(buf, array, allow_pickle=array.dtype.hasobject)
        return buf.getvalue()
    np.lib.format.write_array_header_1_0(buf, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


def _members(path):
    with zipfile.ZipFile(path) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def _header(path):
    with np.load(path) as z:
        return json.loads(str(z["header"]))


def _expect_clear_error(path, match=None):
    with pytest.raises(ValueError, match=match) as info:
        DefOp.load(path)
    assert str(path) in str(info.value)
    return str(info.value)


# ---------------------------------------------------------------- format and old files
def test_format_records_d_and_a_version(op_file):
    op, path, Q = op_file
    header = _header(path)
    assert header["format"] == opio.FORMAT == "defop-operator-3"
    assert header["format_version"] == 3 and header["dim"] == 2 and header["basis"]["kernel"] == "r2logr"
    back = DefOp.load(path)
    assert back.d == 2 and np.array_equal(back(Q), op(Q)) and np.array_equal(back.factors[1], op.factors[1])


@pytest.mark.parametrize("name, key", [("op_7c4dc5f_bar_tps.npz", "X"), ("op_7c4dc5f_bar_tps_rank3.npz", "Xc")])
def test_files_saved_by_7c4dc5f_load_and_evaluate_as_they_did(name, key):
    # saved by /work/wt/old (7c4dc5f, format defop-operator-2) with its outputs at 5 held-out Q: bit for bit
    with np.load(DATA / "op_7c4dc5f_expected.npz") as ref:
        Q, X = ref["Q"], ref[key]
    assert _header(DATA / name)["format"] == "defop-operator-2"
    op = DefOp.load(DATA / name)
    assert op.d == 2 and op.meta["version"] == "0.1.0"
    assert np.array_equal(op(Q), X)


def test_a_3d_mesh_in_an_old_format_is_rejected(op_file, tmp_path):
    _, path, _ = op_file
    members = _members(path)
    header = _header(path)
    header["format"] = "defop-operator-2"
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    members["V.npy"] = _npy(np.zeros((3, 3)))
    _expect_clear_error(_zip(tmp_path / "old3d.npz", members), "format-2 operator file holds 2D meshes")


def test_header_dim_must_match_V(op_file, tmp_path):
    _, path, _ = op_file
    members, header = _members(path), _header(path)
    header["dim"] = 3
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    _expect_clear_error(_zip(tmp_path / "dim.npz", members), "the header says dim = 3")


# ---------------------------------------------------------------- atomic saves
def test_save_is_atomic(op_file, tmp_path, monkeypatch):
    op, path, _ = op_file
    target = tmp_path / "keep.npz"
    target.write_bytes(path.read_bytes())
    before = target.read_bytes()

    def broken(fh, **arrays):
        fh.write(b"PK\x03\x04 half an archive")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError, match="disk full"):
        op.save(target)
    assert target.read_bytes() == before  # the old file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.npz"]  # and no temporary file is left
    monkeypatch.undo()
    op.save(tmp_path / "new.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.npz", "new.npz"]
    assert (tmp_path / "new.npz").stat().st_mode & 0o777 == 0o644


# ---------------------------------------------------------------- hostile files, one class each
def test_npy_named_npz(tmp_path):
    bad = tmp_path / "op.npz"
    np.save(tmp_path / "arr.npy", np.zeros(3))
    os.replace(tmp_path / "arr.npy", bad)
    _expect_clear_error(bad, r"is a single \.npy array, not a defop operator file")


def test_not_a_zip_missing_and_a_directory(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"hello")
    _expect_clear_error(tmp_path / "junk.npz", r"not a defop operator file \(not a zip archive\)")
    _expect_clear_error(tmp_path / "missing.npz", "no such operator file")
    _expect_clear_error(tmp_path, "is a directory, not an operator file")  # issue 35: not "no such file"
    (tmp_path / "empty.npz").write_bytes(b"")
    _expect_clear_error(tmp_path / "empty.npz", "not a zip archive")


def test_deeply_nested_json_header(op_file, tmp_path):
    _, path, _ = op_file
    members = _members(path)
    deep = '{"format": "defop-operator-3", "meta": ' + "[" * 100_000 + "]" * 100_000 + "}"
    members["header.npy"] = _npy(np.array(deep))  # json.loads raises RecursionError on this
    msg = _expect_clear_error(_zip(tmp_path / "deep.npz", members), "nested 100001 levels deep, limit 32")
    assert "RecursionError" not in msg
    assert opio.json_depth('{"a": "[[[[", "b": [[1], {"c": "}}"}]}') == 3  # brackets in strings do not count


def test_declared_matrix_beyond_the_limit_is_not_allocated(op_file, tmp_path):
    _, path, _ = op_file
    members = _members(path)
    members["W.npy"] = _npy(shape=(60000, 60000), dtype=np.float64, data=b"\0" * 64)
    msg = _expect_clear_error(_zip(tmp_path / "big.npz", members), "declares a 60000×60000 float64 array")
    assert "limit 2 GiB per array" in msg


def test_declared_size_must_match_the_member(op_file, tmp_path):
    _, path, _ = op_file
    members = _members(path)
    members["W.npy"] = _npy(shape=(1000, 1000), dtype=np.float64, data=b"\0" * 64)  # 7.6 MiB declared, 64 B held
    _expect_clear_error(_zip(tmp_path / "short.npz", members), "damaged or truncated")


def test_declared_degree_beyond_the_limit(op_file, tmp_path):
    op, path, _ = op_file
    members, header = _members(path), _header(path)
    header["basis"].update(kind="degree1000000000", degree=10**9)
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    msg = _expect_clear_error(_zip(tmp_path / "deg.npz", members), "degree 1000000000, limit 8")
    assert "MemoryError" not in msg
    header["basis"].update(kind="cubic", degree=3.5)
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    _expect_clear_error(_zip(tmp_path / "deg2.npz", members), "degree must be a positive integer")
    header["basis"].update(kind="degree8", degree=8)  # 2 handles' R^2: C(10, 8) = 45 monomials, W has 12 rows
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    _expect_clear_error(_zip(tmp_path / "deg3.npz", members), r"'W' has shape")


def test_too_many_tps_centres(op_file, tmp_path, monkeypatch):
    _, path, _ = op_file
    monkeypatch.setattr(opio.files, "MAX_CENTERS", 5)
    _expect_clear_error(path, "declares 9 TPS centres, limit 5")


def test_zip_bomb_is_rejected_without_inflating_it(op_file, tmp_path, monkeypatch):
    _, path, _ = op_file
    members = _members(path)
    members["W.npy"] = _npy(np.zeros((2048, 2048)))  # 32 MiB of zeros, 33 kB deflated
    bomb = _zip(tmp_path / "bomb.npz", members)
    assert bomb.stat().st_size < 100_000
    monkeypatch.setattr(opio.files, "MAX_ARRAY_BYTES", 2**20)  # a 1 MiB limit: the bomb declares 32 times more
    inflated = []
    read = zipfile.ZipExtFile.read

    def counting(self, n=-1):
        out = read(self, n)
        inflated.append(len(out))
        return out

    monkeypatch.setattr(zipfile.ZipExtFile, "read", counting)
    _expect_clear_error(bomb, r"member 'W\.npy' declares 32 MiB uncompressed, limit 1 MiB per array \(not inflated\)")
    assert sum(inflated) < 200_000  # the headers of the other members only
    # the same bomb with a directory that lies about its size: numpy's header and the member disagree
    monkeypatch.setattr(opio.files, "MAX_ARRAY_BYTES", 2 * 2**30)
    lied = bytearray(bomb.read_bytes())
    with zipfile.ZipFile(bomb) as zf:
        info = zf.getinfo("W.npy")
    cd = lied.find(b"W.npy", lied.find(b"PK\x01\x02")) - 46  # the central-directory entry of W.npy
    assert lied[cd : cd + 4] == b"PK\x01\x02"
    lied[cd + 24 : cd + 28] = (1000).to_bytes(4, "little")  # uncompressed size: 1000 bytes
    (tmp_path / "lied.npz").write_bytes(bytes(lied))
    inflated.clear()
    _expect_clear_error(tmp_path / "lied.npz", "damaged or truncated")
    assert sum(inflated) < 200_000 and info.file_size > 2**25


def test_object_arrays_are_never_unpickled(op_file, tmp_path):
    _, path, _ = op_file
    members = _members(path)
    members["W.npy"] = _npy(np.array([{"a": 1}, None], dtype=object))
    _expect_clear_error(_zip(tmp_path / "pickle.npz", members), "never Python objects or pickles")


def test_unexpected_members_and_too_many(op_file, tmp_path, monkeypatch):
    _, path, _ = op_file
    members = _members(path)
    members["evil.npy"] = b"x"
    _expect_clear_error(_zip(tmp_path / "extra.npz", members), "unexpected member 'evil.npy'")
    monkeypatch.setattr(opio.files, "MAX_MEMBERS", 3)
    _expect_clear_error(path, "archive members, limit 3")


def test_every_truncation_is_a_clear_error(op_file, tmp_path):
    _, path, _ = op_file
    raw = path.read_bytes()
    bad = tmp_path / "cut.npz"
    lengths = sorted(set(range(0, len(raw), max(1, len(raw) // 400))) | set(range(len(raw) - 64, len(raw))))
    for n in lengths:
        bad.write_bytes(raw[:n])
        _expect_clear_error(bad)


# ---------------------------------------------------------------- properties
def _check_load(path):
    """Loads, or raises a ValueError / OSError naming the file; anything else fails the test."""
    try:
        DefOp.load(path)
    except (ValueError, OSError) as exc:
        assert str(path) in str(exc), exc


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=2000), st.sampled_from([b"", b"PK\x03\x04", b"PK\x05\x06", b"\x93NUMPY"]))
def test_random_bytes(tmp_path, data, prefix):
    path = tmp_path / "random.npz"
    path.write_bytes(prefix + data)
    _check_load(path)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_mutated_files(op_file, tmp_path, data):
    _, path, _ = op_file
    raw = bytearray(path.read_bytes())
    # mutate anywhere, or in the first bytes of a member (its .npy header) or of the central directory
    anchors = [m.start() for m in __import__("re").finditer(rb"PK\x01\x02|PK\x03\x04|\x93NUMPY", bytes(raw))]
    for _ in range(data.draw(st.integers(1, 4))):
        where = data.draw(st.one_of(st.integers(0, len(raw) - 1), st.sampled_from(anchors).map(lambda a: a + 8)))
        raw[min(where + data.draw(st.integers(0, 120)), len(raw) - 1)] = data.draw(st.integers(0, 255))
    bad = tmp_path / "mutated.npz"
    bad.write_bytes(bytes(raw))
    _check_load(bad)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
        lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
        max_leaves=20,
    ),
    st.sampled_from(["meta", "basis", "format", "dim", "kind", "scale", "degree", "kernel"]),
)
def test_mutated_json_headers(op_file, tmp_path, value, key):
    _, path, _ = op_file
    members, header = _members(path), _header(path)
    (header["basis"] if key in ("kind", "scale", "degree", "kernel") else header)[key] = value
    members["header.npy"] = _npy(np.array(json.dumps(header)))
    bad = _zip(tmp_path / "json.npz", members)
    _check_load(bad)


def test_path_as_bytes_and_str(op_file):
    op, path, Q = op_file
    for p in (bytes(path), str(path)):
        assert np.array_equal(DefOp.load(p)(Q), op(Q))


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_or_device_is_not_called_missing(tmp_path):
    """A FIFO exists: it was called "no such operator file" (review of issue 35); it is said to be no regular file,
    and nothing is opened (reading a FIFO would block)."""
    os.mkfifo(tmp_path / "op.npz")
    _expect_clear_error(tmp_path / "op.npz", r"op\.npz is not a regular file \(a FIFO, socket or device\)")
    _expect_clear_error(Path("/dev/null"), r"/dev/null is not a regular file")
