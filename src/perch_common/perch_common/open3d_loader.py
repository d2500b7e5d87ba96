"""Open3D imported without its Plotly/Dash web viewer, which Perch never uses.

`import open3d` runs `open3d.visualization.draw_plotly`, which imports Dash and Plotly: about 0.4 s
of the ~0.9 s the import takes on two cores, paid by every node process and every `perch plan`.
`open3d()` imports Open3D with that module deferred: its functions stay importable under their
names and load the real module on their first call.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any, Callable

DEFERRED = "open3d.visualization.draw_plotly"


class _Deferred(types.ModuleType):
    """Stands in for DEFERRED until one of the callables taken from it is called."""

    def __init__(self) -> None:
        super().__init__(DEFERRED, "deferred by perch_common.open3d_loader; loaded on first use")
        self._handed_out: list[str] = []

    def __getattr__(self, name: str) -> Callable[..., Any]:
        if name.startswith("__"):
            raise AttributeError(name)
        self._handed_out.append(name)

        def call(*args, **kwargs):
            return getattr(_load_real(self), name)(*args, **kwargs)

        call.__name__ = call.__qualname__ = name
        call.__doc__ = f"{DEFERRED}.{name} (loaded on first call)"
        return call


def _load_real(stub: _Deferred) -> types.ModuleType:
    """Import the real module in place of `stub` and re-bind the names the package took from it."""
    if sys.modules.get(DEFERRED) is stub:
        del sys.modules[DEFERRED]
    real = importlib.import_module(DEFERRED)
    package = sys.modules[DEFERRED.rpartition(".")[0]]
    for name in stub._handed_out:
        if hasattr(real, name):
            setattr(package, name, getattr(real, name))
    return real


def open3d() -> types.ModuleType:
    """The open3d module (imported on the first call, its web viewer deferred)."""
    if "open3d" not in sys.modules and DEFERRED not in sys.modules:
        sys.modules[DEFERRED] = _Deferred()
    import open3d as o3d

    return o3d
