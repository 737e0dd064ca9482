"""When a lockstep step counts as answered (core.sim.lockstep), against a model of the loop.

The claim of the module: once every participant's last answer shows it has taken all the
participants sent on the topics it reads, nothing of the step is in flight or being
handled anywhere, whatever the order messages and answers travel in. The model below
runs the demo's loop shape (sim -> odometry -> follower -> cmd_vel -> sim, a recorder
reading everything and sending paths to the follower) with each message answered by
any number of messages, every channel first in first out per writer and reader (as a
reliable DDS reader keeps one writer's order), and every interleaving Hypothesis finds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.sim.lockstep import (
    Tally,
    answered,
    lags,
    missing,
    resolve,
    unmatched,
)

SIM = "/sim_node"
# participant -> (topics it reads, topics it writes)
LOOP = {
    SIM: (("/wheel_commands",), ("/clock", "/joint_states")),
    "/odometry_node": (("/clock", "/joint_states"), ("/odom",)),
    "/path_follower_node": (("/clock", "/odom", "/path"), ("/cmd_vel",)),
    "/cmd_vel_node": (("/clock", "/cmd_vel"), ("/wheel_commands",)),
    "/recorder": (("/clock", "/joint_states", "/odom", "/cmd_vel"), ("/path",)),
}


def test_an_answer_reads_back_as_written() -> None:
    tally = Tally(sent={"/odom": 12, "/tf": 12}, took={"/clock": 13, "/joint_states": 12},
                  readers={"/odom": 2}, writers={"/joint_states": 1})
    text = tally.answer("/odometry_node")
    assert text.splitlines()[0] == "/odometry_node"
    assert "sent /odom 12" in text.splitlines()
    assert Tally.parse(text) == ("/odometry_node", tally)
    # A topic name with a space cannot be a ROS name, but the count is the last word.
    assert Tally.parse("/n\ntook /a b 3") == ("/n", Tally(took={"/a b": 3}))


@pytest.mark.parametrize("text", ["/n\nsent /odom", "/n\nheard /odom 3", "/n\nsent /odom x",
                                  "/n\n", "/n\nsent  3"])
def test_anything_else_is_refused(text: str) -> None:
    with pytest.raises(ValueError):
        Tally.parse(text)


def test_a_reader_short_of_what_was_sent_is_named_and_a_foreign_extra_holds_nothing() -> None:
    tallies = {
        SIM: Tally(sent={"/joint_states": 5}, took={"/wheel_commands": 4}),
        "/odometry_node": Tally(sent={"/odom": 4}, took={"/joint_states": 4}),
        "/cmd_vel_node": Tally(sent={"/wheel_commands": 4}, took={"/cmd_vel": 9}),
    }
    assert lags(tallies) == ["/odometry_node has taken 4 of the 5 messages sent on "
                             "/joint_states"]
    tallies["/odometry_node"].took["/joint_states"] = 5
    assert lags(tallies) == []  # 9 taken on /cmd_vel, none sent in the loop: a foreign one


def test_only_a_participant_that_ticks_must_have_taken_the_clock_phase() -> None:
    """A step's /clock: a node with work of its own at a /clock (a heartbeat) must have
    taken it before the readings are sent; one that only answers readings takes it with
    them. Once the readings are out, every reader of /clock must have taken it."""
    ticking = Tally(took={"/clock": 2, "/cmd_vel": 1}, ticks=True)
    assert Tally.parse(ticking.answer("/cmd_vel_node")) == ("/cmd_vel_node", ticking)
    tallies = {
        SIM: Tally(sent={"/clock": 3, "/joint_states": 2}),
        "/odometry_node": Tally(took={"/clock": 2, "/joint_states": 2}),
        "/cmd_vel_node": ticking,
    }
    held = ["/cmd_vel_node has taken 2 of the 3 messages sent on /clock"]
    assert lags(tallies, "/clock") == held and not answered(tallies, "/clock")
    ticking.took["/clock"] = 3
    assert lags(tallies, "/clock") == [] and answered(tallies, "/clock")
    assert lags(tallies) == ["/odometry_node has taken 2 of the 3 messages sent on /clock"]
    assert not answered(tallies)


def test_the_start_waits_for_every_endpoint_and_every_participant() -> None:
    tallies = {
        SIM: Tally(sent={"/joint_states": 0}, took={"/wheel_commands": 0},
                   readers={"/joint_states": 2}, writers={"/wheel_commands": 0}),
        "/odometry_node": Tally(took={"/joint_states": 0}, writers={"/joint_states": 1}),
        "/recorder": Tally(took={"/joint_states": 0}, writers={"/joint_states": 1}),
        "/cmd_vel_node": Tally(sent={"/wheel_commands": 0}, readers={"/wheel_commands": 1}),
    }
    assert unmatched(tallies) == ["/sim_node's reader on /wheel_commands has matched 0 of "
                                  "the 1 writers in the loop"]
    tallies[SIM].readers["/joint_states"] = 1
    assert len(unmatched(tallies)) == 2
    assert missing(["/odometry_node", "/ghost"], tallies) == [
        "/ghost has not answered yet (running, with lockstep: true?)"]


def test_names_resolve_in_the_sims_namespace() -> None:
    assert resolve("odometry_node", "/") == "/odometry_node"
    assert resolve("odometry_node", "/robot1") == "/robot1/odometry_node"
    assert resolve("/elsewhere/n", "/robot1") == "/elsewhere/n"


@dataclass
class Node:
    name: str
    tally: Tally = field(default_factory=Tally)
    answers: deque[Tally] = field(default_factory=deque)  # on their way to the sim


class Model:
    """The loop as messages in channels; the sim's conductor sees answers as they arrive."""

    def __init__(self, fanout: dict[tuple[str, str], int]) -> None:
        # (participant, topic taken) -> messages it sends on each of its topics for one
        self.fanout = fanout
        self.nodes = {name: Node(name) for name in LOOP}
        for name, (reads, writes) in LOOP.items():
            self.nodes[name].tally.took.update(dict.fromkeys(reads, 0))
            self.nodes[name].tally.sent.update(dict.fromkeys(writes, 0))
        # (topic, reader) -> messages in flight (each a number: who sent it is irrelevant)
        self.channels: dict[tuple[str, str], deque[int]] = {
            (topic, reader): deque() for reader, (reads, _) in LOOP.items() for topic in reads}
        self.inbox: dict[str, deque[str]] = {name: deque() for name in LOOP}  # delivered
        # The conductor's last answer of each: the start waits for every one's first.
        self.seen: dict[str, Tally] = {
            n: Tally(dict(node.tally.sent), dict(node.tally.took))
            for n, node in self.nodes.items() if n != SIM}

    def send(self, name: str, topic: str) -> None:
        self.nodes[name].tally.sent[topic] += 1
        for (t, _reader), channel in self.channels.items():
            if t == topic:
                channel.append(1)

    def step(self, topics: tuple[str, ...]) -> None:
        """The sim sends a phase: a message on each of ``topics``."""
        for topic in topics:
            self.send(SIM, topic)

    def events(self) -> list[tuple[str, ...]]:
        out: list[tuple[str, ...]] = [("deliver", t, r) for (t, r), c in self.channels.items()
                                      if c]
        out += [("handle", n) for n, box in self.inbox.items() if box]
        out += [("answer", n) for n, node in self.nodes.items() if node.answers]
        return out

    def run(self, event: tuple[str, ...]) -> None:
        if event[0] == "deliver":
            topic, reader = event[1], event[2]
            self.channels[(topic, reader)].popleft()
            self.inbox[reader].append(topic)
        elif event[0] == "handle":
            node = self.nodes[event[1]]
            topic = self.inbox[node.name].popleft()
            for out in LOOP[node.name][1]:  # its answers first, then it counts the one taken
                for _ in range(self.fanout.get((node.name, topic), 0)):
                    self.send(node.name, out)
            node.tally.took[topic] += 1
            if node.name != SIM:
                node.answers.append(Tally(dict(node.tally.sent), dict(node.tally.took)))
        else:
            node = self.nodes[event[1]]
            self.seen[node.name] = node.answers.popleft()

    def answered(self) -> bool:
        """The conductor's verdict: the sim's exact counts and the answers heard."""
        return not lags({**self.seen, SIM: self.nodes[SIM].tally})

    def quiet(self) -> bool:
        """The truth: nothing in flight, nothing delivered and not yet handled."""
        return (not any(self.channels.values()) and not any(self.inbox.values()))


# Who answers what (the sim answers nothing: it sends each phase itself; the recorder
# sends a path only at a /clock, as the demo's does).
ANSWERING = [(n, t) for n, (reads, _) in LOOP.items() for t in reads
             if n != SIM and (n != "/recorder" or t == "/clock")]


@settings(max_examples=60)
@given(st.data(), st.fixed_dictionaries({key: st.integers(0, 2) for key in ANSWERING}))
def test_answered_means_nothing_of_the_step_is_left_anywhere(
        data: st.DataObject, fanout: dict[tuple[str, str], int]) -> None:
    model = Model(fanout)
    for phase in (("/clock",), ("/joint_states",), ("/clock",), ("/joint_states",)):
        model.step(phase)
        for _ in range(400):
            if model.answered():
                assert model.quiet(), (phase, model.channels, model.inbox)
                break
            events = model.events()
            assert events, "nothing left to happen and the step is not answered"
            model.run(data.draw(st.sampled_from(events)))
        else:
            raise AssertionError("not answered in 400 events")
