"""`perch console`: the operator console in a browser, a client of the running graph.

    perch launch &                                     # the graph (or any running Perch graph on this domain)
    perch console --mesh ../shared/data/meshes/apartment.ply
    # open http://127.0.0.1:8080/ ; --host 0.0.0.0 exposes it (to a tablet) behind a token in the URL
"""

from __future__ import annotations

import dataclasses
import errno
import http
import ipaddress
import socket
import sys
import time
from pathlib import Path

import numpy as np

from perch_common.cli_types import int_between
from perch_common.errors import PerchError
from perch_common.mesh import add_units_arguments
from perch_common.outputs import atomic_path, check_writable_file

DEFAULT_PORT = 8080


def register(sub) -> None:
    """Add `perch console`."""
    p = sub.add_parser("console", help="the operator console in a browser (scan, boxes, review, confirmation)")
    p.add_argument("--mesh", type=Path, help="the scan to show and plan on (missions are started from the console)")
    add_units_arguments(p, "--mesh")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default loopback only); any other needs the token printed in the URL")
    p.add_argument("--port", type=int_between(0, 65535), default=DEFAULT_PORT,
                   help=f"port (default {DEFAULT_PORT}; 0: a free one); one in use is refused")
    p.add_argument("--token", default="", help="the URL token (default: none on loopback, a new random one when exposed)")
    p.add_argument("--recording", type=Path, help="show a mission's run.mcap (its scan, markers, proposals and views)")
    p.add_argument("--screenshot", type=Path, metavar="PNG",
                   help="open the console in headless chromium, save what it shows once the room is drawn, and exit")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --screenshot file (else refused)")
    p.set_defaults(func=_console)


def check_can_serve(host: str, port: int) -> None:
    """Raise PerchError unless `host`:`port` can be bound here, as the server will bind it.

    Checked before viser starts: on a port in use viser silently serves on the next one, and on an
    address it cannot bind it tries 1000 ports and then waits forever."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as exc:
        raise PerchError(f"--host {host}: cannot be served on here ({getattr(exc, 'strerror', None) or exc}); "
                         "give an address of this machine (127.0.0.1, or 0.0.0.0 for all)") from None
    for family, kind, proto, _, address in addresses:
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as asyncio's server: TIME_WAIT is free
            if family == socket.AF_INET6:
                probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)   # as asyncio's server too
            try:
                probe.bind(address)
            except OSError as exc:
                raise _bind_error(host, port, exc) from None


def _bind_error(host: str, port: int, exc: OSError) -> PerchError:
    if exc.errno in (errno.EADDRINUSE, errno.EACCES):
        return PerchError(f"--port {port}: cannot be used on {host} ({exc.strerror}); give another port, "
                          "or --port 0 for any free one")
    return PerchError(f"--host {host}: cannot be served on here ({exc.strerror}); give an address of this "
                      "machine (127.0.0.1, or 0.0.0.0 for all)")


def check_screenshot(path: Path, overwrite: bool) -> None:
    """A screenshot is a .png file in a writable folder, new unless --overwrite: checked before the console
    and chromium start (a folder failed in Playwright after the room was drawn; a file was replaced)."""
    check_writable_file(path, "--screenshot", "console.png")
    if path.suffix.lower() != ".png":
        raise PerchError(f"--screenshot {path}: not a .png file; give a PNG path (e.g. {path.with_suffix('.png')})")
    if path.exists() and not overwrite:
        raise PerchError(f"--screenshot {path}: the file exists; give a new path, or add --overwrite to replace it")


def check_recording(recording: Path) -> None:
    """Missing, empty, not an MCAP or not a Perch run (no /perch/ topic): refused before anything is served."""
    from perch_operator.outputs import runfile

    if not Path(recording).is_file():
        raise PerchError(f"{recording}: no such recording (give --recording a run.mcap)")
    topics = runfile.recorded_topics(recording)   # the recording reader's own check first (MCAP magic), with its fix
    if not any("/perch/" in "/" + topic.lstrip("/") for topic in topics):   # a camera bag (in any namespace)
        held = f"its topics: {', '.join(topics[:4])}{', ...' if len(topics) > 4 else ''}" if topics else "no topics"
        raise PerchError(f"{recording}: not a Perch run recording ({held}); give --recording the run.mcap that perch "
                         "plan, perch demo or perch record wrote (a camera bag is planned with `perch plan --bag`)")


def is_loopback(host: str) -> bool:
    """Whether `host` only serves this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def require_token(token: str) -> None:
    """Serve viser only under /<token>/: other HTTP requests and websocket connections get 403.

    viser has no access control of its own; its browser client opens the websocket on the page's
    path (query dropped), so a path token covers both. Installed on websockets' `serve` for this
    process, which serves nothing but the console."""
    import websockets.asyncio.server as ws_server
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    original = ws_server.serve
    if getattr(original, "perch_token", None) is not None:
        original = original.perch_original
    prefix = f"/{token}"

    def gated(handler, *args, process_request=None, **kwargs):
        def check(connection, request):
            path, sep, query = request.path.partition("?")
            if path != prefix and not path.startswith(prefix + "/"):
                return Response(http.HTTPStatus.FORBIDDEN, "Forbidden",
                                Headers([("Content-Type", "text/plain")]),
                                b"this Perch console needs the URL with its token (printed by perch console)\n")
            inner = dataclasses.replace(request, path=(path[len(prefix):] or "/") + sep + query)
            return process_request(connection, inner) if process_request is not None else None

        return original(handler, *args, process_request=check, **kwargs)

    gated.perch_token, gated.perch_original = token, original
    ws_server.serve = gated


def start_console(mesh_path: Path | None, host: str = "127.0.0.1", port: int = DEFAULT_PORT, token: str = "",
                  recording: Path | None = None, scale: float = 1.0, shift: tuple[float, float, float] | None = None):
    """The console serving and attached to the graph (rclpy must be initialised); returns (console, graph, url)."""
    from perch_console.graph import ConsoleGraph
    from perch_console.state import new_token
    from perch_console.ui import Console, scan_source

    if mesh_path is not None and not Path(mesh_path).is_file():
        raise PerchError(f"{mesh_path}: no such scan file (give --mesh a .ply/.obj/.glb mesh)")
    if recording is not None:
        check_recording(recording)
    check_can_serve(host, port)
    if not is_loopback(host):
        token = token or new_token()
    if token:   # always beyond loopback; on loopback when one is given
        require_token(token)
    console = Console(host=host, port=port)
    if port and console.server.get_port() != port:   # taken since the check: viser moved on rather than fail
        console.server.stop()
        raise _bind_error(host, port, OSError(errno.EADDRINUSE, "address already in use"))
    graph = ConsoleGraph(console.changed)
    console.attach(graph)
    if mesh_path is not None:
        mesh, mesh_msg, convention = scan_source(Path(mesh_path), scale, shift)
        console.goal_source = (mesh_msg, convention)
        console.place_boxes(mesh.vertices)
        console.show_scan(mesh, Path(mesh_path).name)
    if recording is not None:
        graph.show_recording(recording)
        if graph.scan is not None and mesh_path is None:
            points = np.array([(p.x, p.y, p.z) for p in graph.scan.points[::3]])
            console.place_boxes(points, graph.picture.to_input[:3, 2])   # the stages' up in the input frame
    shown_host = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    url = f"http://{shown_host}:{console.server.get_port()}/" + (f"{token}/" if token else "")
    for what in ("scan", "markers", "proposals", "review", "removals", "progress"):
        console.changed(what)   # what the latched topics already delivered
    return console, graph, url


def _console(args) -> int:
    from perch_operator.cli.runner import client_context

    started = time.monotonic()
    if args.screenshot is not None:
        check_screenshot(args.screenshot, args.overwrite)
    with client_context():
        console, graph, url = start_console(args.mesh, args.host, args.port, args.token, args.recording,
                                            args.scale, args.shift)
        if args.screenshot is not None:
            try:
                seconds = screenshot(url, args.screenshot)
                print(f"perch console: {args.screenshot} ({seconds:.1f} s in chromium)")
                return 0
            finally:
                graph.close()
                console.server.stop()
        print(f"perch console: {url}  (room shown after {console.first_picture_at - started:.2f} s)"
              if console.first_picture_at else f"perch console: {url}", flush=True)
        if not is_loopback(args.host):
            print("perch console: exposed beyond this machine; only the URL above (with its token) opens it",
                  file=sys.stderr, flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
        finally:
            graph.close()
            console.server.stop()
    return 0


def screenshot(url: str, path: Path, size: tuple[int, int] = (1600, 1000), timeout: float = 300.0) -> float:
    """Open `url` in Debian's headless chromium (Playwright), wait until the room is drawn, save a PNG;
    returns the seconds it took."""
    from playwright.sync_api import sync_playwright

    from perch_console.bench import room_drawn

    started = time.monotonic()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": size[0], "height": size[1]})
        page.goto(url)
        page.get_by_role("button", name="Start mission").wait_for(timeout=timeout * 1000)
        dismiss_notices(page)
        while not room_drawn(page.screenshot()):
            if time.monotonic() - started > timeout:
                raise PerchError(f"the room was not drawn within {timeout:.0f} s")
        dismiss_notices(page)   # shown again once WebGL started
        with atomic_path(path) as partial:   # an interrupted run never leaves half a PNG over the user's
            page.screenshot(path=str(partial))
        browser.close()
    return time.monotonic() - started


def dismiss_notices(page) -> None:
    """Close viser's notices (e.g. 'software WebGL rendering') so that screenshots show the room."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    for close in page.locator(".mantine-Notification-closeButton").all():
        try:
            close.click(timeout=2000)
        except PlaywrightTimeout:   # it closed itself meanwhile
            pass
