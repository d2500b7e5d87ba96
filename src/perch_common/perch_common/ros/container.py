"""Several Perch nodes in one process on one executor, the way a ROS 2 component container works.

Each node module names its node class `COMPONENT`; the container creates one of each in the
current rclpy context (so the context's `--ros-args --params-file ...` apply to every node by
name) and spins them all on one MultiThreadedExecutor. Services, actions and topics are exactly
those of the separate processes. Used in-process by `perch plan`/`demo` and as its own process by
`perch launch --graph-mode one-process` (`python -m perch_common.ros.container --nodes a,b ...`).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import threading

from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from perch_common.memory import freeze_startup_objects, tune_memory
from perch_common.mesh_cache import PROCESS_CACHE
from perch_common.ros.spinning import keep_spinning
from perch_common.threads import limit_threads

# Threads per hosted node: a long service call must never starve another node's callbacks
# (the coordinator blocks one thread for a whole mission and waits on stage replies).
THREADS_PER_NODE = 2
MIN_THREADS = 8


class NodeContainer:
    """Create the named nodes in this process and spin them on one executor (in a thread or here)."""

    def __init__(self, nodes: list[str], modules: dict[str, str] | None = None, context=None):
        from perch_common.launch import available_nodes

        registered = modules or available_nodes()
        unknown = [n for n in nodes if n not in registered]
        if unknown:
            raise ValueError(f"unknown node(s) {', '.join(unknown)}; installed: {', '.join(sorted(registered))}")
        self.names = list(nodes)
        self.modules = {n: registered[n] for n in nodes}
        self.context = context
        self.nodes: list = []
        self.executor: MultiThreadedExecutor | None = None
        self._thread: threading.Thread | None = None

    def create(self) -> "NodeContainer":
        """Import each node's module and create its COMPONENT; all on one new executor."""
        tune_memory()  # freed memory reused within a request, given back after it (as run_node does)
        self.executor = MultiThreadedExecutor(num_threads=max(MIN_THREADS, THREADS_PER_NODE * len(self.names)),
                                              context=self.context)
        # Every module first, then the nodes: each rclpy log line (a node's "ready") looks its caller
        # up through inspect, which re-scans the modules imported since the last one (~25 ms each).
        modules = {name: importlib.import_module(self.modules[name]) for name in self.names}
        for name in self.names:
            module = modules[name]
            component = getattr(module, "COMPONENT", None)
            if component is None:
                raise ValueError(f"{self.modules[name]} defines no COMPONENT (its node class); "
                                 "it cannot be hosted in a one-process graph")
            node = component()
            PROCESS_CACHE.hosts.add(node.get_name())
            self.nodes.append(node)
            self.executor.add_node(node)
        freeze_startup_objects()
        return self

    def spin(self) -> None:
        """Spin here until shutdown (Ctrl-C or the context ends)."""
        try:
            keep_spinning(self.executor)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass

    def start(self) -> "NodeContainer":
        """Create the nodes and spin them in a background thread."""
        from perch_common.processes import clean_dead_shm

        clean_dead_shm()   # what killed Perch processes left in /dev/shm
        self.create()
        self._thread = threading.Thread(target=self.spin, name="perch-container", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop spinning and destroy every node."""
        if self.executor is not None:
            self.executor.shutdown(timeout_sec=5.0)
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for node in self.nodes:
            PROCESS_CACHE.hosts.discard(node.get_name())
            node.destroy_node()
        self.nodes.clear()

    def __enter__(self) -> "NodeContainer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    """`python -m perch_common.ros.container --nodes a,b --ros-args ...`: host the nodes until Ctrl-C."""
    from perch_common.processes import die_with_parent
    from perch_common.ros.node_main import ros_context

    die_with_parent()    # started by a launcher: never outlive it
    limit_threads()
    argv = list(sys.argv[1:] if argv is None else argv)
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    parser = argparse.ArgumentParser(prog="perch_common.ros.container")
    parser.add_argument("--nodes", required=True, help="comma-separated node names (entry points perch.nodes)")
    options = parser.parse_args(argv[:split])
    with ros_context([sys.argv[0], *argv[split:]]):
        container = NodeContainer(options.nodes.split(",")).create()
        try:
            container.spin()
        finally:
            container.executor.shutdown()
            for node in container.nodes:
                node.destroy_node()
    return 0


if __name__ == "__main__":
    sys.exit(main())
