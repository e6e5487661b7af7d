"""One DEALER connection to a broker: request/reply with ids, timeouts, map uploads.

Every message is a ``paddock.v1.Envelope`` frame (the routing header) and the payload
frames its body announces (an env request's message, an observation's scans, a rollout
result's outcomes). A request carries a fresh request id; the reply with that id is awaited
for at most ``timeout`` seconds (never forever), replies to older requests (answered after
their caller gave up) are dropped, and an error reply is raised as the matching
:mod:`paddock.errors` exception. Payload frames are received without a copy out of
ZeroMQ's messages.
"""

from __future__ import annotations

import hashlib
import itertools
import os
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import zmq
from google.protobuf.message import DecodeError, Message

from . import errors
from . import resume as rs
from ._proto import paddock_pb2 as pb
from .maps import MapBundle, find_map_dir, read_bundle, server_map

#: The largest model file the server accepts (bytes), as ``paddock`` checks it.
MAX_MODEL_BYTES = 64 << 20

PROTOCOL_VERSION = 2
DEFAULT_TIMEOUT = 30.0
IN_PROCESS = "in-process"
"""The ``endpoint`` of envs whose simulator runs inside this process (:mod:`paddock.inprocess`)."""


Z85_ALPHABET = "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ.-:+=^!/*?&<>()[]{}@%$#"


def _check_z85_key(value: str) -> str | None:
    """What is wrong with a Z85 CURVE key (never repeating it: it may be secret), or None."""
    if len(value) != 40:
        return f"has {len(value)} characters; a Z85 CURVE key has 40"
    for i, c in enumerate(value):
        if c not in Z85_ALPHABET:
            return f"character {i + 1} is not in the Z85 alphabet"
    for g in range(0, 40, 5):
        n = 0
        for c in value[g:g + 5]:
            n = n * 85 + Z85_ALPHABET.index(c)
        if n >= 1 << 32:
            return f"characters {g + 1}..{g + 5} overflow 32 bits"
    return None


def read_model(path: str) -> bytes:
    """The bytes of the ONNX model file ``path``, at most ``MAX_MODEL_BYTES``; ValueError
    naming the driver otherwise."""
    try:
        size = os.path.getsize(path)
        if size > MAX_MODEL_BYTES:
            raise ValueError(f"{path}: {size} bytes is over the {MAX_MODEL_BYTES}-byte "
                             "model limit")
        with open(path, "rb") as f:
            return f.read()
    except OSError as e:
        raise ValueError(f"driver {path!r}: cannot read the model file: {e}") from e


def fingerprint(public: bytes) -> str:
    """The first 8 hex digits of the SHA-256 of a Z85 public key's 32 bytes: the same
    fingerprint the broker logs when it refuses a key and the ``paddock`` CLI reports."""
    import hashlib

    from zmq.utils import z85

    return hashlib.sha256(z85.decode(public)).hexdigest()[:8]


def _read_keys(path: str) -> dict[str, bytes]:
    """The checked Z85 keys (``public``, ``secret``) of a key file written by ``paddock keys
    generate``; a secret key must belong to the file's public key."""
    try:
        text = open(path, encoding="utf-8").read()
    except OSError as e:
        raise errors.PaddockError(f"key file {path}: {e}") from e
    keys: dict[str, bytes] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if line.startswith("#") or "=" not in line:
            continue
        key, _, value = line.partition("=")
        name = key.strip().removesuffix("-key")
        value = value.strip().strip('"')
        if name not in ("public", "secret"):
            raise errors.PaddockError(f"key file {path}: line {n}: unknown entry {key.strip()!r}")
        wrong = _check_z85_key(value)
        if wrong is not None:
            raise errors.PaddockError(f"key file {path}: line {n}: field `{name}`: {wrong}")
        keys[name] = value.encode()
    if "secret" in keys:
        if "public" not in keys:
            raise errors.PaddockError(f"key file {path}: no `public = \"...\"` line beside the secret key")
        derived = zmq.curve_public(keys["secret"])
        if derived != keys["public"]:
            raise errors.PaddockError(
                f"key file {path}: field `secret`: its public key (fingerprint {fingerprint(derived)}) "
                f"is not the file's `public` (fingerprint {fingerprint(keys['public'])}): "
                "the two halves come from different key pairs")
    return keys


def _read_key(path: str, name: str) -> bytes:
    """The Z85 value of ``name = "..."`` in a key file written by ``paddock keys generate``."""
    value = _read_keys(path).get(name)
    if value is None:
        raise errors.PaddockError(f"key file {path}: no `{name} = \"...\"` line")
    return value


def curve_keys() -> tuple[bytes, bytes, bytes] | None:
    """CURVE keys from ``PADDOCK_KEY_FILE`` (this client's key file) and
    ``PADDOCK_BROKER_KEY_FILE`` (the broker's public key file), the same variables the
    ``paddock`` CLI reads; None when neither is set (plain TCP)."""
    import os

    key_file = os.environ.get("PADDOCK_KEY_FILE")
    broker_file = os.environ.get("PADDOCK_BROKER_KEY_FILE")
    if not key_file and not broker_file:
        return None
    if not (key_file and broker_file):
        raise errors.PaddockError("PADDOCK_KEY_FILE and PADDOCK_BROKER_KEY_FILE must be set together")
    return (_read_key(key_file, "public"), _read_key(key_file, "secret"), _read_key(broker_file, "public"))


def _token_path() -> str | None:
    """Where this user's client token is kept (the same file the ``paddock`` CLI uses):
    ``PADDOCK_CLIENT_TOKEN_FILE``, else ``$XDG_CONFIG_HOME/paddock/client-token``, else
    ``~/.config/paddock/client-token``."""
    import os

    explicit = os.environ.get("PADDOCK_CLIENT_TOKEN_FILE")
    if explicit:
        return explicit
    config = os.environ.get("XDG_CONFIG_HOME") or (
        os.path.join(os.environ["HOME"], ".config") if os.environ.get("HOME") else None)
    return os.path.join(config, "paddock", "client-token") if config else None


def client_token() -> bytes:
    """This user's client token (32 random bytes, 64 hex digits in a 0600 file made on
    first use): who this client is to a broker without CURVE, so its jobs and env
    sessions are its own. Empty when there is nowhere to keep it."""
    import os
    import secrets

    path = _token_path()
    if path is None:
        return b""
    try:
        with open(path, encoding="ascii") as f:
            text = f.read().strip()
    except FileNotFoundError:
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        text = secrets.token_hex(32)
        tmp = f"{path}.tmp-{os.getpid()}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w", encoding="ascii") as f:
            f.write(text + "\n")
        try:
            os.link(tmp, path)  # never overwrites a token another process made first
        except FileExistsError:
            with open(path, encoding="ascii") as f:
                text = f.read().strip()
        finally:
            os.unlink(tmp)
    except OSError:
        return b""
    try:
        token = bytes.fromhex(text)
    except ValueError as e:
        raise errors.PaddockError(f"client token file {path}: not 64 hex digits") from e
    if len(token) != 32:
        raise errors.PaddockError(f"client token file {path}: {len(text)} characters, not 64 hex digits")
    return token


# why a connection or an env session refuses pickle and copy.deepcopy: it is a live
# session on a server's worker or in this process's library, not data
NOT_PICKLED = ("a Paddock env or client holds a live connection to its simulator (a server, or "
               "this process's library) and cannot be pickled or copied: make a new one from "
               "the same arguments where it is needed (for a registered env, "
               "gymnasium.make(env.spec))")

class MapsAndModels:
    """The maps and ONNX models a transport hands to env sessions, each handed over once:
    :meth:`map_ref` and :meth:`driver_name`, for a server (:class:`Connection`) and for
    the simulator in this process (:class:`paddock.inprocess.InProcess`), which differ
    only in how a map bundle or a model's bytes get there (``_put_map``, ``_put_model``)
    and in the maps they ship (``status``)."""

    def __init__(self) -> None:
        self._maps: dict[str, pb.MapRef] = {}
        self._models: dict[str, str] = {}

    def __getstate__(self) -> Any:
        raise TypeError(NOT_PICKLED)

    def _put_map(self, bundle: MapBundle) -> pb.MapRef:
        raise NotImplementedError

    def _put_model(self, path: str, data: bytes) -> str:
        raise NotImplementedError

    def status(self, timeout: float | None = None) -> pb.BrokerStatus:
        raise NotImplementedError

    def map_ref(self, map: str) -> pb.MapRef:
        """The reference of map ``map``: a map on this machine (a directory, a map YAML,
        a folder in ``PADDOCK_MAPS``) is handed over once; otherwise the name of a map
        shipped with the simulator (from :meth:`status`)."""
        ref = self._maps.get(map)
        if ref is None:
            d = find_map_dir(map)
            if d is not None:
                ref = self._put_map(read_bundle(map, d))
            else:
                ref = server_map(map, list(self.status().maps))
            self._maps[map] = ref
        return ref

    def driver_name(self, driver: str | os.PathLike[str]) -> str:
        """The driver name a scenario or env open carries: a driver's name as given, or
        for an ONNX model file (``*.onnx``) ``onnx:<sha256>`` of its bytes, the model
        handed over once."""
        text = os.fspath(driver)
        if not text.lower().endswith(".onnx"):
            return text
        name = self._models.get(text)
        if name is None:
            name = self._put_model(text, read_model(text))
            self._models[text] = name
        return name


# The longest timeout a socket option takes: ZeroMQ's are whole milliseconds in a C int.
MAX_TIMEOUT = (2**31 - 1) // 1000


def check_timeout(timeout: Any) -> None:
    """Refuses a timeout that is not a number of seconds in ``(0, MAX_TIMEOUT]``, naming it."""
    try:
        ok = 0 < float(timeout) <= MAX_TIMEOUT
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"timeout = {timeout!r} is out of range: must be a number of seconds "
                         f"in (0, {MAX_TIMEOUT}]")


def check_endpoint(endpoint: Any) -> None:
    """Refuses an endpoint a connection cannot use, naming what is wrong: a TCP endpoint
    needs a port in [1, 65535] (ZeroMQ takes ``tcp://host:99999`` and connects to
    nothing, so a typo showed only as a timeout). As the Rust client checks it
    (``paddock_libzmq::check_connect_endpoint``)."""
    if not isinstance(endpoint, str) or "://" not in endpoint:
        raise ValueError(f"endpoint {endpoint!r} is not a ZeroMQ endpoint like tcp://HOST:PORT")
    transport, address = endpoint.split("://", 1)
    if transport != "tcp":
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host:
        raise ValueError(f"endpoint {endpoint!r} has no host and port (tcp://HOST:PORT)")
    if not (port.isdigit() and 1 <= int(port) <= 65535):
        raise ValueError(f"endpoint {endpoint!r}: port {port} is out of range: must be a whole "
                         "number in [1, 65535]")


class Connection(MapsAndModels):
    """A DEALER socket connected to a broker's client endpoint (not thread-safe: one
    request at a time; a lock serialises callers)."""

    def __init__(self, endpoint: str, timeout: float = DEFAULT_TIMEOUT,
                 context: zmq.Context | None = None) -> None:
        if endpoint == IN_PROCESS:
            raise ValueError(f"endpoint {endpoint!r} (paddock.IN_PROCESS) runs env sessions in "
                             "this process only; batch rollouts and jobs need a server "
                             "(endpoint=None starts a local one)")
        check_endpoint(endpoint)
        check_timeout(timeout)
        self.endpoint = endpoint
        self.timeout = float(timeout)
        self._ctx = context or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        super().__init__()
        self._sock: zmq.Socket | None = None
        self._monitor: zmq.Socket | None = None
        self._fingerprint = ""
        self._token = client_token()
        self._connect()

    def _connect(self) -> None:
        s = self._ctx.socket(zmq.DEALER)
        curve = curve_keys()
        if curve is not None:
            public, secret, server = curve
            s.curve_publickey = public
            s.curve_secretkey = secret
            s.curve_serverkey = server
            # a refused key never gets a reply: watch the handshake to say so at once
            self._fingerprint = fingerprint(public)
            self._monitor = s.get_monitor_socket(
                zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL)
        s.setsockopt(zmq.LINGER, 0)
        s.setsockopt(zmq.SNDTIMEO, int(self.timeout * 1000))
        s.connect(self.endpoint)
        self._sock = s

    def close(self) -> None:
        if self._monitor is not None:
            assert self._sock is not None
            self._sock.disable_monitor()
            self._monitor.close(linger=0)
            self._monitor = None
        if self._sock is not None:
            self._sock.close(linger=0)
            self._sock = None

    def __enter__(self) -> "Connection":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send(self, field: str, msg: Message, payload: Iterable[bytes] = ()) -> int:
        """Send one request (and its payload frames); return its id."""
        if self._sock is None:
            raise errors.PaddockError(f"connection to {self.endpoint} is closed")
        rid = next(self._ids)
        env = pb.Envelope(protocol_version=PROTOCOL_VERSION, request_id=rid,
                          client_token=self._token)
        getattr(env, field).CopyFrom(msg)
        # small frames: a copy is cheaper than zero-copy
        frames = [env.SerializeToString(), *payload]
        if self._monitor is not None:
            self._send_watched(field, frames)
            return rid
        try:
            self._sock.send_multipart(frames)
        except zmq.Again as e:
            raise errors.BrokerUnavailable(self.endpoint, self.timeout, field) from e
        return rid

    def _send_watched(self, field: str, frames: list[bytes]) -> None:
        """Sends ``frames`` with CURVE, watching the handshake: a key refused while the
        connection sat idle leaves no connection to send on, and a blocking send would
        wait its whole timeout there. ZeroMQ keeps reconnecting meanwhile, each attempt
        refused again, so the socket can be writable when polled and have no connection
        an instant later: the send does not block, and on ``Again`` the wait resumes,
        watching for the refusal."""
        assert self._sock is not None
        deadline = time.monotonic() + self.timeout
        while True:
            left_ms = int((deadline - time.monotonic()) * 1000)
            if left_ms <= 0 or not self._ready(zmq.POLLOUT, left_ms):
                raise errors.BrokerUnavailable(self.endpoint, self.timeout, field)
            try:
                self._sock.send_multipart(frames, flags=zmq.NOBLOCK)
                return
            except zmq.Again:
                time.sleep(0.001)  # the connection went between the poll and the send

    def receive(self, rid: int, what: str,
                timeout: float | None = None) -> tuple[str, Message, list[zmq.Frame]]:
        """The next reply to request ``rid`` as (body name, message, payload frames)."""
        assert self._sock is not None
        limit = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        while True:
            left = deadline - time.monotonic()
            ready = left > 0 and self._ready(zmq.POLLIN, max(1, int(left * 1000)))
            if not ready:
                # a late reply must not be read as the answer to a later request: start over
                self.close()
                self._connect()
                raise errors.BrokerUnavailable(self.endpoint, limit, what)
            # no copy out of ZeroMQ's messages: an observation's scans are a view of one
            frames = self._sock.recv_multipart(copy=False)
            env = pb.Envelope()
            try:
                env.ParseFromString(frames[0].buffer)
            except DecodeError:
                continue
            if env.request_id != rid:
                continue  # the reply to a request its caller gave up on
            body = env.WhichOneof("body")
            if body is None:
                raise errors.BadMessage(1, "body", f"reply to {what} has no body")
            msg = getattr(env, body)
            if body == "error":
                raise errors.from_reply(msg.code, msg.field, msg.message)
            if body == "env_reply" and msg.HasField("error"):
                e = msg.error
                raise errors.from_reply(e.code, e.field, e.message)
            return body, msg, frames[1:]

    def _ready(self, flags: int, timeout_ms: int) -> bool:
        """Whether the socket is ready for ``flags`` (``POLLIN``: a reply is waiting;
        ``POLLOUT``: it takes a request) within ``timeout_ms``; raises
        :class:`errors.KeyRefused` as soon as the broker refuses this client's key."""
        assert self._sock is not None
        if self._monitor is None:
            return bool(self._sock.poll(timeout_ms, flags))
        poller = zmq.Poller()
        poller.register(self._sock, flags)
        poller.register(self._monitor, zmq.POLLIN)
        deadline = time.monotonic() + timeout_ms / 1000
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            ready = dict(poller.poll(max(1, int(left * 1000))))
            # the refusal first: the socket can look ready between two refused attempts
            if self._monitor in ready:
                self._refused()
            if self._sock in ready:
                return True

    def _refused(self) -> None:
        """Raises :class:`errors.KeyRefused` for the handshake failure waiting in the
        monitor."""
        assert self._monitor is not None
        from zmq.utils.monitor import recv_monitor_message

        event = recv_monitor_message(self._monitor)
        if event["event"] == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
            detail = (f"ZAP status {event['value']}: its public key is not in the "
                      "broker's allowed client keys")
        else:
            detail = (f"CURVE handshake failed (protocol error {event['value']:#x}): check "
                      "the broker's public key file and that the broker uses CURVE")
        raise errors.KeyRefused(self.endpoint, self._fingerprint, detail)

    def request(self, field: str, msg: Message, expect: str | Iterable[str],
                timeout: float | None = None,
                on_other: Callable[[str, Message], None] | None = None) -> Message:
        """Send ``msg`` as body ``field`` and return the reply whose body is ``expect``;
        other bodies with the same id (progress) go to ``on_other``."""
        return self.request_frames(field, msg, expect, timeout, on_other)[0]

    def request_frames(self, field: str, msg: Message, expect: str | Iterable[str],
                       timeout: float | None = None,
                       on_other: Callable[[str, Message], None] | None = None,
                       payload: Iterable[bytes] = ()) -> tuple[Message, list[zmq.Frame]]:
        """:meth:`request` with payload frames both ways: the reply's message and frames."""
        wanted = {expect} if isinstance(expect, str) else set(expect)
        with self._lock:
            rid = self.send(field, msg, payload)
            while True:
                body, reply, frames = self.receive(rid, field, timeout)
                if body in wanted:
                    return reply, frames
                if on_other is not None:
                    on_other(body, reply)
                    continue
                raise errors.UnknownType(3, "body", f"unexpected reply {body} to {field}")

    def request_resumable(self, field: str, msg: Message, expect: str,
                          policy: rs.ResumePolicy | None = None, timeout: float | None = None,
                          on_progress: Callable[[Message], None] | None = None,
                          ) -> tuple[Message, list[zmq.Frame]]:
        """Send an idempotent request (a rollout batch) and return its reply and payload
        frames, through restarts of the broker (:mod:`paddock.resume`): the request is
        sent again when another broker instance answers, and a broker that answers no
        status request within ``policy.answer_within`` (default: this connection's
        timeout) raises :class:`errors.BrokerNotAnswering`. ``timeout``: a bound on the
        whole wait (None: as long as the broker answers). ``on_progress`` sees the
        current send's ``RolloutProgress`` messages."""
        policy = policy or rs.ResumePolicy(answer_within=self.timeout)
        status = pb.StatusRequest()
        with self._lock:
            deadline = None if timeout is None else time.monotonic() + timeout
            opening = self.send("status_request", status)
            current = self.send(field, msg)
            sends = {current}
            pings: set[int] = set()  # status requests since the current send
            watch = rs.Watch(policy, time.monotonic())
            while True:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    self._restart()
                    raise errors.BrokerUnavailable(self.endpoint, float(timeout or 0), field)
                step, value = watch.next(now)
                if step == rs.PING:
                    pings.add(self.send("status_request", status))
                    continue
                if step == rs.NOT_ANSWERING:
                    self._restart()
                    raise errors.BrokerNotAnswering(self.endpoint, value, field)
                if deadline is not None:
                    value = min(value, deadline - now)
                if not self._ready(zmq.POLLIN, max(1, int(value * 1000))):
                    continue
                frames = self._sock.recv_multipart(copy=False)  # type: ignore[union-attr]
                env = pb.Envelope()
                try:
                    env.ParseFromString(frames[0].buffer)
                except DecodeError:
                    continue
                rid, body, now = env.request_id, env.WhichOneof("body"), time.monotonic()
                if rid == opening or rid in pings:
                    if body != "broker_status":
                        continue
                    instance = env.broker_status.instance
                    if rid == opening:
                        watch.opened(now, instance)
                        continue
                    answer = watch.answered(now, instance)
                    if answer == rs.GIVE_UP:
                        self._restart()
                        raise errors.BrokerRestarted(self.endpoint, watch.sends, field)
                    if answer == rs.RESEND:
                        pings.clear()
                        opening = self.send("status_request", status)
                        current = self.send(field, msg)
                        sends.add(current)
                        watch.resent(now)
                    continue
                if rid not in sends:
                    continue  # a reply to an earlier request, or an earlier opening status
                if body is None:
                    raise errors.BadMessage(1, "body", f"reply to {field} has no body")
                reply = getattr(env, body)
                if body == "error":
                    raise errors.from_reply(reply.code, reply.field, reply.message)
                if body == expect:
                    return reply, frames[1:]
                if body != "rollout_progress":
                    raise errors.UnknownType(3, "body", f"unexpected reply {body} to {field}")
                if rid == current:
                    watch.progress(now, reply.instance)
                    if on_progress is not None:
                        on_progress(reply)
                else:
                    watch.heard(now)

    def _restart(self) -> None:
        """A new socket: late replies to what was given up never reach later requests."""
        self.close()
        self._connect()

    def env(self, session_id: int, op: int, msg: Message | None = None,
            timeout: float | None = None) -> tuple[pb.EnvReply, list[zmq.Frame]]:
        """A request on env session ``session_id`` (0 to open one): ``op`` (``pb.ENV_OPEN``,
        ...) and its message as the payload frame. The reply's header (with the session id)
        and payload frames; a refusal is raised."""
        header = pb.EnvRequest(session_id=session_id, op=op)
        payload = [] if msg is None else [msg.SerializeToString()]
        reply, frames = self.request_frames("env_request", header, "env_reply", timeout,
                                            payload=payload)
        return reply, frames

    def _put_map(self, bundle: MapBundle) -> pb.MapRef:
        """Uploads a map bundle to the broker (once per connection, see :meth:`map_ref`)."""
        self.request("put_map", pb.PutMap(bundle=bundle.to_proto()), "map_stored")
        return bundle.ref()

    def _put_model(self, path: str, data: bytes) -> str:
        """Stores a model's bytes in the broker (workers fetch it from there by its hash,
        once each); its ``onnx:<sha256>`` name."""
        digest = hashlib.sha256(data).hexdigest()
        stored = self.request("put_blob", pb.PutBlob(data=data), "blob_stored")
        if stored.hash != digest:
            raise errors.ServerError(13, "put_blob.data",
                                     f"the broker stored {path} under hash {stored.hash}, "
                                     f"not its SHA-256 {digest}")
        return f"onnx:{digest}"

    def status(self, timeout: float | None = None) -> pb.BrokerStatus:
        return self.request("status_request", pb.StatusRequest(), "broker_status", timeout)
