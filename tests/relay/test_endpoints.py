"""Endpoint strings: serial ports with baud, NTRIP URLs with credentials (never shown), tcp://, file:."""

from __future__ import annotations

import pytest

from drivers.relay import (
    FileEndpoint,
    NtripEndpoint,
    Secret,
    SerialEndpoint,
    TcpEndpoint,
    mask_credentials,
    open_sink,
    parse_endpoint,
)
from vsccore.errors import ConfigError

PASSWORD = "s3cr#t/pa:ss"


def test_serial_ports() -> None:
    assert parse_endpoint("/dev/ttyUSB0") == SerialEndpoint("/dev/ttyUSB0", None)
    assert parse_endpoint("/dev/ttyUSB0@115200") == SerialEndpoint("/dev/ttyUSB0", 115200)
    assert parse_endpoint("COM3@38400") == SerialEndpoint("COM3", 38400)
    assert parse_endpoint("/dev/ttyUSB0@115200").display == "/dev/ttyUSB0@115200"


def test_tcp_and_file() -> None:
    assert parse_endpoint("tcp://127.0.0.1:5000") == TcpEndpoint("127.0.0.1", 5000)
    assert parse_endpoint("file:/tmp/base.rtcm3") == FileEndpoint("/tmp/base.rtcm3", None)
    assert parse_endpoint("file:capture.bin@9600") == FileEndpoint("capture.bin", 9600)
    with pytest.raises(ConfigError, match="tcp://host:port"):
        parse_endpoint("tcp://127.0.0.1")
    with pytest.raises(ConfigError, match="unknown scheme"):
        parse_endpoint("udp://1.2.3.4:5")


def test_ntrip_url_with_credentials() -> None:
    ep = parse_endpoint(f"ntrip://alice:{PASSWORD}@caster.example:2102/MOUNT1", env={})
    assert isinstance(ep, NtripEndpoint)
    assert (ep.host, ep.port, ep.mountpoint, ep.user, ep.version) == ("caster.example", 2102, "MOUNT1", "alice", 2)
    assert ep.password is not None and ep.password.reveal() == PASSWORD
    for shown in (repr(ep), str(ep), ep.display, repr(ep.password), str(ep.password), f"{ep}"):
        assert PASSWORD not in shown
    assert ep.display == "ntrip://alice:***@caster.example:2102/MOUNT1"


def test_ntrip_defaults_version_and_environment() -> None:
    env = {"VSC_RIG_NTRIP_USER": "bob", "VSC_RIG_NTRIP_PASSWORD": PASSWORD}
    ep = parse_endpoint("ntrip://caster.example/VRS?version=1", env=env)
    assert isinstance(ep, NtripEndpoint)
    assert (ep.port, ep.user, ep.version) == (2101, "bob", 1)
    assert ep.password == Secret(PASSWORD)
    # A user in the URL takes the password from the environment.
    ep2 = parse_endpoint("ntrip://carol@caster.example:2101/M", env=env)
    assert isinstance(ep2, NtripEndpoint)
    assert ep2.user == "carol" and ep2.password == Secret(PASSWORD)
    ep3 = parse_endpoint("ntrip://h:1/M", env={"U": "u", "P": "p"}, user_env="U", password_env="P")
    assert isinstance(ep3, NtripEndpoint) and ep3.user == "u" and ep3.password == Secret("p")


def test_errors_never_quote_the_password() -> None:
    for bad in (
        f"ntrip://alice:{PASSWORD}@caster.example:notaport/M",
        f"ntrip://alice:{PASSWORD}@caster.example:2101/",
        f"ntrip://alice:{PASSWORD}@caster.example:2101/M?colour=red",
    ):
        with pytest.raises(ConfigError) as excinfo:
            parse_endpoint(bad, env={})
        assert PASSWORD not in str(excinfo.value)
        assert PASSWORD not in repr(excinfo.value)
        assert "caster.example" in str(excinfo.value)
    with pytest.raises(ConfigError, match="only be a source") as excinfo:
        open_sink(f"ntrip://alice:{PASSWORD}@caster.example:2101/M")
    assert PASSWORD not in str(excinfo.value)


def test_mask_credentials() -> None:
    assert mask_credentials("ntrip://u:pw@h:1/M and tcp://x:1") == "ntrip://u:***@h:1/M and tcp://x:1"


def test_secret_is_not_pickled() -> None:
    import pickle

    with pytest.raises(TypeError):
        pickle.dumps(Secret(PASSWORD))


def test_a_password_given_as_a_config_key_is_masked_like_one_in_a_url() -> None:
    """The session attaches its configuration file: a ``source_password`` key must not reach it."""
    from drivers.relay.endpoints import mask_credentials

    text = (
        "[relay]\n"
        'source = "ntrip://user:pa55@caster:2101/MOUNT"\n'
        'source_password = "hunter2"  # from the caster admin\n'
        "baud = 115200\n"
    )
    masked = mask_credentials(text)
    assert "hunter2" not in masked
    assert "pa55" not in masked
    assert 'source_password = "***"' in masked
    assert "baud = 115200" in masked
    assert 'source = "ntrip://user:***@caster:2101/MOUNT"' in masked
