"""Persistence: the files lobattodae writes and reads back, and nothing else.

* :mod:`.atomic` — the one atomic writer (unique temporary file, fsync, rename, directory fsync,
  no symbolic links) of every file below;
* :mod:`.fingerprint` — digests of a run's identity: a state's schema, numbers, code;
* :mod:`.checkpoint` — the versioned checkpoint format that resumes a run bit for bit, with its
  row segments (:mod:`.segments`) and its guarded reader (:mod:`.archive`);
* :mod:`.ensemble_files` — the block files of :func:`lobattodae.ensemble`.

The rest of the library takes the names below from here, and the API of the two formats from
:mod:`.checkpoint` and :mod:`.ensemble_files`.
"""

from .archive import CheckpointError
from .checkpoint import CheckpointWriteError
from .ensemble_files import EnsembleFileError
from .fingerprint import fingerprint_arrays, fingerprint_callable

__all__ = ["CheckpointError", "CheckpointWriteError", "EnsembleFileError", "fingerprint_arrays",
           "fingerprint_callable"]
