"""Authenticated commands for a networked graph (`--network` / PERCH_NETWORK=1): HMAC-SHA256 tokens.

On a host-only graph (the default) only this host's processes can reach the graph, and commands
are not signed. Once the graph is opened to the network, any host that reaches its DDS domain could
decide on proposals, stop stage calls or publish waypoint sets; the Fast DDS of the PyPI wheels is
built without DDS security, so SROS2 cannot help. Instead every such command carries a token

    "<unix seconds>:<hex HMAC-SHA256(key, kind \\x1f seconds \\x1f field \\x1f ...)>"

made with a key shared by the hosts of the graph: a file of 32 random bytes, created with mode 0600
on first use (PERCH_KEY_FILE, default ~/.config/perch/network.key) and copied by the user to the other
hosts. A key file that others can read is refused. A token is valid for TOKEN_WINDOW seconds, binds
every field of its command (a changed field invalidates it) and its kind; a replay within the window
repeats the identical command only, and a receiver that must not act twice (the mission cancel) keeps
the tokens it took for the window in a ReplayGuard and refuses them again. What it does not give:
secrecy (the traffic is readable) and protection against a host that holds the key.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import stat
import threading
import time
from pathlib import Path

KEY_ENV = "PERCH_KEY_FILE"
TOKEN_WINDOW = 120.0   # s a token stays valid (clocks of the graph's hosts must agree this closely)
KEY_BYTES = 32


class AuthError(PermissionError):
    """A key that cannot be used (readable by others, wrong size)."""


def key_path(env: dict | None = None) -> Path:
    """PERCH_KEY_FILE, else ~/.config/perch/network.key."""
    value = (os.environ if env is None else env).get(KEY_ENV, "").strip()
    return Path(value).expanduser() if value else Path.home() / ".config" / "perch" / "network.key"


def load_key(path: Path | None = None, create: bool = True) -> bytes:
    """The shared key; created (mode 0600, its folder 0700) when missing and `create`."""
    path = Path(path) if path else key_path()
    if not path.exists() and create:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            pass   # another process created it first: read theirs
        else:
            with os.fdopen(fd, "wb") as stream:
                stream.write(secrets.token_bytes(KEY_BYTES))
    mode = path.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise AuthError(f"{path}: the network key is readable by other users (mode {stat.S_IMODE(mode):o}); "
                        f"`chmod 600 {path}` and copy it to the graph's other hosts only")
    key = path.read_bytes()
    if len(key) < 16:
        raise AuthError(f"{path}: the network key has {len(key)} bytes; delete it to have a new one made, "
                        "and copy that to the graph's other hosts")
    return key


def _message(kind: str, seconds: int, fields) -> bytes:
    return "\x1f".join([kind, str(seconds), *(repr(f) if isinstance(f, float) else str(f) for f in fields)]).encode()


def sign(key: bytes, kind: str, *fields, now: float | None = None) -> str:
    """A token for the command `kind` with these fields."""
    seconds = int(time.time() if now is None else now)
    return f"{seconds}:{hmac.new(key, _message(kind, seconds, fields), hashlib.sha256).hexdigest()}"


def check(key: bytes, token: str, kind: str, *fields, now: float | None = None) -> str:
    """'' when `token` authenticates the command, else why not (for the refusal's message)."""
    if not token:
        return "it carries no authentication token (a networked graph takes commands signed with its key only)"
    seconds_text, _, mac = token.partition(":")
    if not seconds_text.isdigit() or not mac:
        return "its authentication token is malformed"
    seconds = int(seconds_text)
    if abs((time.time() if now is None else now) - seconds) > TOKEN_WINDOW:
        return f"its authentication token is older than {TOKEN_WINDOW:g} s (or the hosts' clocks differ)"
    wanted = hmac.new(key, _message(kind, seconds, fields), hashlib.sha256).hexdigest()
    if not hmac.compare_digest(wanted, mac):
        return "its authentication token does not match (another key, or a changed command)"
    return ""


class ReplayGuard:
    """The tokens a receiver has acted on, each remembered for TOKEN_WINDOW (after that `check` refuses
    it as too old anyway): `refusal(token)` is '' the first time and names the replay afterwards."""

    def __init__(self, window: float = TOKEN_WINDOW):
        self.window = window
        self._seen: dict[str, float] = {}   # token -> monotonic time it was taken
        self._lock = threading.Lock()

    def refusal(self, token: str, now: float | None = None) -> str:
        """'' when `token` has not been taken before (it is remembered now), else why it is refused."""
        now = time.monotonic() if now is None else now
        with self._lock:   # a token passes `check` from window before to window after its stamp
            self._seen = {t: at for t, at in self._seen.items() if now - at <= 2 * self.window}
            if token in self._seen:
                return "its authentication token was used before (a replayed command)"
            self._seen[token] = now
        return ""


def networked(env: dict | None = None) -> bool:
    """Whether this process belongs to a networked graph (commands signed and checked)."""
    from perch_common.launch import network_requested

    return network_requested(env)


def waypoint_set_fields(msg) -> list:
    """What a waypoint set's token binds: the mission and every waypoint's numbers and frame."""
    fields: list = [bytes(bytearray(msg.mission_id.uuid)).hex(), msg.header.frame_id, len(msg.waypoints)]
    for w in msg.waypoints:
        p, q, a = w.pose.pose.position, w.pose.pose.orientation, w.approach
        fields += [w.drone_index, w.proposal_id, w.pose.header.frame_id, p.x, p.y, p.z, q.x, q.y, q.z, q.w,
                   a.x, a.y, a.z, w.pan, w.tilt, w.zoom]
    return fields


_process_key: bytes | None = None


def process_key() -> bytes:
    """This process's key (loaded, or created, once)."""
    global _process_key
    if _process_key is None:
        _process_key = load_key()
    return _process_key


def sign_if_networked(kind: str, *fields) -> str:
    """A token for the command when this process is networked, else ''."""
    return sign(process_key(), kind, *fields) if networked() else ""


def refusal_if_networked(token: str, kind: str, *fields) -> str:
    """Why a networked process refuses the command ('' when it is accepted or the graph is host-only)."""
    if not networked():
        return ""
    try:
        return check(process_key(), token, kind, *fields)
    except (OSError, AuthError) as exc:
        return f"this node cannot check it: {exc}"
