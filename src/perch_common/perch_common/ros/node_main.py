"""The `main()` every Perch node uses: init, spin until Ctrl-C or shutdown, clean up."""

from __future__ import annotations

import contextlib
import sys
from typing import Callable, Iterator

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from perch_common.config import ConfigError
from perch_common.memory import freeze_startup_objects, tune_memory
from perch_common.mesh_cache import PROCESS_CACHE
from perch_common.processes import die_with_parent
from perch_common.ros.spinning import keep_spinning
from perch_common.threads import limit_threads


@contextlib.contextmanager
def ros_context(args: list[str] | None = None) -> Iterator[None]:
    """rclpy.init ... shutdown as a block (rclpy 7.1's init() is not a context manager)."""
    rclpy.init(args=args)
    try:
        yield
    finally:
        rclpy.try_shutdown()


def make_executor(threads: int, context=None):
    """The executor for `threads` threads (rclpy warns about a MultiThreadedExecutor with one)."""
    if threads == 1:
        return SingleThreadedExecutor(context=context)
    return MultiThreadedExecutor(num_threads=threads, context=context)


def run_node(factory: Callable[[], Node], args: list[str] | None = None, threads: int = 2) -> int:
    """Create the node inside an rclpy context and spin it; returns the process exit code.

    A bad parameter (ConfigError from declare_config) stops the node before it serves anything, with
    one line on stderr naming the node, the parameter and what it accepts, and exit code 2."""
    die_with_parent()    # started by a launcher: never outlive it
    limit_threads()
    tune_memory()  # freed memory reused within a request, given back after it
    with ros_context(args if args is not None else sys.argv):
        try:
            node = factory()
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            return 2
        PROCESS_CACHE.hosts.add(node.get_name())   # requests it reads may name this process's meshes by id
        freeze_startup_objects()
        executor = make_executor(threads)
        executor.add_node(node)
        try:
            keep_spinning(executor)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            executor.shutdown()
            node.destroy_node()
    return 0
