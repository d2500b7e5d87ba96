"""Thread limits: importing Perch leaves the process environment alone; the entry points apply the limits."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from perch_common.threads import BLAS_THREADS, OPENMP_THREADS, thread_environment

THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
PACKAGES = ("perch_common", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement",
            "perch_operator")


def run_python(code: str, **env_changes: str) -> dict:
    """Run `code` in a fresh interpreter without the thread variables (plus env_changes); its JSON output."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env.update(env_changes)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_importing_every_perch_module_leaves_the_environment_unchanged():
    changed = run_python(f"""
import importlib, json, os, pkgutil
import cv2  # noqa: F401  (OpenCV's own import edits LD_LIBRARY_PATH: a third-party effect, taken first)
before = dict(os.environ)
imported = 0
for name in {PACKAGES!r}:
    package = importlib.import_module(name)
    for info in pkgutil.walk_packages(package.__path__, name + "."):
        if not info.name.endswith("__main__"):
            importlib.import_module(info.name)
            imported += 1
after = dict(os.environ)
print(json.dumps({{"imported": imported, "changed": sorted(k for k in set(before) | set(after)
                                                   if before.get(k) != after.get(k))}}))
""")
    assert changed["imported"] > 50  # every module of every package, node adapters and CLIs included
    assert changed["changed"] == []


def test_limit_threads_limits_the_loaded_blas_and_sets_openmp_for_later():
    result = run_python("""
import json, os
import numpy  # loaded first, as by every entry point's imports
from threadpoolctl import threadpool_info
from perch_common.threads import limit_threads
limits = limit_threads()
blas = sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})
print(json.dumps({"limits": limits, "blas": blas, "omp": os.environ.get("OMP_NUM_THREADS"),
                  "openblas": os.environ.get("OPENBLAS_NUM_THREADS")}))
""")
    assert result["limits"] == {"blas": BLAS_THREADS, "openmp": OPENMP_THREADS}
    assert result["blas"] == [BLAS_THREADS]  # numpy's (and scipy's) OpenBLAS, already loaded
    assert result["omp"] == str(OPENMP_THREADS) and result["openblas"] == str(BLAS_THREADS)


def test_a_user_setting_wins():
    result = run_python("""
import json
from threadpoolctl import threadpool_info
from perch_common.threads import limit_threads
limits = limit_threads()
print(json.dumps({"limits": limits, "blas": sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})}))
""", OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="1")
    assert result["limits"] == {"blas": 2, "openmp": 1}
    assert thread_environment({"OMP_NUM_THREADS": "1"}) == {"OPENBLAS_NUM_THREADS": str(BLAS_THREADS),
                                                            "OMP_NUM_THREADS": "1"}


def test_the_perch_command_and_a_node_main_apply_the_limits():
    """`perch` (here without a command: it prints its help) and a node's main() (here one whose parameters
    are bad, so it stops at once) leave this process with the limits."""
    result = run_python("""
import contextlib, io, json
from threadpoolctl import threadpool_info
from perch_common.cli import main
from perch_common.config import ConfigError
from perch_common.ros.node_main import run_node
blas = lambda: sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})
before = blas()
with contextlib.redirect_stdout(io.StringIO()):
    code = main([])
after_cli = blas()
from threadpoolctl import threadpool_limits
threadpool_limits(limits=2, user_api="blas")
def bad_node():
    raise ConfigError("bad value")
with contextlib.redirect_stderr(io.StringIO()):
    node_code = run_node(bad_node, ["node"])
print(json.dumps({"before": before, "cli": [code, after_cli], "node": [node_code, blas()]}))
""")
    assert result["cli"] == [0, [BLAS_THREADS]]
    assert result["node"] == [2, [BLAS_THREADS]]


def test_side_by_side_keeps_the_order_uses_a_second_thread_and_raises_an_error():
    import threading

    from perch_common.threads import one_thread, side_by_side, work_threads

    def ident(value):
        return lambda: (value, threading.get_ident())

    results = side_by_side(ident("a"), ident("b"))
    assert [r[0] for r in results] == ["a", "b"]
    assert results[0][1] == threading.get_ident()
    assert (results[1][1] != threading.get_ident()) == (work_threads() > 1)
    with one_thread():
        assert {r[1] for r in side_by_side(ident("a"), ident("b"))} == {threading.get_ident()}

    def fails():
        raise ValueError("second share")

    with pytest.raises(ValueError, match="second share"):
        side_by_side(ident("a"), fails)
