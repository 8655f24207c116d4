"""The Zenoh front end's settings: validation and the session configuration they make."""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.errors import ConfigError
from omnican.zenoh.settings import ZenohSettings, config_entries
from tests.zenoh.conftest import wait_real


def test_defaults_are_a_peer_without_multicast() -> None:
    s = ZenohSettings().validate()
    assert config_entries(s) == [("mode", '"peer"'), ("scouting/multicast/enabled", "false")]
    assert s.ros_namespace == "/"


def test_endpoints_and_mode_go_into_the_config() -> None:
    s = ZenohSettings(mode="client", connect=("tcp/10.0.0.1:7447",),
                      listen=("tcp/127.0.0.1:0",), multicast=True).validate()
    entries = dict(config_entries(s))
    assert json.loads(entries["mode"]) == "client"
    assert json.loads(entries["connect/endpoints"]) == ["tcp/10.0.0.1:7447"]
    assert json.loads(entries["listen/endpoints"]) == ["tcp/127.0.0.1:0"]
    assert json.loads(entries["scouting/multicast/enabled"]) is True


@pytest.mark.parametrize(("changes", "words"), [
    ({"domain_id": 233}, "domain id"),
    ({"mode": "broker"}, "mode"),
    ({"node_name": "my node"}, "node name"),
    ({"namespace": "/robot 1"}, "namespace"),
    ({"connect": ("127.0.0.1:7447",)}, "not a Zenoh endpoint"),
    ({"rates_hz": {"/odom": 0.0}}, "rate of /odom"),
])
def test_bad_settings_name_what_is_wrong(changes: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        ZenohSettings(**changes).validate()  # type: ignore[arg-type]


@given(st.lists(st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True), max_size=3),
       st.booleans(), st.booleans())
def test_namespaces_are_written_as_ros_2_does(chunks: list[str], lead: bool,
                                              trail: bool) -> None:
    ns = ("/" if lead else "") + "/".join(chunks) + ("/" if trail and chunks else "")
    s = ZenohSettings(namespace=ns).validate()
    assert s.ros_namespace == "/" + "/".join(chunks)


def test_a_zenoh_config_file_passes_through(tmp_path: Any, router: str) -> None:
    """The file alone says where the router is (as a deployment's would, with TLS or
    access control beside); the session reaches it."""
    from omnican.zenoh.bridge import open_session

    conf = tmp_path / "zenoh.json5"
    conf.write_text("{ mode: \"peer\", connect: { endpoints: " + json.dumps([router]) + " } }")
    session = open_session(ZenohSettings(mode="client", config_file=str(conf)))
    try:
        assert wait_real(lambda: len(list(session.info.routers_zid())) == 1)
    finally:
        session.close()


def test_a_session_that_cannot_open_is_a_config_error(tmp_path: Any) -> None:
    pytest.importorskip("zenoh")
    from omnican.zenoh.bridge import open_session

    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 12 }")
    with pytest.raises(ConfigError, match=r"^Zenoh config .*bad\.json5: JSON error"):
        open_session(ZenohSettings(config_file=str(bad)))
    with pytest.raises(ConfigError, match=r"^Zenoh config .*missing\.json5: no such file$"):
        open_session(ZenohSettings(config_file=str(tmp_path / "missing.json5")))
