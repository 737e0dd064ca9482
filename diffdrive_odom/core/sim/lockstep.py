"""Lockstep: when the loop has answered a step of the simulation. Pure.

In lockstep ``sim_node`` owns the time and moves it on only once every node of the loop
(a *participant*) has answered what the last step sent. An answer is counted, not
stamped: a ``Twist`` on ``cmd_vel`` and a ``Float64MultiArray`` on ``wheel_commands``
carry no stamp to carry through, and a node need not answer every step with a message
(a heartbeat slower than the sim's step, a follower with no path). So each participant
counts, per topic of the loop, the messages it has *sent* and those it has *taken*
(received and handled to the end: whatever it sent in answer was counted first), and
after each message it takes it says so (:class:`Tally`, the answer). The step is
answered when each participant has taken every message the participants, the sim
included, sent on each topic it reads (:func:`lags` is empty): a message still on its
way, or one being handled, leaves its reader's count short, and what it will cause is
then still to be counted. By induction from the sim's own exact counts nothing of the
step is left anywhere, whatever the messages' types, whoever answers and how often.

Before the first step the loop's endpoints must have found each other, or a message
written before its reader was matched is lost and the loop waits for ever
(:func:`unmatched`): each participant also says how many readers each of its writers
has matched, and how many writers each of its readers.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

# The four counts of a tally, as an answer's lines name them: "<kind> <topic> <count>".
SENT, TOOK, READERS, WRITERS = "sent", "took", "readers", "writers"
KINDS = (SENT, TOOK, READERS, WRITERS)
TICKS = "ticks"


@dataclass
class Tally:
    """One participant's counts per topic (fully qualified names): its answer.

    ``ticks``: it runs work of its own at a /clock (a heartbeat, a recorder's step), so
    the readings of a step wait until it has taken that step's /clock.
    """

    sent: dict[str, int] = field(default_factory=dict)  # messages it published
    took: dict[str, int] = field(default_factory=dict)  # messages it took, to the end
    readers: dict[str, int] = field(default_factory=dict)  # readers its writer matched
    writers: dict[str, int] = field(default_factory=dict)  # writers its reader matched
    ticks: bool = False

    def answer(self, name: str) -> str:
        """The answer's text: the participant's name, ``ticks`` if it does, a line per count.

        Plain text, one ``std_msgs/String``: cheap to send and read at every message
        taken, and readable as it is (``ros2 topic echo /lockstep``).
        """
        return "\n".join([name, *([TICKS] if self.ticks else []),
                          *(f"{kind} {topic} {n}" for kind in KINDS
                            for topic, n in getattr(self, kind).items())])

    @classmethod
    def parse(cls, text: str) -> tuple[str, Tally]:
        """The name and the tally :meth:`answer` wrote (ValueError for anything else)."""
        name, *lines = text.split("\n")
        tally = cls()
        for line in lines:
            if line == TICKS:
                tally.ticks = True
                continue
            kind, _, rest = line.partition(" ")
            topic, _, count = rest.rpartition(" ")
            if kind not in KINDS or not topic:
                raise ValueError(f"not a lockstep count: {line!r}")
            getattr(tally, kind)[topic] = int(count)
        return name, tally


def lags(tallies: Mapping[str, Tally], clock: str | None = None) -> list[str]:
    """What keeps the step from being answered, one line per reader and topic short.

    Empty: every participant has taken all the participants sent on the topics it reads.
    A reader may have taken more (a publisher outside the loop): that never holds it up.
    ``clock``: the phase of a step's /clock (this topic), which only the participants that
    tick must have taken (the others take it with the readings that follow).
    """
    sent = _sent(tallies)
    return [f"{name} has taken {n} of the {sent[topic]} messages sent on {topic}"
            for name, tally in tallies.items() for topic, n in tally.took.items()
            if n < sent.get(topic, 0) and (tally.ticks or topic != clock)]


def answered(tallies: Mapping[str, Tally], clock: str | None = None) -> bool:
    """:func:`lags` is empty (asked at every answer the sim hears: no text made)."""
    sent = _sent(tallies)
    return all(n >= sent.get(topic, 0) or (topic == clock and not tally.ticks)
               for tally in tallies.values() for topic, n in tally.took.items())


def _sent(tallies: Mapping[str, Tally]) -> dict[str, int]:
    """Messages sent on each topic by all the participants.

    A plain sum: Counter.update is several times slower, and this runs at every answer.
    """
    sent: dict[str, int] = {}
    for tally in tallies.values():
        for topic, n in tally.sent.items():
            sent[topic] = sent.get(topic, 0) + n
    return sent


def unmatched(tallies: Mapping[str, Tally]) -> list[str]:
    """The loop's endpoints that have not found each other yet, one line each.

    Each writer must have matched every participant that reads its topic, and each
    reader every participant that writes it (more is fine: a recorder, ``ros2 topic
    echo``). Both sides, as each side of DDS matches on its own.
    """
    writers = Counter(topic for tally in tallies.values() for topic in tally.sent)
    readers = Counter(topic for tally in tallies.values() for topic in tally.took)
    out = [f"{name}'s writer on {topic} has matched {n} of the {readers[topic]} readers "
           "in the loop" for name, tally in tallies.items()
           for topic, n in tally.readers.items() if n < readers[topic]]
    out += [f"{name}'s reader on {topic} has matched {n} of the {writers[topic]} writers "
            "in the loop" for name, tally in tallies.items()
            for topic, n in tally.writers.items() if n < writers[topic]]
    return out


def missing(expected: Iterable[str], tallies: Mapping[str, Tally]) -> list[str]:
    """The participants expected that have not answered yet, one line each."""
    return [f"{name} has not answered yet (running, with lockstep: true?)"
            for name in expected if name not in tallies]


def resolve(name: str, namespace: str) -> str:
    """A node name as the participant says it: ``name`` under ``namespace`` unless absolute."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"
