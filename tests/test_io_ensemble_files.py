"""The ensemble block files (lobattodae._io.ensemble_files): a crafted or damaged block is our
error naming the file, never a MemoryError or a NumPy traceback from a header's claims."""

import io
import json
import zipfile

import numpy as np
import pytest

import lobattodae as L
from lobattodae._io import ensemble_files as EF


def _npy(header_shape, data: bytes) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": "<f8", "fortran_order": False, "shape": header_shape})
    return out.getvalue() + data


def _save(a) -> bytes:
    out = io.BytesIO()
    np.save(out, a, allow_pickle=False)
    return out.getvalue()


def _block(path, members: dict, compression=zipfile.ZIP_STORED):
    meta = np.asarray(json.dumps({"format": EF.FILE_FORMAT, "version": EF.FILE_VERSION}))
    with zipfile.ZipFile(path, "w", compression) as zf:
        zf.writestr("meta.npy", _save(meta))
        zf.writestr("digests.npy", _save(np.asarray(json.dumps({"meta": "0", **{k: "0" for k in members}}))))
        for name, raw in members.items():
            zf.writestr(f"{name}.npy", raw)


@pytest.mark.parametrize("raw, reason", [
    (_npy((2**40,), b"\0" * 8), "8 data bytes for shape (1099511627776,)"),  # np.load would reserve 8 TiB
    (_npy((4,), b"\0" * 40), "40 data bytes for shape (4,)"),  # trailing bytes NumPy would ignore
])
def test_a_header_that_lies_about_its_size_is_our_error(tmp_path, raw, reason):
    path = tmp_path / EF.file_name(0, 0)
    _block(path, {"q": raw})
    with pytest.raises(L.EnsembleFileError, match="is damaged or cannot be read") as info:
        EF.read_block(str(path))
    assert reason in str(info.value) and str(path) in str(info.value)


def test_compressed_members_are_refused(tmp_path):
    """Blocks are written stored (np.savez): a compressed member did not come from lobattodae, and
    its expansion is not bounded by the file's size."""
    path = tmp_path / EF.file_name(0, 0)
    _block(path, {"q": _save(np.zeros(4))}, compression=zipfile.ZIP_DEFLATED)
    with pytest.raises(L.EnsembleFileError, match="compressed or encrypted"):
        EF.read_block(str(path))


def test_a_block_written_by_the_library_reads_back_bit_for_bit(tmp_path):
    path = str(tmp_path / EF.file_name(0, 3))
    arrays = {"q": np.linspace(0.0, 1.0, 12).reshape(4, 3), "status": np.array([0, 0, 3, 0], np.int32)}
    meta = np.asarray(json.dumps({"format": EF.FILE_FORMAT, "version": EF.FILE_VERSION, "block": 3}))
    EF.write_block(path, {"meta": meta, **arrays})
    meta, back = EF.read_block(path)
    assert meta["block"] == 3
    for name, x in arrays.items():
        assert back[name].dtype == x.dtype and np.array_equal(back[name], x)
