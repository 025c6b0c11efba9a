"""CurveZMQ on the bus's tcp sockets: key files, server/client socket options, ZAP authentication.

A graph's ``security:`` section names one key pair (``key:``, the ``.key_secret`` file written by
``mocapgraph keys generate``) and a folder of public keys allowed to connect (``authorized:``).
Every tcp publisher is a CURVE server with that pair and authenticates connecting subscribers
against the folder through ZAP (pyzmq's ``zmq.auth``); every subscriber of a tcp endpoint is a
CURVE client with the same pair. ipc sockets stay plaintext: they live in the 0700 run directory.
Without the right keys a subscriber's handshake fails and it receives nothing, and what crosses
the wire is encrypted.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import zmq
import zmq.auth

if TYPE_CHECKING:   # imported by start_authenticator: its asyncio costs every node ~40 ms, most have no keys
    from zmq.auth.thread import ThreadAuthenticator


class KeyError_(ValueError):
    """A key file or folder that cannot be used."""


@dataclass(frozen=True)
class CurveKeys:
    """The graph's key pair (z85 bytes) and the folder of public keys allowed to connect."""

    public: bytes
    secret: bytes
    authorized: str

    @classmethod
    def load(cls, secret_file: str, authorized: str) -> "CurveKeys":
        try:
            public, secret = zmq.auth.load_certificate(secret_file)
        except (OSError, ValueError) as exc:
            raise KeyError_(f"cannot read key {secret_file}: {exc}") from None
        if secret is None:
            raise KeyError_(f"{secret_file} holds no secret key (name the .key_secret file)")
        if not Path(authorized).is_dir() or not list(Path(authorized).glob("*.key")):
            raise KeyError_(f"{authorized} is not a folder of public keys (*.key)")
        return cls(public, secret, str(authorized))

    def to_wiring(self) -> dict[str, str]:
        return {"public": self.public.decode(), "secret": self.secret.decode(), "authorized": self.authorized}

    @classmethod
    def from_wiring(cls, d: dict[str, str] | None) -> "CurveKeys | None":
        return None if not d else cls(d["public"].encode(), d["secret"].encode(), d["authorized"])


def generate(folder: str | Path, name: str) -> tuple[Path, Path]:
    """Write ``name.key`` (public) and ``name.key_secret`` (0600) in ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    public, secret = zmq.auth.create_certificates(str(folder), name)
    Path(secret).chmod(0o600)
    return Path(public), Path(secret)


_auth_lock = threading.Lock()
_authenticators: dict[int, ThreadAuthenticator] = {}
_users: dict[int, int] = {}   # nodes of this process using each context's handler


def start_authenticator(ctx: zmq.Context, keys: CurveKeys) -> None:
    """One ZAP handler per context: accept clients whose public key is in ``keys.authorized``.
    Each call is one user of it (the nodes of a ``process:`` group share the context)."""
    with _auth_lock:
        _users[id(ctx)] = _users.get(id(ctx), 0) + 1
        if id(ctx) in _authenticators:
            return
        from zmq.auth.thread import ThreadAuthenticator
        auth = ThreadAuthenticator(ctx)
        auth.start()
        auth.configure_curve(domain="*", location=keys.authorized)
        _authenticators[id(ctx)] = auth


def release_authenticator(ctx: zmq.Context) -> None:
    """One user fewer; the handler stops with its last (a node that stops alone leaves the others'
    sockets guarded)."""
    with _auth_lock:
        left = _users.get(id(ctx), 0) - 1
        if left > 0:
            _users[id(ctx)] = left
            return
        _users.pop(id(ctx), None)
        auth = _authenticators.pop(id(ctx), None)
        if auth is not None:
            auth.stop()


def make_server(sock: zmq.Socket, keys: CurveKeys) -> None:
    """A publisher that only talks CURVE to authorised clients (call before bind)."""
    sock.curve_secretkey = keys.secret
    sock.curve_publickey = keys.public
    sock.curve_server = True


def make_client(sock: zmq.Socket, keys: CurveKeys, server_public: bytes | None = None) -> None:
    """A subscriber that connects with CURVE (call before connect); the server's key is the graph's."""
    sock.curve_secretkey = keys.secret
    sock.curve_publickey = keys.public
    sock.curve_serverkey = server_public or keys.public
