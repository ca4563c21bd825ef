"""The native step's LU factorisation, its plain copy against its AVX-512 copy (issue #25 item 5).

The generated C (:mod:`lobattodae.mechanics._native`) compiles ``factor`` a second time for
x86-64-v4 (AVX-512) where gcc, x86-64 Linux and the Newton matrix's size allow it, and the
processor picks its copy when the library is loaded. This script takes ``factor`` as the
generator writes it, compiles it twice into small timing programs (``gcc -O2``: the default copy alone, and
with the AVX-512 copy, at every size whatever the generator's size condition says), factorises the same dense random matrix of each size (entries uniform in [-0.5, 0.5], a
fresh copy per factorisation, best of 5 rounds of ``--count``), and checks that both copies give
the same bits (a weighted sum of the factors, printed in hexadecimal). Dense matrices are the
worst case for the elimination, which skips zero multipliers: the real Newton matrices are
sparser.

Usage::

    PYTHONPATH=src .venv/bin/python benchmarks/lu_copies.py [--sizes 29 36 43 50 57 67 87] [--pin-cpu 1]

Writes ``benchmarks/results/lu_copies.json``.
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile

from lib import cli
from lib.output import log, md_table, results_path, run_meta, write_json
from lobattodae.mechanics import _native

_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
int main(int argc, char **argv) {
  const int count = atoi(argv[1]);
  double *a = malloc(sizeof(double)*NU*NU), *b = malloc(sizeof(double)*NU*NU); int piv[NU];
  srand(1); for (int i = 0; i < NU*NU; i++) a[i] = rand() / (double)RAND_MAX - 0.5;
  double best = 1e300;
  for (int r = 0; r < 5; r++) {
    struct timespec t0, t1; clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int n = 0; n < count; n++) { memcpy(b, a, sizeof(double)*NU*NU); factor(b, piv); }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    const double us = ((t1.tv_sec - t0.tv_sec)*1e9 + (t1.tv_nsec - t0.tv_nsec)) / count / 1e3;
    if (us < best) best = us;
  }
  double check = 0.0; for (int i = 0; i < NU*NU; i++) check += b[i]*(i % 7 + 1);
  printf("%.3f %a\n", best, check);
  return 0;
}
"""


def factor_source() -> str:
    """The generator's LU code (macros, ``factor``, ``lu_solve``), as it stands in the program."""
    return _native._LU_C


def time_size(nu: int, copies: bool, count: int, work: str) -> tuple[float, str]:
    source = "#include <math.h>\n#include <string.h>\n" + f"#define NU {nu}\n" + factor_source() + _MAIN
    # both variants at every size: the size condition of the copies made true, or false
    source = re.sub(r"&& NU >= \d+", "&& 1" if copies else "&& 0", source)
    path = os.path.join(work, f"lu_{nu}_{int(copies)}")
    with open(path + ".c", "w") as fh:
        fh.write(source)
    subprocess.run(["gcc", "-O2", "-o", path, path + ".c", "-lm"], check=True)
    us, check = subprocess.run([path, str(count)], capture_output=True, text=True, check=True).stdout.split()
    return float(us), check


def main(argv=None) -> int:
    ap = cli.parser(__doc__, "pin_cpu")
    ap.add_argument("--sizes", nargs="+", type=int, default=[29, 36, 43, 50, 57, 67, 87])
    ap.add_argument("--count", type=int, default=4000, help="factorisations per round")
    a = cli.start(ap.parse_args(argv))
    rows, out = [], []
    with tempfile.TemporaryDirectory() as work:
        for nu in a.sizes:
            plain, check_plain = time_size(nu, False, a.count, work)
            copies, check_copies = time_size(nu, True, a.count, work)
            out.append({"unknowns": nu, "plain_us": plain, "copies_us": copies, "same_bits": check_plain == check_copies})
            rows.append([nu, f"{plain:.2f}", f"{copies:.2f}", f"{copies / plain:.2f}", check_plain == check_copies])
    log(md_table(["unknowns", "plain µs", "with the AVX-512 copy µs", "ratio", "same bits"], rows))
    write_json({"meta": run_meta(), "sizes": out}, results_path("lu_copies.json"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
