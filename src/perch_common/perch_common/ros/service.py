"""Service callbacks that always answer: expected errors become success=false with their message,
unexpected ones are logged with a traceback and answered as internal errors; the node keeps serving."""

from __future__ import annotations

import functools
import time
import traceback
from typing import Callable

from perch_common.errors import EXPECTED


def answering(callback: Callable) -> Callable:
    """Decorate `callback(self, request, response) -> response` of a Node.

    The response type must have `success` and `message`; a `seconds` field, when present, is set
    to the callback's duration.
    """

    @functools.wraps(callback)
    def wrapper(self, request, response):
        started = time.perf_counter()
        try:
            response = callback(self, request, response)
        except EXPECTED as exc:
            response.success, response.message = False, str(exc)
        except Exception as exc:  # keep serving; the traceback goes to the log
            self.get_logger().error(traceback.format_exc())
            response.success, response.message = False, f"internal error: {type(exc).__name__}: {exc}"
        if hasattr(response, "seconds"):
            response.seconds = time.perf_counter() - started
        # rclpy ties a severity to each logging call site: one line per severity.
        if response.success:
            self.get_logger().info(f"{callback.__name__}: {response.message}")
        else:
            self.get_logger().warning(f"{callback.__name__}: {response.message}")
        return response

    return wrapper


def create_stage_service(node, srv_type, name: str, callback: Callable, introspection: bool = True,
                         **kwargs):
    """A service whose requests and replies are published as introspection events when enabled,
    so a recorder (perch_operator) can capture and replay them."""
    from rclpy.qos import qos_profile_services_default
    from rclpy.service_introspection import ServiceIntrospectionState

    service = node.create_service(srv_type, name, callback, **kwargs)
    if introspection:
        service.configure_introspection(node.get_clock(), qos_profile_services_default,
                                        ServiceIntrospectionState.CONTENTS)
    return service
