"""Operator commands into the station, and what became of each (`CommandOutcome`).

A face hands a command to `HoistPipeline.submit` (or `Station.submit`) from any thread; the
station carries it out at its next pump and settles the `concurrent.futures.Future` that
`submit` returned with the command's `CommandOutcome`: carried out, or refused and why. The
face that sent a command learns its outcome from that future (`outcome_within` in an asyncio
loop), never from the events; a refusal is also published as a `refused` event, for the log
and the other faces.
"""
from __future__ import annotations

import asyncio
import concurrent.futures
from dataclasses import dataclass, field
from typing import ClassVar

#: how long a face waits for the station to carry out its command before it answers without
#: the outcome (the station still carries it out; the log has it)
OUTCOME_WAIT_S = 2.0


@dataclass(frozen=True)
class Command:
    """An operator action; `operator` says who, `via` where from (terminal, web, OPC UA)."""

    operator: str
    via: str
    action: ClassVar[str] = ""      # the event's action when carried out (`CommandOutcome.action`)

    @property
    def target(self) -> str:
        """What the command acts on: an alarm id (or kind, "*"), or "rewound:nN" for a node."""
        return str(getattr(self, "alarm", ""))


@dataclass(frozen=True)
class Acknowledge(Command):
    action: ClassVar[str] = "ack"
    alarm: str = "*"          # an alarm id, a kind, or "*" for all


@dataclass(frozen=True)
class Shelve(Command):
    """Shelve one alarm for `minutes` with a reason (it returns by itself)."""

    action: ClassVar[str] = "shelve"
    alarm: str = ""
    minutes: float = 0.0
    reason: str = ""


@dataclass(frozen=True)
class Unshelve(Command):
    action: ClassVar[str] = "unshelve"
    alarm: str = ""


@dataclass(frozen=True)
class RemoveFromService(Command):
    """Take one alarm out of service (maintenance) with a reason, until returned."""

    action: ClassVar[str] = "out_of_service"
    alarm: str = ""
    reason: str = ""


@dataclass(frozen=True)
class ReturnToService(Command):
    action: ClassVar[str] = "in_service"
    alarm: str = ""


@dataclass(frozen=True)
class AcceptRewound(Command):
    """Trust `node` although its boot counter went back (flash wiped or replaced)."""

    action: ClassVar[str] = "accept"
    node: int = 0
    how: str = "interactively"

    @property
    def target(self) -> str:
        return f"rewound:n{self.node}"


@dataclass(frozen=True)
class CommandOutcome:
    """What became of one command: carried out (`ok`), or refused with the `reason`."""

    ok: bool
    alarm: str                      # what the command named (`Command.target`)
    action: str                     # the command's action: ack, shelve, unshelve, out_of_service, ...
    reason: str | None = None       # why it was refused; None when carried out
    command: Command | None = field(default=None, compare=False, repr=False)

    @classmethod
    def done(cls, command: Command) -> "CommandOutcome":
        return cls(True, command.target, command.action, None, command)

    @classmethod
    def refused(cls, command: Command, reason: str) -> "CommandOutcome":
        return cls(False, command.target, command.action, reason, command)


Ticket = concurrent.futures.Future   # settled with the command's CommandOutcome by the station


def settle(ticket: Ticket, outcome: CommandOutcome) -> None:
    """Give `ticket` its outcome (once; a ticket given up on by its face is left alone)."""
    try:
        ticket.set_result(outcome)
    except concurrent.futures.InvalidStateError:
        pass


async def outcome_within(ticket: Ticket, wait_s: float | None = None) -> CommandOutcome | None:
    """The outcome of a submitted command, awaited in an asyncio loop for at most `wait_s`
    (default `OUTCOME_WAIT_S`); None: the station has not carried it out yet (it still will)."""
    try:
        return await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(ticket)),
                                      OUTCOME_WAIT_S if wait_s is None else wait_s)
    except asyncio.TimeoutError:
        return None
