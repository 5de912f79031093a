"""ZeroMQ CURVE authentication and encryption for non-loopback use.

Guarantees (libzmq CURVE, RFC 26 CurveZMQ): with a :class:`CurveServer` applied to a
bound socket, only peers whose public key is in the allowed-clients directory complete
the handshake; everything else is refused before a single message is read or sent
(a PUB sends nothing to them, a PULL receives nothing from them). Traffic is
encrypted and authenticated end to end. Not guaranteed: protection against a client
whose secret key has leaked (remove its public key file and restart the service).

Keys are files in the format pyzmq's ``zmq.auth`` writes (``NAME.key`` public,
``NAME.key_secret`` secret + public); ``streamfix keys DIR`` makes a server pair and
one client pair. The server holds ``server.key_secret`` and a directory of allowed
client ``*.key`` files; each client holds its own ``*.key_secret`` and the server's
``server.key``. The authenticator (a ZAP handler thread) runs per ZeroMQ context, so
every server socket that uses it must share that context.
"""
from __future__ import annotations

import ipaddress
import socket as _socket
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

__all__ = ["CurveServer", "CurveClient", "create_keys", "is_loopback_endpoint"]


def _load(path: str | Path, *, secret: bool) -> tuple[bytes, bytes | None]:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"CURVE key file {p} does not exist (make keys with `streamfix keys DIR`)")
    try:
        public, secret_key = zmq.auth.load_certificate(str(p))
    except (ValueError, OSError) as exc:
        raise ValueError(f"{p} is not a ZeroMQ certificate file: {exc}") from None
    if secret and not secret_key:
        raise ValueError(f"{p} holds no secret key: pass the .key_secret file, not the public .key")
    return public, secret_key


class CurveServer:
    """A bound socket's CURVE identity (``secret_file``) and allowed client keys (``clients_dir``)."""

    def __init__(self, secret_file: str | Path, clients_dir: str | Path) -> None:
        self.public, self.secret = _load(secret_file, secret=True)
        self.clients_dir = Path(clients_dir)
        if not self.clients_dir.is_dir():
            raise FileNotFoundError(f"allowed CURVE client keys: {self.clients_dir} is not a directory")
        self.n_clients = len(list(self.clients_dir.glob("*.key")))
        if self.n_clients == 0:
            raise ValueError(f"{self.clients_dir} holds no client public keys (*.key): nobody could connect")
        self._auth: dict[int, ThreadAuthenticator] = {}

    def start(self, context: zmq.Context) -> None:
        """Run the ZAP authenticator on ``context`` (once per context)."""
        if id(context) in self._auth:
            return
        auth = ThreadAuthenticator(context)
        auth.start()
        auth.configure_curve(domain="*", location=str(self.clients_dir))
        self._auth[id(context)] = auth

    def apply(self, sock: zmq.Socket) -> None:
        """Make ``sock`` (before bind) a CURVE server that authenticates its peers."""
        self.start(sock.context)
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_server = True

    def stop(self) -> None:
        for auth in self._auth.values():
            auth.stop()
        self._auth.clear()


class CurveClient:
    """A connecting socket's CURVE key pair (``secret_file``) and the server's public key."""

    def __init__(self, secret_file: str | Path, server_public_file: str | Path) -> None:
        self.public, self.secret = _load(secret_file, secret=True)
        self.server_public, _ = _load(server_public_file, secret=False)

    def apply(self, sock: zmq.Socket) -> None:
        """Make ``sock`` (before connect) a CURVE client of the server."""
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_serverkey = self.server_public


def create_keys(directory: str | Path, names: tuple[str, ...] = ("server", "client")) -> list[Path]:
    """Write a key pair per name into ``directory`` (``NAME.key``, ``NAME.key_secret``); refuses to overwrite."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    for name in names:
        for suffix in (".key", ".key_secret"):
            if (d / f"{name}{suffix}").exists():
                raise FileExistsError(f"{d / (name + suffix)} exists; not overwriting a key")
    made: list[Path] = []
    for name in names:
        public, secret = zmq.auth.create_certificates(str(d), name)
        Path(secret).chmod(0o600)
        made.extend([Path(public), Path(secret)])
    return made


def is_loopback_endpoint(endpoint: str) -> bool:
    """True if ``endpoint`` can only be reached from this machine (loopback TCP, ipc, inproc)."""
    scheme, _, rest = endpoint.partition("://")
    if scheme in ("ipc", "inproc"):
        return True
    host = rest.rsplit(":", 1)[0].strip("[]")
    if host in ("*", "", "0.0.0.0", "::"):
        return False
    if ";" in host:  # source;destination form: the destination decides
        host = host.split(";")[-1]
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # an interface or host name: resolve it
        try:
            return all(ipaddress.ip_address(a[4][0]).is_loopback for a in _socket.getaddrinfo(host, None))
        except (OSError, ValueError):
            return False
