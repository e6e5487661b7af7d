"""Exceptions raised by the Paddock client.

Every error the broker or a worker sends back arrives as a subclass of
:class:`ServerError` chosen by its code, carrying the server's ``code``, ``field`` (the
offending field path, e.g. ``"env_step.actions[3]"``) and ``message``.
"""

from __future__ import annotations


class PaddockError(Exception):
    """Base class of every exception this package raises."""


class BrokerUnavailable(PaddockError):
    """No reply from the broker within the timeout (it is down, unreachable or stuck)."""

    def __init__(self, endpoint: str, timeout: float, what: str) -> None:
        self.endpoint = endpoint
        self.timeout = timeout
        super().__init__(
            f"no reply from the Paddock broker at {endpoint} within {timeout:g} s "
            f"(waiting for the reply to {what}); is it running and reachable?"
        )


class BrokerNotAnswering(BrokerUnavailable):
    """A request (a rollout batch) went quiet and the broker answered no status request
    within the timeout: it is down, unreachable or stuck. A broker that restarts is
    not this error: the batch is sent again (:mod:`paddock.resume`)."""

    def __init__(self, endpoint: str, timeout: float, what: str) -> None:
        PaddockError.__init__(
            self,
            f"the Paddock broker at {endpoint} does not answer: no reply to a status request "
            f"within {timeout:g} s while {what} ran; is it running and reachable?"
        )
        self.endpoint = endpoint
        self.timeout = timeout


class BrokerRestarted(PaddockError):
    """The broker restarted (a new instance id) after every one of ``sends`` sends of a
    request: the client gave up sending it again."""

    def __init__(self, endpoint: str, sends: int, what: str) -> None:
        self.endpoint = endpoint
        self.sends = sends
        super().__init__(
            f"the Paddock broker at {endpoint} restarted after each of {sends} sends of "
            f"{what}: gave up"
        )


class KeyRefused(PaddockError):
    """The broker's authenticator refused this client's CURVE key (or the CURVE handshake
    failed): reported as soon as the handshake fails, not after the reply timeout."""

    def __init__(self, endpoint: str, fingerprint: str, detail: str) -> None:
        self.endpoint = endpoint
        self.fingerprint = fingerprint
        super().__init__(
            f"the Paddock broker at {endpoint} refused this client's key "
            f"(fingerprint {fingerprint}): {detail}"
        )


class ServerError(PaddockError):
    """An error reply from the broker or a worker."""

    code_name = "ERROR_CODE_UNSPECIFIED"

    def __init__(self, code: int, field: str, message: str) -> None:
        self.code = code
        self.field = field
        self.message = message
        where = f" [{field}]" if field else ""
        super().__init__(f"{self.code_name}{where}: {message}")


class BadMessage(ServerError):
    code_name = "BAD_MESSAGE"


class UnsupportedVersion(ServerError):
    code_name = "UNSUPPORTED_VERSION"


class UnknownType(ServerError):
    code_name = "UNKNOWN_TYPE"


class InvalidArgument(ServerError, ValueError):
    code_name = "INVALID_ARGUMENT"


class NotFound(ServerError):
    code_name = "NOT_FOUND"




class Busy(ServerError):
    code_name = "BUSY"


class TooLarge(ServerError):
    code_name = "TOO_LARGE"


class Cancelled(ServerError):
    code_name = "CANCELLED"


class Internal(ServerError):
    code_name = "INTERNAL"


_BY_CODE: dict[int, type[ServerError]] = {
    1: BadMessage,
    2: UnsupportedVersion,
    3: UnknownType,
    4: InvalidArgument,
    5: NotFound,
    6: Busy,
    7: TooLarge,
    8: Cancelled,
    9: Internal,
}


class SessionLost(ServerError):
    """The worker hosting an env session died (the broker answers NOT_FOUND, or INTERNAL
    for a request that was in flight); the episode cannot continue: open a new env."""

    def __init__(self, code: int, field: str, message: str) -> None:
        self.code_name = _BY_CODE.get(code, ServerError).code_name
        super().__init__(code, field, message)


def from_reply(code: int, field: str, message: str) -> ServerError:
    """The exception for an error reply."""
    if "session" in message and "was lost" in message:
        return SessionLost(code, field, message)
    return _BY_CODE.get(code, ServerError)(code, field, message)


class JobFailed(PaddockError):
    """A job ended in the FAILED or CANCELLED state."""

    def __init__(self, job_id: str, state: str, error: str) -> None:
        self.job_id = job_id
        self.state = state
        self.error = error
        super().__init__(f"job {job_id} ended {state}: {error}")


class ServerStartError(PaddockError):
    """A local `paddock serve` could not be started."""
