"""Lockstep on DDS: the nodes of a simulated loop answer each step, ``sim_node`` waits for them.

:mod:`diffdrive_odom.core.sim.lockstep` says when a step is answered; here the counts are
kept and the answers sent. A node takes its loop's endpoints, clock and timers from
:func:`join`: with ``lockstep`` false it gets :class:`Alone`, which changes nothing (the
node's own QoS, the steady clock, a steady timer: a robot's node as before); with it true
a :class:`Participant`, which

- takes ``/clock`` itself, reliably, sets the node's clock to it, then runs the node's
  timers that are due (on simulated time, inside that message: a heartbeat answers the
  step it belongs to, never the next);
- gives reliable subscriptions deep enough for a step (:data:`LOOP_QOS`), counts what the
  node sends and takes on them, and answers on :data:`ANSWER_TOPIC` (``std_msgs/String``:
  the node's name, then a line per count, ``sent /odom 12``: readable with ``ros2 topic
  echo``) once it has taken all that is ready (:func:`settle`, called by the spin loop
  after each message: a step's burst of messages gets one answer, not one each).

``sim_node`` in lockstep holds a :class:`Conductor`: it counts the sim's own messages,
reads the answers, and calls the sim's next phase once the loop has answered the last;
a steady guard names what the loop still owes when an answer is late.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile
from rclpy.subscription import Subscription
from rclpy.time import Time
from rclpy.timer import Timer
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import String

from diffdrive_odom.core.sim.lockstep import (
    Tally,
    answered,
    lags,
    missing,
    resolve,
    unmatched,
)
from diffdrive_odom.ros.qos import qos
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.wire import cdr
from diffdrive_odom.wire.conversions import stamp_to_ns

ANSWER_TOPIC = "/lockstep"
# Each participant's last answer is what counts: latched, so a sim started late hears it.
ANSWER_OUT_QOS = qos(1, reliable=True, latched=True)
ANSWER_IN_QOS = qos(100, reliable=True, latched=True)  # several participants' at once
# The loop's subscriptions in lockstep: nothing may be lost (the loop would wait for it),
# and a step sends a handful per topic (a latched topic stays latched: its last message,
# sent before the reader matched, is counted by the writer).
LOOP_DEPTH = 100
LOOP_QOS = qos(LOOP_DEPTH, reliable=True)
CLOCK_TOPIC = "/clock"
POLL_S = 0.1  # [s, steady] how often a participant looks whether its counts changed unasked
GUARD_S = 5.0  # [s, wall] an answer this late is named (again each GUARD_S)
START_SETTLE_S = 0.5  # [s, wall] the loop stays matched this long before the first step

# Messages a settle() takes before it answers anyway (a stream that never pauses).
SETTLE_MAX = 50

Publish = Callable[[Any], None]


class Loop(Protocol):
    """What a node of a (possibly simulated) loop takes from :func:`join`."""

    clock: Clock  # the clock of the node's own timing: timeouts, limits, ages

    def subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None],
                     qos_profile: QoSProfile, raw: bool = False) -> Subscription:
        """A subscription on a topic of the loop (``qos_profile``: the node's own)."""

    def publish(self, publisher: Publisher) -> Publish:
        """The function that publishes on a topic of the loop through ``publisher``."""

    def timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """A periodic callback of the node's own work (the heartbeat)."""

    def destroy_timer(self, timer: Any) -> None:
        """Stop a timer made by :meth:`timer`."""

    def destroy(self) -> None:
        """Remove what the loop added to the node."""


class Alone:
    """Not in lockstep: the node's own QoS, steady clock and timers, nothing counted."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self.clock = Clock(clock_type=ClockType.STEADY_TIME)

    def subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None],
                     qos_profile: QoSProfile, raw: bool = False) -> Subscription:
        """The node's subscription, with its own QoS."""
        return self._node.create_subscription(msg_type, topic, callback, qos_profile, raw=raw)

    def publish(self, publisher: Publisher) -> Publish:
        """The publisher's own ``publish``."""
        publish: Publish = publisher.publish
        return publish

    def timer(self, period_s: float, callback: Callable[[], None]) -> Timer:
        """A steady timer: a heartbeat must not stop when /clock pauses (use_sim_time)."""
        return self._node.create_timer(period_s, callback, clock=self.clock)

    def destroy_timer(self, timer: Any) -> None:
        """Destroy the rclpy timer."""
        self._node.destroy_timer(timer)

    def destroy(self) -> None:
        """Nothing was added."""


class _SimTimer:
    """A periodic callback on simulated time, run by the /clock message that makes it due.

    As an rcl timer that cannot keep up, it runs once per /clock however many periods
    have passed, and the next one is due a whole number of periods after the first.
    """

    def __init__(self, period_s: float, callback: Callable[[], None]) -> None:
        self.period_ns = max(1, round(period_s * 1e9))
        self.callback = callback
        self.due_ns: int | None = None  # None: at the first /clock

    def run_due(self, now_ns: int) -> None:
        due = self.due_ns
        if due is not None and now_ns < due:
            return
        self.callback()
        if due is None:
            self.due_ns = now_ns + self.period_ns
        else:
            self.due_ns = due + self.period_ns * ((now_ns - due) // self.period_ns + 1)


class _Counts:
    """What a lockstep endpoint counts: its writers and readers on the loop's topics."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self.name = node.get_fully_qualified_name()
        self.tally = Tally()
        self.stepping = False  # the loop has started (the sim's own side knows)
        self._writers: list[tuple[str, Publisher]] = []
        self._readers: list[tuple[str, Subscription]] = []

    def _taken(self, topic: str) -> None:
        """A message was taken to the end: the participant answers, the conductor looks."""

    def _early(self, handle: Callable[[], None], stamp_ns: int | None) -> bool:
        """Hold a message to handle later (True), or let it be handled now."""
        return False

    def subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None],
                     qos_profile: QoSProfile, raw: bool = False) -> Subscription:
        """A reliable subscription whose messages are counted once handled.

        ``qos_profile`` is the node's own, for a robot: lockstep keeps its durability
        and makes it :data:`LOOP_QOS`'s reliable, deep history.
        """
        took = self.tally.took
        name: list[str] = []
        stamp_of = _stamp_reader(msg_type, raw)

        def handle(msg: Any) -> None:
            callback(msg)
            took[name[0]] += 1
            self._taken(name[0])

        def counted(msg: Any) -> None:
            if not self._early(lambda: handle(msg), stamp_of(msg)):
                handle(msg)

        profile = qos(max(LOOP_DEPTH, qos_profile.depth), reliable=True,
                      latched=qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
        sub = self._node.create_subscription(msg_type, topic, counted, profile, raw=raw)
        name.append(sub.topic_name)
        took.setdefault(sub.topic_name, 0)
        self._readers.append((sub.topic_name, sub))
        return sub

    def publish(self, publisher: Publisher) -> Publish:
        """Publishing through ``publisher``, counted (a managed node's only while active)."""
        topic = publisher.topic_name
        sent = self.tally.sent
        sent.setdefault(topic, 0)
        self._writers.append((topic, publisher))

        def counted(msg: Any) -> None:
            if getattr(publisher, "is_activated", True):
                publisher.publish(msg)
                sent[topic] += 1

        return counted

    def matched(self) -> Tally:
        """The tally with how many endpoints each of ours has matched now.

        Only the start needs these: once the loop steps they are left as they were.
        """
        t = self.tally
        if not t.took.get(CLOCK_TOPIC) and not self.stepping:
            t.readers = {topic: pub.get_subscription_count() for topic, pub in self._writers}
            t.writers = {topic: sub.get_publisher_count() for topic, sub in self._readers}
        return t


class Participant(_Counts):
    """A node in lockstep: on the sim's clock, its loop counted, each step answered."""

    def __init__(self, node: Node) -> None:
        super().__init__(node)
        clock = node.get_clock()
        if not getattr(clock, "ros_time_is_active", False):
            raise ParameterError("lockstep", "needs use_sim_time: true (the node runs on "
                                 "the simulation's /clock)")
        self.clock = clock
        self._now = 0  # the last /clock taken [ns]
        self._held: list[Callable[[], None]] = []  # stamped after it: for the next /clock
        self._timers: list[_SimTimer] = []
        # Run at every /clock before the timers: the simulated time now [ns].
        self.on_clock: list[Callable[[int], None]] = []
        self._said = ""
        self.owed = False  # taken messages not answered yet
        _participants.add(self)
        self._answer_pub = node.create_publisher(String, ANSWER_TOPIC, ANSWER_OUT_QOS)
        self._clock_sub = self.subscription(ClockMsg, CLOCK_TOPIC, self._on_clock, LOOP_QOS)
        # Counts can change outside a message (sent at start, endpoints matched): said too.
        self._poll = node.create_timer(POLL_S, self._answer_if_changed,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def timer(self, period_s: float, callback: Callable[[], None]) -> _SimTimer:
        """A timer on simulated time, run inside the /clock message that makes it due."""
        timer = _SimTimer(period_s, callback)
        self._timers.append(timer)
        return timer

    def destroy_timer(self, timer: Any) -> None:
        """Stop a timer of :meth:`timer`."""
        self._timers.remove(timer)

    def destroy(self) -> None:
        """Remove the answers' publisher, the /clock subscription and the poll."""
        _participants.discard(self)
        self._node.destroy_timer(self._poll)
        self._node.destroy_subscription(self._clock_sub)
        self._node.destroy_publisher(self._answer_pub)

    @property
    def ticks(self) -> bool:
        """It has work of its own at a /clock: the step's readings wait until it took it."""
        return bool(self._timers or self.on_clock)

    def _on_clock(self, msg: ClockMsg) -> None:
        now = self._now = stamp_to_ns(msg.clock)
        self.clock.set_ros_time_override(Time(nanoseconds=now, clock_type=ClockType.ROS_TIME))
        held, self._held = self._held, []
        for handle in held:
            handle()
        for hook in tuple(self.on_clock):
            hook(now)
        for timer in tuple(self._timers):
            timer.run_due(now)

    def _early(self, handle: Callable[[], None], stamp_ns: int | None) -> bool:
        """A message stamped after this node's clock came before its /clock: held until then.

        The sim sends a step's /clock before its readings; a node without work of its own
        at a /clock need not have taken it when the readings are sent (the sim waits only
        for those that tick), and two writers' messages may arrive in either order. Its
        next /clock is that step's, so the message is handled at the step's time.
        """
        if stamp_ns is None or stamp_ns <= self._now:
            return False
        self._held.append(handle)
        return True

    def _taken(self, topic: str) -> None:
        global _taken_here
        _taken_here += 1
        # answered by settle() once nothing more is ready (or the poll); a /clock alone is
        # answered with the readings by a node that does not tick (none waits for it)
        if topic != CLOCK_TOPIC or self.ticks:
            self.owed = True

    def answer_owed(self) -> None:
        """Answer if a message was taken since the last answer."""
        if self.owed:
            self._answer()

    def _answer(self) -> None:
        self.owed = False
        self.tally.ticks = self.ticks
        text = self._said = self.matched().answer(self.name)
        self._answer_pub.publish(String(data=text))

    def _answer_if_changed(self) -> None:
        self.tally.ticks = self.ticks
        if self.owed or self.matched().answer(self.name) != self._said:
            self._answer()


_participants: weakref.WeakSet[Participant] = weakref.WeakSet()  # this process's
_taken_here = 0  # messages its participants took, all told


def settle(executor: Any) -> None:
    """After a spin: take what else is ready at once, then answer (a spin loop's duty).

    Called after each ``spin_once`` of a loop that spins a participant (``runtime``'s, the
    demo's recorder, a test's peer): what is already waiting is taken first, so a step's
    burst of messages is answered once. Nothing happens without a participant owed.
    """
    for _ in range(SETTLE_MAX):
        if not any(p.owed for p in _participants):
            return
        before = _taken_here
        executor.spin_once(timeout_sec=0.0)
        if _taken_here == before:
            break
    for p in tuple(_participants):
        p.answer_owed()


def _stamp_reader(msg_type: Any, raw: bool) -> Callable[[Any], int | None]:
    """How to read a message's header stamp [ns] (None: it has no header, or unreadable)."""
    fields: dict[str, str] = getattr(msg_type, "get_fields_and_field_types", dict)()
    if next(iter(fields), None) != "header":
        return lambda msg: None
    if not raw:
        return lambda msg: stamp_to_ns(msg.header.stamp)

    def from_bytes(buf: bytes) -> int | None:
        try:
            head = cdr.header(buf, "a stamped message")
        except ValueError:
            return None
        return None if head is None else head[0] * 1_000_000_000 + head[1]

    return from_bytes


def join(node: Node, lockstep: bool) -> Alone | Participant:
    """The node's loop: a :class:`Participant` in lockstep, else :class:`Alone`."""
    return Participant(node) if lockstep else Alone(node)


class Conductor(_Counts):
    """The sim's side: its own messages counted, the participants' answers read.

    ``start()`` (it sends the first /clock) is called once every participant expected
    has answered with its endpoints matched and nothing owed, for
    :data:`START_SETTLE_S`; then ``step()`` each time the loop has answered all that was
    sent since the last call (it returns True when it sent a /clock, which only the
    participants that tick must have taken before the next phase). ``where()`` says for
    the guard's lines which step the loop owes.
    """

    def __init__(self, node: Node, expected: Sequence[str], start: Callable[[], None],
                 step: Callable[[], bool], where: Callable[[], str]) -> None:
        super().__init__(node)
        # The phase sent last is a /clock: only the participants that tick must take it.
        self.at_clock = False
        ns = node.get_namespace()
        self._expected = tuple(dict.fromkeys(resolve(n, ns) for n in expected))
        self._start, self._step, self._where = start, step, where
        self._answers: dict[str, Tally] = {}
        self._ignored: set[str] = set()
        self.started = False
        self._ready_since: float | None = None
        self._since = self._warned = time.monotonic()
        self._log: Any = node.get_logger()
        node.create_subscription(String, ANSWER_TOPIC, self._on_answer, ANSWER_IN_QOS)
        node.create_timer(POLL_S, self._guard, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def tallies(self) -> dict[str, Tally]:
        """Every participant's last answer and the sim's own counts."""
        return {**self._answers, self.name: self.matched()}

    def _on_answer(self, msg: String) -> None:
        try:
            name, tally = Tally.parse(msg.data)
        except ValueError as err:
            self._log.warning(f"lockstep: an answer dropped: {err}",
                              throttle_duration_sec=GUARD_S)
            return
        if name not in self._expected:
            if name not in self._ignored:
                self._ignored.add(name)
                self._log.warning(f"lockstep: {name} answers but is not in lockstep_nodes "
                                  f"({', '.join(self._expected)}): not waited for")
            return
        self._answers[name] = tally
        self._taken(ANSWER_TOPIC)

    def _clock(self) -> str | None:
        return CLOCK_TOPIC if self.at_clock else None

    def _taken(self, topic: str) -> None:
        """A message taken or an answer heard: step on while the loop has answered.

        Again at once after a step: a phase no participant reads (readings nobody takes) is
        answered as it is sent; the next /clock always has readers (each participant's).
        """
        while self.started and answered(self.tallies(), self._clock()):
            self._since = time.monotonic()
            self.at_clock = self._step()

    def _owed(self) -> list[str]:
        tallies = self.tallies()
        if self.started:
            return lags(tallies, self._clock())
        return (missing(self._expected, tallies) or unmatched(tallies) or lags(tallies))

    def _guard(self) -> None:
        """Start once the loop is ready; name what it owes when an answer is late."""
        now = time.monotonic()
        owed = self._owed()
        if not self.started:
            if owed:
                self._ready_since = None
            elif self._ready_since is None:
                self._ready_since = now
            elif now - self._ready_since >= START_SETTLE_S:
                self.started = self.stepping = self.at_clock = True
                self._since = now
                self._start()
                self._taken(ANSWER_TOPIC)
                return
        if owed and now - self._since >= GUARD_S and now - self._warned >= GUARD_S:
            self._warned = now
            what = self._where() if self.started else "the start"
            self._log.warning(f"lockstep: {what} not answered for {now - self._since:.0f} s "
                              f"(wall): " + "; ".join(owed))
