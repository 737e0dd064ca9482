"""The demo's Ctrl-C: raised at once, or where the loop checks, never inside rclpy's C code
nor inside ``Popen.poll``."""

from __future__ import annotations

import os
import signal

import pytest

from diffdrive_odom.demo import interrupts
from diffdrive_odom.ros.lifetime import stop_signals

STOPS = [pytest.param(s, marks=pytest.mark.skipif(
    s not in stop_signals(), reason="SIGHUP ignored from the start (nohup): not a stop"))
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]


@pytest.mark.parametrize("signum", STOPS)
def test_a_signal_outside_a_spin_is_a_keyboard_interrupt_at_once(signum: int) -> None:
    reached = False
    with pytest.raises(KeyboardInterrupt), interrupts.handled():
        os.kill(os.getpid(), signum)
        reached = True  # not reached: the handler raised where the signal arrived
    assert not reached


STOPS = [pytest.param(s, marks=pytest.mark.skipif(
    s not in stop_signals(), reason="SIGHUP ignored from the start (nohup): not a stop"))
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]


@pytest.mark.parametrize("signum", STOPS)
def test_a_signal_inside_a_spin_is_raised_when_the_spin_is_over(signum: int) -> None:
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt), interrupts.handled():
        with interrupts.deferred():
            os.kill(os.getpid(), signum)
            steps.append("the spin went on")  # e.g. rclpy deserializing a message
        steps.append("not reached")
    assert steps == ["the spin went on"]


def test_a_held_signal_is_raised_at_the_check_and_only_once() -> None:
    """The run with its children is one deferral: a signal is raised where the loop
    checks (between spins, never in the code that polls or stops the children)."""
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt), interrupts.handled(), interrupts.deferred():
        os.kill(os.getpid(), signal.SIGINT)
        steps.append("polled the children")
        with interrupts.deferred():  # a spin inside: leaving it raises nothing yet
            pass
        steps.append("spun")
        try:
            interrupts.check()
        except KeyboardInterrupt:
            steps.append("raised at the check")
            interrupts.check()  # the signal was raised once: nothing more held
            steps.append("the teardown goes on")
            raise
    assert steps == ["polled the children", "spun", "raised at the check",
                     "the teardown goes on"]


def test_the_previous_handlers_are_back_afterwards() -> None:
    stops = stop_signals()  # SIGHUP too, unless this runs under nohup
    before = [signal.getsignal(s) for s in stops]
    with interrupts.handled():
        assert all(signal.getsignal(s) is not b for s, b in zip(stops, before, strict=True))
    assert [signal.getsignal(s) for s in stops] == before
