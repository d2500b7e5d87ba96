"""Helpers for cross-process ROS tests: start a node process, call its services with timeouts."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import rclpy
from rclpy.node import Node

from perch_common.launch import use_perch_dds
from perch_common.processes import stop_process
from perch_common.threads import thread_environment


def isolated_ros_env(domain_id: int | None = None) -> dict[str, str]:
    """Environment for a test graph on loopback only, on its own DDS domain."""
    env = dict(os.environ)
    if domain_id is None:
        # PERCH_TEST_DOMAIN pins the domain, so that test runs started side by side never share one.
        domain_id = int(os.environ.get("PERCH_TEST_DOMAIN") or 100 + os.getpid() % 100)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    env.update(thread_environment(env))
    return use_perch_dds(env)


def use_isolated_ros_env(domain_id: int | None = None) -> None:
    """Apply isolated_ros_env to this process (call before rclpy.init)."""
    os.environ.update(isolated_ros_env(domain_id))


@contextlib.contextmanager
def node_process(module: str, params: dict[str, Any] | None = None, params_file: str | Path | None = None,
                 log_path: str | Path | None = None) -> Iterator[subprocess.Popen]:
    """Run `python -m module --ros-args ...` for the duration of the block; stop it with SIGINT."""
    cmd = [sys.executable, "-m", module, "--ros-args"]
    if params_file:
        cmd += ["--params-file", str(params_file)]
    for key, value in (params or {}).items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        cmd += ["-p", f"{key}:={text}"]
    log = open(log_path, "w") if log_path else subprocess.DEVNULL
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=log, stderr=subprocess.STDOUT)
    try:
        yield proc
    finally:
        stop_process(proc)
        if log_path:
            log.close()


_clients: dict[tuple[int, str, str], object] = {}


def call_service(node: Node, srv_type, name: str, request, timeout: float = 30.0, wait: float = 30.0,
                 resend_every: float | None = None):
    """Wait for the service, call it and return the response; raise TimeoutError naming what hung.

    One client per (node, service) is kept: a client created just before its first call can lose
    the reply while discovery still matches it to the server (Perch's Fast DDS profiles let the
    server wait 5 s for that match: test_service_reply_wait). The request itself can be lost the
    same way: wait_for_service tells that this client's request writer matched the server's reader,
    not that the server's reader has matched the writer yet, and a volatile reader drops what came
    before. Nothing on the client's side shows that second match, so for an idempotent service
    `resend_every` seconds sends the request again until a reply comes.
    """
    key = (id(node), srv_type.__name__, name)
    client = _clients.get(key)
    if client is None or client not in node.clients:
        client = _clients[key] = node.create_client(srv_type, name)
    if not client.wait_for_service(timeout_sec=wait):
        raise TimeoutError(f"service {name} did not appear within {wait:.0f} s")
    futures = [client.call_async(request)]
    start = time.monotonic()
    deadline = start + timeout
    while not any(f.done() for f in futures) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        if resend_every and time.monotonic() - start > resend_every * len(futures):
            futures.append(client.call_async(request))
    answered = next((f for f in futures if f.done()), None)
    if answered is not None:   # requests sent after the answered one are served next: let them finish first
        later = futures[futures.index(answered) + 1:]
        settle = time.monotonic() + (resend_every or 0.0)
        while not all(f.done() for f in later) and time.monotonic() < settle:
            rclpy.spin_once(node, timeout_sec=0.1)
    for future in futures:
        if not future.done():
            client.remove_pending_request(future)
    if answered is None:
        sent = f" ({len(futures)} requests sent)" if len(futures) > 1 else ""
        raise TimeoutError(f"service {name} did not answer within {timeout:.0f} s{sent}")
    return answered.result()


def poll_until(condition, timeout: float, what: str):
    """The first truthy value of `condition()`, polled every 50 ms; AssertionError "{what} within N s" after `timeout`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what} within {timeout:.0f} s")
