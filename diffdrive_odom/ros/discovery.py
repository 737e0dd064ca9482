"""Fast DDS discovery for processes started one after another (the demo's loop, the tests).

Fast DDS announces a new participant a few times, 100 ms apart, then every 3 s. A
process that comes up after another's first announcements can miss it until the next
periodic one: the demo's recorder and its path follower, the last node it starts, found
each other only after about 3 s, and the loop's start waited for them (a ``--short`` run:
nodes up after 4.8-5.1 s in 6 runs of 10 with 10 first announcements, in none of 10
with 30, which span the 3 s; 1.8-2.2 s otherwise). :func:`with_profile` gives the
processes a tool starts a profile with 30 (``data/fastdds_discovery.xml``), unless the
user runs another RMW or chose a Fast DDS profile of their own, left as they are.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
# Fast DDS also reads this file from the working directory when no variable names one.
CWD_PROFILE = "DEFAULT_FASTRTPS_PROFILES.xml"


def profile_path() -> str:
    """The shipped profile (package data, beside the example params file)."""
    return str(Path(__file__).resolve().parent.parent / "data" / "fastdds_discovery.xml")


def with_profile(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` with the discovery profile named, where Fast DDS runs and none is chosen."""
    out = dict(env)
    rmw = out.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return out
    if any(out.get(var) for var in PROFILE_VARS) or os.path.exists(CWD_PROFILE):
        return out
    out[PROFILE_VARS[0]] = profile_path()
    return out


@contextmanager
def in_this_process() -> Iterator[None]:
    """The profile for the participants this process creates inside the block.

    Fast DDS reads the variable when the process's first participant is made; it is put
    back as it was after the block.
    """
    added = {k: v for k, v in with_profile(os.environ).items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)
