"""Requests that outlive a broker restart: the rules, without sockets or clocks.

A rollout batch is idempotent (its outcomes are a pure function of its scenarios and
seeds), but a broker that restarts loses the batches it was running. The broker draws an
instance id when its process starts (``BrokerStatus.instance``, also carried by
``RolloutProgress``). The client sends a ``StatusRequest`` right before each send of the
batch (the *opening* status, whose answer names the instance that took it), and when
nothing comes for the batch for ``quiet`` seconds it asks for the status again, every
``ping_every`` seconds:

- the instance that holds the batch answers: it is still running there; wait on;
- another instance answers (or the opening status was never answered): the broker
  restarted; send the batch again, at most ``max_resends`` times (the first result of any
  send is the answer: results are taken once, never twice);
- nobody answers within ``answer_within`` seconds: the broker does not answer
  (:class:`paddock.errors.BrokerNotAnswering`).

The same rules as the Rust client's (``paddock_broker::client::Watch``).
"""

from __future__ import annotations

from dataclasses import dataclass

#: What :meth:`Watch.next` asks for.
WAIT, PING, NOT_ANSWERING = "wait", "ping", "not_answering"
#: What a status reply to a ping means.
ALIVE, RESEND, GIVE_UP = "alive", "resend", "give_up"


@dataclass(frozen=True)
class ResumePolicy:
    """How a resumable request watches the broker (seconds)."""

    quiet: float = 3.0
    answer_within: float = 10.0
    ping_every: float = 1.0
    max_resends: int = 3


class Watch:
    """The state of one resumable request; every method takes the time ``now``."""

    def __init__(self, policy: ResumePolicy, now: float) -> None:
        self.policy = policy
        self.holder: str | None = None  # the instance that holds the current send
        self.last_heard = now
        self.asking_since: float | None = None
        self.last_ping = now
        self.sends = 1

    def resent(self, now: float) -> None:
        """The request was sent again."""
        self.sends += 1
        self.holder = None
        self.heard(now)

    def heard(self, now: float) -> None:
        """Anything that shows the request alive."""
        self.last_heard = now
        self.asking_since = None

    def opened(self, now: float, instance: str) -> None:
        """The opening status of the current send was answered by ``instance``."""
        self.holder = instance
        self.heard(now)

    def progress(self, now: float, instance: str) -> None:
        """Progress of the current send from ``instance`` ("" when the broker does not say)."""
        if instance:
            self.holder = instance
        self.heard(now)

    def answered(self, now: float, instance: str) -> str:
        """A status request sent since the current send was answered by ``instance``:
        ``ALIVE``, ``RESEND`` or ``GIVE_UP``."""
        if self.holder == instance:
            self.heard(now)
            return ALIVE
        return GIVE_UP if self.sends > self.policy.max_resends else RESEND

    def next(self, now: float) -> tuple[str, float]:
        """(``WAIT``, seconds), (``PING``, 0) or (``NOT_ANSWERING``, seconds waited)."""
        p = self.policy
        if self.asking_since is None:
            idle = now - self.last_heard
            if idle >= p.quiet:
                self.asking_since = self.last_ping = now
                return PING, 0.0
            return WAIT, p.quiet - idle
        waited = now - self.asking_since
        if waited >= p.answer_within:
            return NOT_ANSWERING, p.answer_within
        since_ping = now - self.last_ping
        if since_ping >= p.ping_every:
            self.last_ping = now
            return PING, 0.0
        return WAIT, min(p.ping_every - since_ping, p.answer_within - waited)
