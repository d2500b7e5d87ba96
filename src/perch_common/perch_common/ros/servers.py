"""Who serves a service: the servers in the graph, not the clients that merely name it.

`Node.get_service_names_and_types()` also lists a service that only clients use (a client creates the
request writer and reply reader too), so a graph query for "is it offered" must look at the servers'
own endpoint: the reader of the request topic.
"""

from __future__ import annotations


def server_endpoints(node, service: str) -> dict[bytes, str]:
    """The servers of a (fully qualified) service now in the graph: request-reader GID -> node name.

    A service travels on the DDS topics rq<service>Request / rr<service>Reply; each server has one
    reader of the request topic, with a GID that a restarted node never reuses."""
    infos = node.get_subscriptions_info_by_topic(f"rq{service}Request", no_mangle=True)
    return {bytes(info.endpoint_gid): endpoint_node(info) for info in infos}


UNNAMED_NODE = "a node not yet named"


def endpoint_node(info) -> str:
    """The full name of the node an endpoint (rclpy's TopicEndpointInfo) belongs to; UNNAMED_NODE for one
    discovered before its participant's node names (it reads _NODE_NAME_UNKNOWN_)."""
    if "_UNKNOWN_" in info.node_name or "_UNKNOWN_" in info.node_namespace:
        return UNNAMED_NODE
    return f"{info.node_namespace.rstrip('/')}/{info.node_name}"
