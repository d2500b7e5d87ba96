"""`perch bench transport`: mesh <-> message conversion, a cross-process service round trip, and how soon a
process started in the place of a SIGKILLed one hears what is sent to it (the profile's transports: Perch's
profiles use no shared memory, config/fastdds.xml says why; a profile of your own in
FASTRTPS_DEFAULT_PROFILES_FILE is measured instead).

`python -m perch_common.bench_transport DOMAIN` is the listener the bench kills and starts again."""

from __future__ import annotations

import statistics
import subprocess
import sys
import time

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.cli_types import non_negative_int, positive_int


def register(sub) -> None:
    """Add `perch bench transport`: mesh message conversion and cross-process round-trip times."""
    p = sub.add_parser("transport", help="mesh message conversion and cross-process round trip")
    p.add_argument("--faces", type=positive_int, default=300000, help="faces of the test mesh (>= 1)")
    p.add_argument("--repeats", type=positive_int, default=5, help="timed runs (>= 1; the median is reported)")
    p.add_argument("--respawns", type=non_negative_int, default=6,
                   help="listeners SIGKILLed and started again (>= 0; 0 skips it)")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    p.set_defaults(func=_run)


def grid_mesh(faces: int, seed: int = 0):
    """A coloured, noisy height-field mesh with about `faces` triangles."""
    from perch_common.mesh import Mesh

    n = max(2, int(np.sqrt(faces / 2)) + 1)
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 10, n), np.linspace(0, 10, n), indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), 0.01 * rng.standard_normal(n * n)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces_arr = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])[:faces]
    return Mesh(vertices, faces_arr, rng.integers(0, 255, (n * n, 3), dtype=np.uint8))


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _run(args) -> int:
    import rclpy

    from perch_common.ros.conversions import mesh_from_msg, mesh_to_msg
    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import call_service, node_process, use_isolated_ros_env
    from perch_interfaces.srv import InspectMesh

    mesh = grid_mesh(args.faces)
    msg = mesh_to_msg(mesh)
    result = {"faces": mesh.num_faces, "vertices": mesh.num_vertices, "repeats": args.repeats,
              "to_msg_s": _median_time(lambda: mesh_to_msg(mesh), args.repeats),
              "from_msg_s": _median_time(lambda: mesh_from_msg(msg), args.repeats)}
    use_isolated_ros_env()
    request = InspectMesh.Request(mesh=msg, echo=True)
    with ros_context(), node_process("perch_common.mesh_node"):
        node = rclpy.create_node("perch_bench_transport")
        call_service(node, InspectMesh, "perch/inspect_mesh", request, timeout=60)  # warm-up, discovery
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            reply = call_service(node, InspectMesh, "perch/inspect_mesh", request, timeout=60, wait=5)
            times.append(time.perf_counter() - start)
            if not reply.success or reply.faces != mesh.num_faces or len(reply.mesh.triangles) != 3 * mesh.num_faces:
                raise RuntimeError(f"round trip reply is wrong: {reply.message}")
        heard = respawned_listener_heard(node, args.respawns) if args.respawns > 0 else []
        node.destroy_node()
    result.update({"roundtrip_s": statistics.median(times), "roundtrip_min_s": min(times),
                   "peak_rss_mb": peak_rss_mb(),
                   "targets": {"to_msg_s": 0.05, "from_msg_s": 0.05, "roundtrip_s": 0.5}})
    if heard:
        result.update({"respawns": len(heard), "respawned_heard_s": statistics.median(heard),
                       "respawned_heard_max_s": max(heard)})
        result["targets"]["respawned_heard_s"] = 1.5
    return emit(result)


LISTEN_TOPIC = "perch_bench/ping"
HEARD = "heard"


def respawned_listener_heard(node, respawns: int, wait: float = 30.0) -> list[float]:
    """Seconds from its start until a listener process, started right after the previous one was
    SIGKILLed, hears the pings `node` publishes (20 Hz); one figure per respawn."""
    import os
    import select
    import threading

    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    from perch_common.ros.spinning import keep_spinning

    publisher = node.create_publisher(String, LISTEN_TOPIC, 10)
    node.create_timer(0.05, lambda: publisher.publish(String(data="ping")))
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    threading.Thread(target=keep_spinning, args=(executor,), daemon=True).start()
    command = [sys.executable, "-m", "perch_common.bench_transport", os.environ["ROS_DOMAIN_ID"]]

    def start_and_time() -> tuple[subprocess.Popen, float]:
        started = time.monotonic()
        listener = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=dict(os.environ))
        while time.monotonic() - started < wait:
            if select.select([listener.stdout], [], [], 0.1)[0] and HEARD in listener.stdout.readline():
                return listener, time.monotonic() - started
        listener.kill()
        raise RuntimeError(f"a listener did not hear {LISTEN_TOPIC} within {wait:.0f} s of its start")

    heard = []
    listener, _ = start_and_time()   # the first one: a port nobody held before
    try:
        for _ in range(respawns):
            listener.kill()   # no goodbye: the publisher drops it only at the lease's end
            listener.wait()
            listener, seconds = start_and_time()
            heard.append(seconds)
    finally:
        listener.kill()
        listener.wait()
        executor.shutdown()
    return heard


def listen(domain: int) -> None:
    """The listener: print HEARD once a ping arrives, then keep listening until killed."""
    import rclpy
    from std_msgs.msg import String

    from perch_common.ros.testing import use_isolated_ros_env

    use_isolated_ros_env(domain)
    rclpy.init()
    node = rclpy.create_node("perch_bench_listener")
    said = []

    def on_ping(_msg) -> None:
        if not said:
            print(HEARD, flush=True)
            said.append(True)

    node.create_subscription(String, LISTEN_TOPIC, on_ping, 10)
    rclpy.spin(node)


if __name__ == "__main__":
    listen(int(sys.argv[1]))
