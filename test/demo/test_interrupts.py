"""The demo's Ctrl-C: raised at once, or after a spin, never inside rclpy's C code."""

from __future__ import annotations

import os
import signal

import pytest

from diffdrive_odom.demo import interrupts


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_outside_a_spin_is_a_keyboard_interrupt_at_once(signum: int) -> None:
    reached = False
    with pytest.raises(KeyboardInterrupt), interrupts.handled():
        os.kill(os.getpid(), signum)
        reached = True  # not reached: the handler raised where the signal arrived
    assert not reached


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_a_spin_is_raised_when_the_spin_is_over(signum: int) -> None:
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt), interrupts.handled():
        with interrupts.deferred():
            os.kill(os.getpid(), signum)
            steps.append("the spin went on")  # e.g. rclpy deserializing a message
        steps.append("not reached")
    assert steps == ["the spin went on"]


def test_the_previous_handlers_are_back_afterwards() -> None:
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with interrupts.handled():
        assert signal.getsignal(signal.SIGINT) is not before[0]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
