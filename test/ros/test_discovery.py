"""The discovery profile the demo and the suite give the processes they start.

What it changes is Fast DDS's (the oracle reads it: a participant made with it is a real
one); what is checked here is when it is given and that the file says what its module
claims.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.etree import ElementTree

import pytest

from diffdrive_odom.ros import discovery

NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_the_profile_announces_30_times_100_ms_apart_as_the_default_participant() -> None:
    root = ElementTree.parse(discovery.profile_path()).getroot()
    part = root.find("f:participant", NS)
    assert part is not None and part.get("is_default_profile") == "true"
    first = part.find("f:rtps/f:builtin/f:discovery_config/f:initialAnnouncements", NS)
    assert first is not None
    assert first.findtext("f:count", namespaces=NS) == "30"
    assert first.findtext("f:period/f:nanosec", namespaces=NS) == "100000000"


@pytest.mark.parametrize("rmw", ["", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp"])
def test_fast_dds_gets_the_profile_where_none_is_chosen(
        rmw: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    env = {"ROS_DOMAIN_ID": "3", **({"RMW_IMPLEMENTATION": rmw} if rmw else {})}
    out = discovery.with_profile(env)
    assert out == {**env, "FASTRTPS_DEFAULT_PROFILES_FILE": discovery.profile_path()}
    assert Path(discovery.profile_path()).is_file()


@pytest.mark.parametrize("env", [
    {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
    {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
])
def test_another_rmw_or_the_users_own_profile_is_left_as_it_is(
        env: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert discovery.with_profile(env) == env


def test_a_profile_in_the_working_directory_is_left_to_fast_dds(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / discovery.CWD_PROFILE).write_text("<profiles/>", encoding="utf-8")
    assert discovery.with_profile({}) == {}


def test_in_this_process_puts_the_environment_back(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    for var in discovery.PROFILE_VARS:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
    with discovery.in_this_process():
        assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == discovery.profile_path()
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ
