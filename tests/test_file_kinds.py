"""Every file kind the library has written or read: each fixture of tests/data/files/ loads to its stored answer,
bit for bit, forever; each loader names the kind of another kind's file and the loader that reads it; stored dtypes
the kernels cannot take are converted (big-endian) or refused by name (float16); header fields are named."""

from __future__ import annotations

import io
import json
import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

from defop.geometry.archive import ArchiveError, Limits, NpzReader
from defop.geometry.mesh import read_mesh
from defop.operator import io as opio
from defop.operator.branched import BranchedOperator
from defop.operator.defop import DefOp
from defop.operator.io import OperatorFileError
from defop.operator.movable import MovableOp
from defop.training.cache import Cache

FILES = Path(__file__).parent / "data" / "files"
OLD = Path(__file__).parent / "data"

#: fixture -> (its loader, the kind's words in another loader's error, the loader named)
KINDS = {
    "operator-1_tps.npz": (DefOp.load, "a single-valued operator file", "DefOp.load"),
    "operator-3_tps_rank3.npz": (DefOp.load, "a single-valued operator file", "DefOp.load"),
    "operator-3_quadratic.npz": (DefOp.load, "a single-valued operator file", "DefOp.load"),
    "branched-1.npz": (BranchedOperator.load, "a multi-valued operator file", "BranchedOperator.load"),
    "branched-2.npz": (BranchedOperator.load, "a multi-valued operator file", "BranchedOperator.load"),
    "movable-1.npz": (MovableOp.load, "a movable-handle operator file", "MovableOp.load"),
    "cache-entry.npz": (None, "a defop cache entry", "Cache.load"),
    "mesh.npz": (read_mesh, "a mesh file", "read_mesh"),
}
LOADERS = {"DefOp": DefOp.load, "BranchedOperator": BranchedOperator.load, "MovableOp": MovableOp.load}


@pytest.fixture(scope="module")
def expected():
    with np.load(FILES / "expected.npz") as z:
        return {k: z[k] for k in z.files}


def _quiet(f, *a):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a)


@pytest.mark.parametrize("name", ["operator-1_tps", "operator-3_tps_rank3", "operator-3_quadratic"])
def test_operator_files_load_to_their_stored_answers(expected, name):
    op = DefOp.load(FILES / f"{name}.npz")
    assert np.array_equal(_quiet(op, expected["Q"]), expected[name])


@pytest.mark.parametrize("name", ["op_7c4dc5f_bar_tps.npz", "op_7c4dc5f_bar_tps_rank3.npz"])
def test_format_2_files_load(name):
    with np.load(OLD / "op_7c4dc5f_expected.npz") as ref:
        Q, X = ref["Q"], ref["X" if "rank" not in name else "Xc"]
    assert np.array_equal(DefOp.load(OLD / name)(Q), X)


@pytest.mark.parametrize("name", ["branched-1", "branched-2"])
def test_branched_files_load_to_their_stored_answers(expected, name):
    bop = BranchedOperator.load(FILES / f"{name}.npz")
    assert np.array_equal(_quiet(bop, expected["Q"]), expected[name])
    assert np.array_equal(_quiet(bop.choose, expected["Q"]), expected[f"{name}_labels"])


def test_movable_file_loads_to_its_stored_answers(expected):
    mop = MovableOp.load(FILES / "movable-1.npz")
    assert np.array_equal(_quiet(mop, expected["Q"]), expected["movable-1"])
    fast = np.stack([_quiet(mop.evaluate_fast, q) for q in expected["Q"]])
    assert np.array_equal(fast, expected["movable-1_fast"])


def test_cache_entry_and_mesh_fixtures_read(tmp_path):
    store = Cache(tmp_path)
    shutil.copy(FILES / "cache-entry.npz", store.path("gt", "fixture"))
    arrays, meta = store.load("gt", "fixture", {"X": ((2, None, 2), "f"), "converged": ((2,), "b")})
    assert arrays["X"].shape[0] == 2 and meta == {"times": [0.1, 0.2]}
    assert read_mesh(FILES / "mesh.npz").n_vertices == arrays["X"].shape[1]


@pytest.mark.parametrize("loader", list(LOADERS))
@pytest.mark.parametrize("name", list(KINDS))
def test_each_loader_names_the_kind_of_another_kinds_file(loader, name):
    """Before: 'unexpected member', or a member-count limit (the branched file has more members than 16)."""
    own, words, reader = KINDS[name]
    if reader == f"{loader}.load":
        return
    with pytest.raises(OperatorFileError) as info:
        LOADERS[loader](FILES / name)
    message = str(info.value)
    assert str(FILES / name) in message and words in message and reader in message, message


def _rewrite(src, dst, **changes):
    """A copy of the archive ``src`` with members replaced (``name=array``) or dropped (``name=None``)."""
    with np.load(src) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k, None)
        else:
            arrays[k] = v
    with open(dst, "wb") as fh:
        np.savez(fh, **arrays)
    return dst


def _factors(name):
    with np.load(FILES / name) as z:
        return z["factor_A"], z["factor_B"]


@pytest.mark.parametrize("name, load", [("operator-3_tps_rank3.npz", DefOp.load), ("movable-1.npz", MovableOp.load)])
def test_big_endian_factors_load_to_the_same_frames(tmp_path, expected, name, load):
    """Before: a big-endian factor reached the compiled kernel, which refused it with numba's own error."""
    A, B = _factors(name)
    path = _rewrite(FILES / name, tmp_path / name, factor_A=A.astype(">f4"), factor_B=B.astype(">f4"))
    op, ref = load(path), load(FILES / name)
    q = expected["Q"][1]
    assert np.array_equal(_quiet(op.evaluate_fast, q), _quiet(ref.evaluate_fast, q))
    assert np.array_equal(_quiet(op, expected["Q"]), _quiet(ref, expected["Q"]))


@pytest.mark.parametrize("name, load", [("operator-3_tps_rank3.npz", DefOp.load), ("movable-1.npz", MovableOp.load)])
def test_float16_factors_are_refused_by_name(tmp_path, name, load):
    A, B = _factors(name)
    path = _rewrite(FILES / name, tmp_path / name, factor_A=A.astype(np.float16), factor_B=B.astype(np.float16))
    with pytest.raises(OperatorFileError, match=r"'factor_A' is float16; an operator file stores float32 or float64"):
        load(path)


def test_float16_branch_factors_are_refused_by_name(tmp_path):
    path = FILES / "branched-2.npz"
    op = BranchedOperator.load(path).compress(rank=2)
    op.save(tmp_path / "b.npz")
    A = np.load(tmp_path / "b.npz")["b0.factor_A"]
    bad = _rewrite(tmp_path / "b.npz", tmp_path / "bad.npz", **{"b0.factor_A": A.astype(np.float16)})
    with pytest.raises(OperatorFileError, match=r"'factor_A' is float16"):
        BranchedOperator.load(bad)


@pytest.mark.parametrize("name, load", [(n, KINDS[n][0]) for n in ("operator-3_quadratic.npz", "movable-1.npz")])
def test_an_out_of_range_handle_names_the_field(tmp_path, name, load):
    """Before (movable): an IndexError from the placement, naming no field."""
    with np.load(FILES / name) as z:
        handles, nv = z["handles"].copy(), len(z["V"])
    handles[0] = nv + 5
    with pytest.raises(OperatorFileError, match=rf"'handles'.*\[0, {nv}\), got \[{nv + 5}\]"):
        load(_rewrite(FILES / name, tmp_path / name, handles=handles))


@pytest.mark.parametrize("name", ["operator-3_quadratic.npz", "branched-2.npz", "movable-1.npz"])
@pytest.mark.parametrize("header", ["[1, 2]", '"text"', "3"])
def test_a_non_mapping_header_is_named(tmp_path, name, header):
    """Before: "has format None", naming no field."""
    path = _rewrite(FILES / name, tmp_path / name, header=np.array(header))
    with pytest.raises(OperatorFileError, match=r"the header must be a JSON object, got (list|str|int)"):
        KINDS[name][0](path)


@pytest.mark.parametrize("name", ["branched-2.npz", "movable-1.npz"])
def test_a_non_mapping_meta_is_named(tmp_path, name):
    with np.load(FILES / name) as z:
        header = json.loads(str(z["header"]))
    header["meta"] = [1]
    path = _rewrite(FILES / name, tmp_path / name, header=np.array(json.dumps(header)))
    with pytest.raises(OperatorFileError, match=r"header 'meta' must be a JSON object"):
        KINDS[name][0](path)


def test_the_archive_reader_names_its_file_and_converts_byte_order(tmp_path):
    buf = io.BytesIO()
    np.savez(buf, a=np.arange(3, dtype=">i8"), b=np.ones(2, ">f8"))
    path = tmp_path / "x.npz"
    path.write_bytes(buf.getvalue())
    with NpzReader(path, f"file {path}", "an archive") as z:
        got = z.read_all(z.members())
    assert got["a"].dtype == np.int64 and got["a"].tolist() == [0, 1, 2] and got["b"].dtype == np.float64
    with zipfile.ZipFile(path, "a") as zf:
        zf.writestr("c.npy", b"\x93NUMPY\x01\x00" + b"{" * 300)
    with pytest.raises(ArchiveError, match=rf"^file {path}: member c is not a numpy array"):
        with NpzReader(path, f"file {path}", "an archive") as z:
            z.members()
    with pytest.raises(ArchiveError, match=r"holds 3 archive members, limit 2"):
        with NpzReader(path, f"file {path}", "an archive", Limits(max_members=2)) as z:
            z.members()


def test_every_kind_is_registered_with_its_formats():
    assert set(opio.KINDS) == {"operator", "branched", "movable"}
    assert opio.KINDS["branched"].formats == {"defop-branched-1": 1, "defop-branched-2": 2}
    assert opio.kind_of(["joint_W.npy"])[2] == "defop.operator.MovableOp.load"


def test_every_path_computes_the_frames_of_f3915d6():
    """The frames of every evaluation path, as the code before the one operator core computed them
    (tests/data/files/frames.py): float64 paths bit for bit, the float32 and compiled paths within round-off."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("fixture_frames", FILES / "frames.py")
    frames = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(frames)
    now = frames.frames(FILES)
    with np.load(FILES / "frames_f3915d6.npz") as z:
        old = {k: z[k] for k in z.files}
    assert set(now) == set(old)
    for name, X in old.items():
        if name in frames.EXACT:
            assert np.array_equal(now[name], X), name
        else:
            assert np.allclose(now[name], X, rtol=1e-5, atol=1e-6 * np.abs(X).max()), name
    n_equal = sum(np.array_equal(now[k], old[k]) for k in old)
    assert n_equal >= len(frames.EXACT)
