"""Who may listen where, and who may do what: the pure rules (loopback, the roles' access
control read with Zenoh's own key-expression matching), the settings that turn
credentials on, and the folder ``omnican zenoh credentials`` makes."""

from __future__ import annotations

import json
import stat
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican.config import parse_config
from omnican.errors import ConfigError
from omnican.zenoh import rmw
from omnican.zenoh.security import (
    MESSAGES,
    ROLES,
    Identity,
    Roster,
    access_control,
    base_acl,
    router_acl,
)
from omnican.zenoh.settings import (
    ZenohSettings,
    base_problem,
    default_listen,
    exposed,
    exposed_refusal,
    loopback,
    role_problem,
)

zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                            "(pip install 'omnican[zenoh]')")

# ---------------------------------------------------------------- listening


_PORT = st.integers(0, 65535)
_LOOPBACK_V4 = st.tuples(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255)).map(
    lambda t: f"127.{t[0]}.{t[1]}.{t[2]}")
_PUBLIC_V4 = st.tuples(st.integers(1, 223), st.integers(0, 255), st.integers(0, 255),
                       st.integers(1, 254)).filter(lambda t: t[0] != 127).map(
    lambda t: ".".join(map(str, t)))
_PROTO = st.sampled_from(("tcp", "udp", "tls", "quic", "ws"))


@given(_PROTO, st.one_of(_LOOPBACK_V4, st.just("[::1]"), st.just("localhost")), _PORT)
def test_a_loopback_endpoint_is_never_exposed(proto: str, host: str, port: int) -> None:
    endpoint = f"{proto}/{host}:{port}"
    assert loopback(endpoint)
    assert exposed([endpoint]) == []


@given(_PROTO, st.one_of(_PUBLIC_V4, st.sampled_from(("0.0.0.0", "[::]", "robot1.lan",
                                                      "[fe80::1]"))), _PORT)
def test_beyond_loopback_only_credentials_guard_it(proto: str, host: str, port: int) -> None:
    endpoint = f"{proto}/{host}:{port}"
    assert not loopback(endpoint)
    assert exposed([endpoint]) == [endpoint]
    # mutual TLS guards what goes over TLS (or QUIC), not a plain link beside it
    assert exposed([endpoint], mtls=True) == ([] if proto in ("tls", "quic") else [endpoint])
    assert exposed([endpoint], password=True) == []


def test_a_unix_socket_and_an_endpoints_options_are_read_as_zenoh_writes_them() -> None:
    assert loopback("unixsock-stream//tmp/zenoh.sock")
    assert loopback("tcp/127.0.0.1:7447?iface=lo#rel=1")
    assert not loopback("tcp/0.0.0.0:7447#iface=eth0")


def test_where_a_session_listens_when_nothing_says() -> None:
    """Zenoh's own default is every interface ([::]); omnican's is loopback."""
    zenoh_default = json.loads(zenoh.Config().get_json("listen/endpoints"))
    assert zenoh_default["peer"] == ["tcp/[::]:0"]  # what a base did before
    assert default_listen(ZenohSettings()) == ("tcp/127.0.0.1:0",)
    assert default_listen(ZenohSettings(mode="router")) == ("tcp/127.0.0.1:7447",)
    assert default_listen(ZenohSettings(mode="client")) == ()
    mtls = ZenohSettings(credentials="/x", identity="base/robot1")
    assert default_listen(mtls) == ("tls/127.0.0.1:0",)


def test_the_refusal_is_one_line_that_says_who_could_drive() -> None:
    base = exposed_refusal(ZenohSettings(), ["tcp/[::]:0"])
    router = exposed_refusal(ZenohSettings(mode="router"), ["tcp/192.168.1.5:7447"])
    assert "\n" not in base and "\n" not in router
    assert base.startswith("zenoh: would listen on tcp/[::]:0 (every interface) without "
                           "credentials: anyone who can reach it could drive this robot")
    assert "could drive every robot connected to this router" in router
    for text in (base, router):
        assert "--zenoh-credentials" in text and "--zenoh-allow-insecure" in text


@pytest.mark.parametrize(("changes", "words"), [
    ({"listen": ("tcp/0.0.0.0:7448",)}, "would listen on tcp/0.0.0.0:7448 (every interface)"),
    ({"security": "tls"}, "security 'tls' is not one of none, mtls"),
    ({"security": "mtls"}, "needs the credentials"),
    ({"credentials": "/fleet"}, "needs the identity"),
    ({"identity": "base/robot1"}, "identity base/robot1 needs the credentials' folder"),
    ({"security": "none", "credentials": "/fleet"}, "credentials is for security"),
    ({"credentials": "/fleet", "identity": "pilot/alice"}, "is not ROLE/NAME"),
    ({"credentials": "/fleet", "identity": "base/robot 1"}, "not a namespace chunk"),
    ({"credentials": "/fleet", "identity": "base/robot1", "connect": ("tcp/10.0.0.1:7447",)},
     "'tcp/10.0.0.1:7447' is not a tls/HOST:PORT endpoint"),
])
def test_bad_security_settings_are_one_line_each(changes: dict[str, Any], words: str) -> None:
    with pytest.raises(ConfigError) as err:
        ZenohSettings(**changes).validate()
    assert words in str(err.value) and "\n" not in str(err.value)


def test_what_may_listen_beyond_loopback() -> None:
    ZenohSettings(listen=("tcp/0.0.0.0:7448",), allow_insecure=True).validate()
    ZenohSettings(listen=("tls/0.0.0.0:7448",), credentials="/fleet",
                  identity="base/robot1").validate()


def test_a_base_presents_its_own_namespaces_credentials() -> None:
    def base(identity: str, namespace: str) -> ZenohSettings:
        return ZenohSettings(credentials="/fleet", identity=identity, namespace=namespace)

    assert base_problem(base("base/robot1", "/robot1")) is None
    assert base_problem(ZenohSettings()) is None
    assert "give --namespace /robot1" in str(base_problem(base("base/robot1", "/robot2")))
    assert "not viewer/bob" in str(base_problem(base("viewer/bob", "/robot1")))
    assert role_problem(ZenohSettings(mode="router", credentials="/f",
                                      identity="router/r")) is None
    assert "cannot be operator/alice" in str(role_problem(ZenohSettings(
        mode="router", credentials="/f", identity="operator/alice")))
    assert "cannot be router/r" in str(role_problem(ZenohSettings(
        credentials="/f", identity="router/r")))


# ---------------------------------------------------------------- the roles


def allows(acl: dict[str, Any], name: str, message: str, flow: str, key: str) -> bool:
    """Whether ``acl`` lets a link presenting the certificate ``name`` do ``message`` on
    ``key`` (``flow``: ingress, what it sends in; egress, what is sent to it): Zenoh's
    evaluation, default deny, key expressions matched by Zenoh itself."""
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    subjects = {s["id"] for s in acl["subjects"] if name in s["cert_common_names"]}
    rules = {r["id"]: r for r in acl["rules"]}
    target = zenoh.KeyExpr(key)
    for policy in acl["policies"]:
        if subjects & set(policy["subjects"]):
            for rule_id in policy["rules"]:
                rule = rules[rule_id]
                if message in rule["messages"] and flow in rule["flows"] and any(
                        zenoh.KeyExpr(k).includes(target) for k in rule["key_exprs"]):
                    return True
    return False


_BASE = st.from_regex(r"[a-z][a-z0-9_]{0,7}", fullmatch=True)
_PERSON = st.from_regex(r"[a-z][a-z0-9]{0,7}", fullmatch=True)


@st.composite
def fleets(draw: st.DrawFn) -> Roster:
    names = draw(st.lists(st.one_of(_BASE, _PERSON), min_size=5, max_size=9, unique=True))
    domain = draw(st.integers(0, 232))
    roster = Roster(domain)
    for role, name in zip(("base", "base", "operator", "viewer", "router"), names[:5],
                          strict=True):
        roster = roster.adding(role, name)
    for name in names[5:]:
        roster = roster.adding(draw(st.sampled_from(ROLES)), name)
    return roster


def keys(domain: int, base: str) -> dict[str, str]:
    """A base's keys as rmw_zenoh writes them (the node omnican under /<base>)."""
    node = rmw.RosNode(domain, "5f3a", 0, "omnican", namespace=f"/{base}")
    srv = "std_srvs::srv::dds_::Trigger_/RIHS01_" + "e" * 64
    twist = rmw.data_key(domain, f"/{base}/cmd_vel", "geometry_msgs/msg/Twist", "RIHS01_" + "a" * 64)
    return {"cmd_vel": twist, "odom": f"{domain}/{base}/odom/x/RIHS01_" + "b" * 64,
            "stop": f"{domain}/{base}/omnican/stop/{srv}",
            "recover": f"{domain}/{base}/omnican/recover/{srv}",
            "reset": f"{domain}/{base}/omnican/reset_odometry/{srv}",
            "token": node.token()}


@settings(max_examples=40, deadline=None)
@given(fleets())
def test_a_base_lets_operators_drive_and_viewers_only_stop(roster: Roster) -> None:
    d = roster.domain_id
    for base in roster.names("base"):
        acl = base_acl(roster, base)
        k = keys(d, base)
        for op in roster.names("operator"):
            assert allows(acl, op, "put", "ingress", k["cmd_vel"])
            for service in ("stop", "recover", "reset"):
                assert allows(acl, op, "query", "ingress", k[service])
        for viewer in roster.names("viewer"):
            assert allows(acl, viewer, "query", "ingress", k["stop"])
            assert allows(acl, viewer, "declare_subscriber", "ingress", k["odom"])
            assert allows(acl, viewer, "put", "egress", k["odom"])  # it reads
            assert not allows(acl, viewer, "put", "ingress", k["cmd_vel"])
            assert not allows(acl, viewer, "query", "ingress", k["recover"])
            assert not allows(acl, viewer, "query", "ingress", k["reset"])
        for other in roster.names("base"):
            if other != base:
                assert not allows(acl, other, "put", "ingress", k["cmd_vel"])
                assert not allows(acl, other, "query", "ingress", k["stop"])
        for router in roster.names("router"):  # it passes on what its own rules let by
            assert allows(acl, router, "put", "ingress", k["cmd_vel"])
        for message in MESSAGES:  # a certificate of the CA that is in no list
            for flow in ("ingress", "egress"):
                assert not allows(acl, "stranger", message, flow, k["cmd_vel"])
                assert not allows(acl, "stranger", message, flow, k["token"])


@settings(max_examples=40, deadline=None)
@given(fleets())
def test_a_router_passes_on_only_what_each_role_may_send(roster: Roster) -> None:
    d = roster.domain_id
    router = roster.names("router")[0]
    acl = router_acl(roster, router)
    for base in roster.names("base"):
        k = keys(d, base)
        assert allows(acl, base, "put", "ingress", k["odom"])
        assert allows(acl, base, "declare_queryable", "ingress", k["stop"])
        assert allows(acl, base, "liveliness_token", "ingress", k["token"])
        assert not allows(acl, base, "put", "ingress", k["cmd_vel"].replace(
            f"/{base}/", "/elsewhere/"))
        for other in roster.names("base"):
            if other != base:  # no base speaks or announces itself for another
                ko = keys(d, other)
                assert not allows(acl, base, "put", "ingress", ko["odom"])
                assert not allows(acl, base, "liveliness_token", "ingress", ko["token"])
                assert not allows(acl, base, "put", "ingress", ko["cmd_vel"])
        for op in roster.names("operator"):
            assert allows(acl, op, "put", "ingress", k["cmd_vel"])
            assert allows(acl, op, "query", "ingress", k["recover"])
            assert not allows(acl, op, "liveliness_token", "ingress", k["token"])
            assert not allows(acl, op, "put", "ingress", k["odom"])
        for viewer in roster.names("viewer"):
            assert allows(acl, viewer, "query", "ingress", k["stop"])
            assert allows(acl, viewer, "liveliness_query", "ingress",
                          f"{rmw.ADMIN_SPACE}/{d}/**")
            assert not allows(acl, viewer, "put", "ingress", k["cmd_vel"])
            assert not allows(acl, viewer, "query", "ingress", k["recover"])
            assert not allows(acl, viewer, "liveliness_token", "ingress", k["token"])
        assert not allows(acl, "stranger", "put", "ingress", k["cmd_vel"])
        assert not allows(acl, "stranger", "put", "egress", k["odom"])


def test_operators_and_viewers_enforce_nothing_themselves() -> None:
    roster = Roster().adding("base", "robot1").adding("operator", "alice")
    assert access_control(roster, Identity("operator", "alice")) is None
    assert access_control(roster, Identity("base", "robot1")) == base_acl(roster, "robot1")


def test_a_role_with_no_members_grants_nothing() -> None:
    """Zenoh refuses an empty name list, and a subject with no field matches everyone:
    such a subject is left out, and the config loads."""
    roster = Roster().adding("base", "robot1").adding("router", "r")
    acl = base_acl(roster, "robot1")
    # (the base itself always: another process under its certificate)
    assert [s["id"] for s in acl["subjects"]] == ["routers", "itself"]
    conf = zenoh.Config()
    conf.insert_json5("access_control", json.dumps(acl))
    conf.insert_json5("access_control", json.dumps(router_acl(roster, "r")))


@given(fleets())
def test_a_roster_reads_back(roster: Roster) -> None:
    again = Roster.from_json(roster.to_json())
    assert again.domain_id == roster.domain_id
    assert again.identities() == roster.identities()


def test_one_name_one_role() -> None:
    roster = Roster().adding("base", "robot1")
    assert roster.adding("base", "robot1") is roster
    with pytest.raises(ValueError, match="already a base"):
        roster.adding("viewer", "robot1")
    with pytest.raises(ValueError, match="is not ROLE/NAME"):
        Identity.parse("pilot/alice")
    with pytest.raises(ValueError, match="namespace chunk"):
        Identity.parse("base/robot-1")
    assert str(Identity.parse("operator/alice.b")) == "operator/alice.b"


# ---------------------------------------------------------------- the [zenoh] table


def _robot(zenoh_table: str) -> str:
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\nvelocity_scale = 1000\n"
                     "position_scale = 1000\n" for n in (1, 2, 3))
    return f"[chassis]\nlayout = \"b21\"\nbase_radius = 0.19\n{wheels}[zenoh]\n{zenoh_table}"


def test_the_zenoh_table_takes_credentials_relative_to_the_file(tmp_path: Path) -> None:
    from omnican.config import tomllib
    from omnican.zenoh.settings import from_table

    text = _robot('credentials = "fleet"\nidentity = "base/robot1"\nnamespace = "/robot1"\n')
    cfg = parse_config(tomllib.loads(text), "robot.toml", base_dir=tmp_path, check_eds=False)
    table = cfg.front_ends.get("zenoh")
    assert table is not None and table.credentials == str(tmp_path / "fleet")
    s = from_table(table, "robot.toml")
    assert s.mtls and s.who == Identity("base", "robot1")


@pytest.mark.parametrize(("table", "words"), [
    ('security = "tls"', "robot.toml: zenoh.security: must be one of none, mtls, got 'tls'"),
    ("allow_insecure = 1", "robot.toml: zenoh.allow_insecure"),
    ('listen = ["tcp/0.0.0.0:7448"]', "robot.toml: zenoh: would listen on tcp/0.0.0.0:7448"),
    ('security = "mtls"', "robot.toml: zenoh: security \"mtls\" needs the credentials"),
])
def test_check_config_refuses_in_one_line(table: str, words: str, tmp_path: Path) -> None:
    from omnican.cli.front_ends import check_tables as check_front_ends
    from omnican.config import load_config

    path = tmp_path / "robot.toml"
    path.write_text(_robot(table))
    with pytest.raises(ConfigError) as err:
        check_front_ends(load_config(path))
    assert str(err.value).startswith(f"{tmp_path}/{words}") and "\n" not in str(err.value)


# ---------------------------------------------------------------- the session's config


def test_a_sessions_config_listens_on_loopback_unless_told(tmp_path: Path) -> None:
    from omnican.zenoh.bridge import session_config

    def listen(s: ZenohSettings) -> Any:
        return json.loads(session_config(s).get_json("listen/endpoints"))

    assert listen(ZenohSettings()) == ["tcp/127.0.0.1:0"]
    assert listen(ZenohSettings(listen=("tcp/127.0.0.1:7450",))) == ["tcp/127.0.0.1:7450"]
    own = tmp_path / "own.json5"
    own.write_text('{ listen: { endpoints: ["tcp/127.0.0.2:7451"] } }')
    assert listen(ZenohSettings(config_file=str(own))) == ["tcp/127.0.0.2:7451"]
    wide = tmp_path / "wide.json5"
    wide.write_text('{ listen: { endpoints: ["tcp/0.0.0.0:7451"] } }')
    with pytest.raises(ConfigError, match=r"would listen on tcp/0\.0\.0\.0:7451"):
        session_config(ZenohSettings(config_file=str(wide)))
    assert listen(ZenohSettings(config_file=str(wide), allow_insecure=True)) == \
        ["tcp/0.0.0.0:7451"]
    guarded = tmp_path / "guarded.json5"
    guarded.write_text('{ listen: { endpoints: ["tcp/0.0.0.0:7451"] }, transport: { auth: '
                       '{ usrpwd: { dictionary_file: "users.txt" } } } }')
    assert listen(ZenohSettings(config_file=str(guarded))) == ["tcp/0.0.0.0:7451"]


def test_a_missing_zenoh_config_is_named_in_one_line(tmp_path: Path) -> None:
    from omnican.zenoh.bridge import open_session

    missing = tmp_path / "zenoh.json5"
    with pytest.raises(ConfigError) as err:
        open_session(ZenohSettings(config_file=str(missing)))
    assert str(err.value) == f"Zenoh config {missing}: no such file"


# ---------------------------------------------------------------- the folder


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("cryptography", reason="cryptography is not installed "
                        "(pip install 'omnican[zenoh-security]')")
    from omnican.zenoh.credentials import make

    root = tmp_path_factory.mktemp("creds") / "fleet"
    make(root, [Identity("base", "robot1"), Identity("base", "robot2"),
                Identity("operator", "alice"), Identity("viewer", "bob"),
                Identity("router", "router")], domain_id=7)
    return root


def test_the_folder_has_a_certificate_and_config_per_member(fleet_dir: Path) -> None:
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    from omnican.zenoh.bridge import session_config
    from omnican.zenoh.credentials import Files, read_roster

    roster = read_roster(fleet_dir)
    assert roster is not None and roster.domain_id == 7
    ca = x509.load_pem_x509_certificate((fleet_dir / "ca.pem").read_bytes())
    assert stat.S_IMODE((fleet_dir / "ca.key").stat().st_mode) == 0o600
    for who in roster.identities():
        files = Files.of(fleet_dir, who)
        assert files.missing() == []
        assert stat.S_IMODE(files.key.stat().st_mode) == 0o600
        cert = x509.load_pem_x509_certificate(files.cert.read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == who.name
        assert cert.issuer == ca.subject
        cert.verify_directly_issued_by(ca)
        # Zenoh reads the whole file (zenohd, rmw_zenoh) ...
        whole = zenoh.Config.from_file(str(files.config))
        acl = json.loads(whole.get_json("access_control"))
        assert acl["enabled"] is (who.role in ("base", "router"))
        assert json.loads(whole.get_json("transport/link/tls/enable_mtls")) is True
        # ... and omnican its access control, with the certificates where they are now
        mode = "router" if who.role == "router" else "peer"
        ns = who.namespace or "/"
        conf = session_config(ZenohSettings(mode=mode, namespace=ns, domain_id=7,
                                            credentials=str(fleet_dir), identity=str(who)))
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert tls["listen_certificate"] == str(files.cert)
        assert json.loads(conf.get_json("transport/link/protocols")) == ["tls"]
        assert json.loads(conf.get_json("access_control"))["enabled"] is (
            who.role in ("base", "router"))


def test_running_it_again_adds_and_removes_members_keeping_the_ca(fleet_dir: Path,
                                                                  tmp_path: Path) -> None:
    import shutil

    from omnican.zenoh.credentials import make

    root = tmp_path / "fleet"
    shutil.copytree(fleet_dir, root)
    ca = (root / "ca.pem").read_bytes()
    alice = (root / "operator/alice/cert.pem").read_bytes()
    said: list[str] = []
    report = make(root, [Identity("operator", "carol")], remove=("bob",), say=said.append)
    assert (root / "ca.pem").read_bytes() == ca
    assert (root / "operator/alice/cert.pem").read_bytes() == alice
    assert [str(w) for w in report.made] == ["operator/carol"]
    assert not (root / "viewer/bob").exists()
    assert any(line.startswith("viewer bob: removed") for line in said)
    acl = json.loads(zenoh.Config.from_file(str(root / "base/robot1/zenoh.json5")).get_json(
        "access_control"))
    names = {n for s in acl["subjects"] for n in s["cert_common_names"]}
    assert "carol" in names and "bob" not in names
    with pytest.raises(ConfigError, match="fleet of domain 7, not 3"):
        make(root, [], domain_id=3)
    with pytest.raises(ConfigError, match="already a operator"):
        make(root, [Identity("base", "carol")])


def test_it_will_not_write_into_a_folder_it_did_not_make(tmp_path: Path) -> None:
    pytest.importorskip("cryptography")
    from omnican.zenoh.credentials import make

    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty, and not a folder this command made"):
        make(tmp_path, [Identity("base", "robot1")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_credentials_that_are_not_there_are_named(fleet_dir: Path, tmp_path: Path) -> None:
    from omnican.zenoh.bridge import session_config

    def settings(root: Path, identity: str) -> ZenohSettings:
        return ZenohSettings(credentials=str(root), identity=identity,
                             namespace="/robot1")

    with pytest.raises(ConfigError, match="no such folder"):
        session_config(settings(tmp_path / "nowhere", "base/robot1"))
    with pytest.raises(ConfigError, match=r"no base/robot9/cert\.pem for base/robot9 \(no "
                                          r"base/robot9 there"):
        session_config(settings(fleet_dir, "base/robot9"))


def test_the_credentials_command_says_what_it_made(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("cryptography")
    from omnican.cli import main

    root = tmp_path / "fleet"
    assert main(["zenoh", "credentials", str(root), "--base", "robot1", "--operator",
                 "alice", "--viewer", "bob"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"CA: made {root}/ca.pem (omnican fleet CA ")
    assert [line.split(":")[0] for line in out[1:5]] == [
        "router router", "base robot1", "operator alice", "viewer bob"]
    assert out[5] == (f"fleet of domain 0 in {root}: 1 router, 1 base, 1 operator, 1 viewer "
                      "(made 4, kept 0); every zenoh.json5 reads in Zenoh")
    assert any(f"--zenoh-credentials {root} --zenoh-identity base/NAME --namespace /NAME"
               in line for line in out)

    assert main(["zenoh", "credentials", str(root), "--operator", "carol"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"CA: kept {root}/ca.pem")
    assert "(made 1, kept 4)" in out[2]
    assert out[3].startswith("the access control changed: give every base and router")

    for argv, words in ((["--base", "robot-1"], "--base robot-1: base name 'robot-1' is "
                         "not a namespace chunk"),
                        (["--viewer", "carol"], "'carol' is already a operator"),
                        ([], None)):
        fresh = root if argv else tmp_path / "empty"
        assert main(["zenoh", "credentials", str(fresh), *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        assert (words or "name the members: --base NAME") in err


def test_a_viewers_recover_is_refused_before_anything_is_asked(
        fleet_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Unanswered (its certificate lets no recover through), a viewer's recover read as
    'nothing serves its recover service': a base that seemed gone. It is refused in one
    line, before a session opens; an operator's is not."""
    from omnican.cli import main
    from omnican.cli.fleet import may_recover

    common = ["--zenoh-credentials", str(fleet_dir), "--zenoh-connect", "tls/127.0.0.1:1"]
    assert main(["fleet", *common, "--zenoh-identity", "viewer/bob", "--recover", "robot1",
                 "--domain-id", "7"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a viewer may only stop" in err
    assert not may_recover(ZenohSettings(credentials=str(fleet_dir), identity="viewer/bob"))
    assert may_recover(ZenohSettings(credentials=str(fleet_dir), identity="operator/alice"))
    assert may_recover(ZenohSettings())  # no credentials: the base decides
