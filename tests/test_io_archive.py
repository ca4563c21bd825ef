"""Reading one checkpoint file without trusting it (lobattodae._io.archive): the checks NumPy's
``.npy`` reader does not make, and the CheckpointError every failure becomes."""

import io
import warnings
import zipfile

import numpy as np
import pytest

from lobattodae._io import archive


def npy(array=None, *, header=None, data=None, version=(1, 0)):
    """A ``.npy`` blob: ``array`` as NumPy writes it, or a ``header`` dict followed by ``data``."""
    buf = io.BytesIO()
    if array is not None:
        np.lib.format.write_array(buf, array, version=version, allow_pickle=True)
        return buf.getvalue()
    np.lib.format.write_array_header_1_0(buf, header)
    return buf.getvalue() + data


def archive_with(tmp_path, **members):
    """An uncompressed zip of ``<key>.npy`` members with valid CRCs: only its contents lie."""
    path = tmp_path / "x.npz"
    with zipfile.ZipFile(path, "w") as zf:
        for key, blob in members.items():
            zf.writestr(f"{key}.npy", blob)
    return path


@pytest.mark.parametrize("array", [
    np.arange(6.0).reshape(2, 3),
    np.asfortranarray(np.arange(6.0).reshape(2, 3)),
    np.zeros((0, 4), np.int32),
    np.asarray(True),
    np.asarray("text"),
    np.arange(3, dtype=">i8"),
])
def test_read_npy_reads_what_numpy_writes(array):
    got = archive.read_npy(npy(array))
    assert got.dtype == array.dtype and got.shape == array.shape and np.array_equal(got, array)
    assert got.flags.writeable


def test_read_npy_reads_version_2_headers():
    array = np.arange(3.0)
    assert np.array_equal(archive.read_npy(npy(array, version=(2, 0))), array)


def test_a_header_claiming_more_data_than_there_is_allocates_nothing():
    """NumPy would allocate what the header claims (8 TiB here) before reading: MemoryError."""
    blob = npy(header={"descr": "<f8", "fortran_order": False, "shape": (2**40,)}, data=bytes(16))
    with pytest.raises(ValueError, match=r"16 data bytes for shape \(1099511627776,\) of float64"):
        archive.read_npy(blob)


def test_bytes_after_the_array_are_refused():
    blob = npy(np.arange(2.0)) + b"\0" * 8
    with pytest.raises(ValueError, match=r"24 data bytes for shape \(2,\) of float64"):
        archive.read_npy(blob)


def test_python_objects_are_refused_unread():
    with pytest.raises(ValueError, match="Python objects"):
        archive.read_npy(npy(np.array([{"a": 1}], dtype=object)))


def test_long_headers_and_other_versions_are_refused():
    header = {"descr": [(f"f{i}", "<f8") for i in range(10_000)], "fortran_order": False, "shape": (0,)}
    buf = io.BytesIO()
    np.lib.format.write_array_header_2_0(buf, header)
    with pytest.raises(ValueError, match="max_header_size"):
        archive.read_npy(buf.getvalue())
    with pytest.raises(ValueError, match=r"unsupported \.npy version \(3, 0\)"):
        archive.read_npy(npy(np.arange(2.0), version=(3, 0)))


def test_a_lying_member_with_a_valid_crc_is_a_checkpoint_error(tmp_path):
    lying = npy(header={"descr": "<f8", "fortran_order": False, "shape": (2**40,)}, data=bytes(16))
    path = archive_with(tmp_path, good=npy(np.arange(2.0)), bad=lying)
    with archive.open_archive(str(path), "run.npz") as r:
        assert np.array_equal(r.array("good"), np.arange(2.0))
        with pytest.raises(archive.CheckpointError) as info:
            r.array("bad")
    assert str(info.value) == (
        "checkpoint 'run.npz' is corrupt or not a lobattodae checkpoint (entry 'bad' is damaged: ValueError: 16 "
        "data bytes for shape (1099511627776,) of float64); delete it or restart without resume."
    )
    assert info.value.path == "run.npz"


@pytest.mark.parametrize("names, reason", [
    (["a.txt"], "unexpected archive member 'a.txt'"),
    (["a.npy", "a.npy"], "duplicate entry 'a'"),
])
def test_members_that_are_not_one_npy_each_are_refused(tmp_path, names, reason):
    path = tmp_path / "x.npz"
    with zipfile.ZipFile(path, "w") as zf, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns about the duplicate it writes
        for name in names:
            zf.writestr(name, npy(np.arange(2.0)))
    with pytest.raises(archive.CheckpointError, match=reason), archive.open_archive(str(path), "run.npz"):
        pass


def test_compressed_members_are_refused(tmp_path):
    path = tmp_path / "x.npz"
    np.savez_compressed(path, a=np.zeros(100))
    with (pytest.raises(archive.CheckpointError, match="entry 'a' is compressed or encrypted"),
          archive.open_archive(str(path), "run.npz")):
        pass


def test_a_segment_is_named_in_the_message(tmp_path):
    with (pytest.raises(archive.CheckpointError) as info,
          archive.open_archive(str(tmp_path / "gone.npz"), "run.npz", "row segment 'run.npz.rows/x.npz'")):
        pass
    assert str(info.value) == ("checkpoint 'run.npz' is corrupt or not a lobattodae checkpoint (row segment "
                               "'run.npz.rows/x.npz' is missing); delete it or restart without resume.")
