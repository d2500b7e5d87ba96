"""Perch's Fast DDS profiles let a server wait for its caller's discovery before giving up a reply.

rmw_fastrtps sends a service reply only once the reply writer has matched the caller's reply reader,
and waits for that at most the writer's max_blocking_time (Fast DDS default 100 ms); past it the reply
is dropped ("failed to send response (timeout)") and the caller waits in vain. A quick first call on a
loaded machine hit it (a CI run's reset "did not answer within 30 s"). The probe makes the match
impossible (a best-effort reply writer cannot match a reliable reply reader) and measures the wait.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from perch_common.launch import dds_profile
from perch_common.ros.testing import isolated_ros_env

pytestmark = pytest.mark.ros

PROBE = r'''
import json, sys, time, warnings
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

rclpy.init()
server, caller = rclpy.create_node("reply_wait_server"), rclpy.create_node("reply_wait_caller")
answered = []
server.create_service(Trigger, "reply_wait", lambda request, response: answered.append(time.monotonic()) or response,
                      qos_profile=QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
client = caller.create_client(Trigger, "reply_wait")   # reliable reply reader: never matched
executor = SingleThreadedExecutor()
executor.add_node(server)
executor.add_node(caller)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    deadline, sent = time.monotonic() + 60, 0.0
    while time.monotonic() < deadline and not caught:
        if not answered and time.monotonic() - sent > 0.5:   # until the request writer has matched
            client.call_async(Trigger.Request())
            sent = time.monotonic()
        executor.spin_once(timeout_sec=0.1)
    dropped = time.monotonic()
print(json.dumps({"warnings": [str(w.message) for w in caught],
                  "waited": dropped - answered[0] if answered else None}))
rclpy.shutdown()
'''


def _reply_wait(env: dict) -> dict:
    run = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "XMLPARSER" not in run.stderr, run.stderr   # the profile loaded whole
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("network", [False, True], ids=["local", "network"])
def test_a_server_waits_seconds_for_its_callers_reply_reader(network):
    env = isolated_ros_env()
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(dds_profile(network))
    env["RMW_FASTRTPS_USE_QOS_FROM_XML"] = "1"
    if network:   # this test's traffic stays on this host
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    result = _reply_wait(env)
    assert result["waited"] is not None, "the server never took the request"
    assert result["warnings"] and "failed to send response" in result["warnings"][0]
    # 5 s in the profile: a 100 ms default would end the wait at once (load only lengthens a wait)
    assert result["waited"] >= 4.5, result
