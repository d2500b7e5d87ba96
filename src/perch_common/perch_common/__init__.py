"""Shared core of Perch: mesh I/O and validation, message conversions, ray casting, configuration,
the procedural scene generator, the perch CLI and launcher."""

import os as _os

# Perch's numpy work is many small (N,3)x(3,3) products: threaded OpenBLAS makes them up to 40x
# slower on a loaded 2-core machine. Open3D's OpenMP pool has hung in a futex when left to size
# itself. Both take effect only if set before numpy/Open3D load, so the launcher and the test
# runner set them too.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
_os.environ.setdefault("OMP_NUM_THREADS", str(min(_os.cpu_count() or 1, 2)))
