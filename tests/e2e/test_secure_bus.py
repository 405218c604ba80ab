"""The secured bus of deploy/secure on loopback: TLS links, user names and passwords, and the
router's access-control policy. Certificates and passwords are made here, in a temporary directory,
and the configs are the committed templates with only their secret paths and passwords filled in."""
from __future__ import annotations

import datetime
import ipaddress
import json
import secrets
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from railswitch.services.adapters.zenoh_bus import BusOptions, Publishers, open_session, zenoh_config
from railswitch.services.adapters.processes import free_loopback_endpoint
from tests.live import ROOT, DiagnosisCollector, ServiceProcesses, wait_for, wait_ready

TEMPLATES = ROOT / "deploy" / "secure"
SECRETS_DIR = "/etc/railswitch/secure"  # where the templates expect certificates and credentials
PLACEHOLDER = "REPLACE-WITH-A-RANDOM-PASSWORD"
USERS = [line.split(":")[0] for line in (TEMPLATES / "credentials.txt.example").read_text().split()]
SWITCH_TOPICS = ("motor", "throw", "truth", "record", "diagnosis", "health", "state", "inject", "commission", "alarm",
                 "ack", "maintenance")
MAY_PUBLISH = {  # the policy the router must enforce (deploy/secure/README.md)
    "simulator": {"motor", "throw", "truth", "record", "inject"},
    "diagnoser": {"diagnosis", "health", "state", "alarm"},
    "historian": set(),
    "recorder": set(),
    "operator": {"inject", "commission", "ack", "maintenance"},
    "notify": set(),
    "reader": set(),
}
SERVICES = ("simulator", "replay", "diagnoser", "historian", "recorder", "notify")
MAY_ANNOUNCE = {"simulator": {"simulator", "replay"}, "diagnoser": {"diagnoser"}, "historian": {"historian"},
                "recorder": {"recorder"}, "operator": set(), "notify": {"notify"}, "reader": set()}
# What a subscriber to switch data listens on: every switch's channel of one kind, and everything
SWITCH_PATTERNS = tuple(f"railswitch/*/{topic}" for topic in SWITCH_TOPICS) + ("railswitch/**",)


# -- certificates, as the openssl recipe of deploy/secure/README.md makes them ---------------------
def _certificate(subject: str, key: ec.EllipticCurvePrivateKey, issuer: str, issuer_key: ec.EllipticCurvePrivateKey,
                 extensions: list[tuple[x509.ExtensionType, bool]]) -> x509.Certificate:
    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (x509.CertificateBuilder()
               .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
               .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer)]))
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1)))
    for extension, critical in extensions:
        builder = builder.add_extension(extension, critical=critical)
    return builder.sign(issuer_key, hashes.SHA256())


def write_ca(path: Path, name: str) -> ec.EllipticCurvePrivateKey:
    """A self-signed certificate authority at path; its key stays in memory."""
    key = ec.generate_private_key(ec.SECP256R1())
    usage = x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                          data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
                          encipher_only=False, decipher_only=False)
    ca = _certificate(name, key, name, key, [(x509.BasicConstraints(ca=True, path_length=None), True), (usage, True)])
    path.write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    return key


def write_router_certificate(directory: Path, ca_name: str, ca_key: ec.EllipticCurvePrivateKey) -> None:
    """router.pem (names localhost and 127.0.0.1) and router-key.pem, signed by the CA."""
    key = ec.generate_private_key(ec.SECP256R1())
    names = x509.SubjectAlternativeName([x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))])
    certificate = _certificate("router", key, ca_name, ca_key,
                               [(names, False), (x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), False)])
    (directory / "router.pem").write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
    (directory / "router-key.pem").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))


# -- the bus ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SecureBus:
    endpoint: str  # tls/127.0.0.1:<port>
    configs: Path  # <name>.json5 for the router and every user, made from the templates
    secrets_dir: Path  # what ./secrets holds in a deployment

    def config_file(self, name: str) -> str:
        return str(self.configs / f"{name}.json5")

    def options(self, user: str) -> BusOptions:
        return BusOptions(config_file=self.config_file(user), connect=(self.endpoint,))

    def session(self, user: str) -> zenoh.Session:
        """A client session of the test as `user`, through the project's own session helper."""
        return open_session(self.options(user), retry=False)


def _from_template(name: str, secrets_dir: Path, password: str | None) -> str:
    text = (TEMPLATES / f"{name}.json5").read_text()
    assert SECRETS_DIR in text
    if password is not None:
        assert PLACEHOLDER in text
        text = text.replace(PLACEHOLDER, password)
    return text.replace(SECRETS_DIR, str(secrets_dir))


def _listening(endpoint: str) -> bool:
    host, _, port = endpoint.split("/")[1].rpartition(":")
    with socket.socket() as probe:
        return probe.connect_ex((host, int(port))) == 0


@pytest.fixture(scope="module")
def bus(tmp_path_factory) -> Iterator[SecureBus]:
    """A `railswitch router` process with deploy/secure/router.json5, fresh certificates and passwords."""
    work = tmp_path_factory.mktemp("secure")
    secrets_dir, configs = work / "secrets", work / "configs"
    secrets_dir.mkdir()
    configs.mkdir()
    write_router_certificate(secrets_dir, "railswitch test CA", write_ca(secrets_dir / "ca.pem", "railswitch test CA"))
    passwords = {user: secrets.token_urlsafe(24) for user in USERS}
    (secrets_dir / "credentials.txt").write_text("".join(f"{user}:{pw}\n" for user, pw in passwords.items()))
    (configs / "router.json5").write_text(_from_template("router", secrets_dir, None))
    for user, password in passwords.items():
        (configs / f"{user}.json5").write_text(_from_template(user, secrets_dir, password))
    endpoint = free_loopback_endpoint().replace("tcp/", "tls/", 1)
    with ServiceProcesses(work) as services:
        router = services.start("router", "--zenoh-config", str(configs / "router.json5"), "--listen", endpoint)
        wait_for(lambda: _listening(endpoint), 30, f"the router on {endpoint}",
                 abort=lambda: router.poll() is not None and f"router exited:\n{services.log(router)}")
        yield SecureBus(endpoint, configs, secrets_dir)


# -- who may connect -------------------------------------------------------------------------------
def _open_fails(config: zenoh.Config) -> str:
    """What open() says; services' configs give up after connect/timeout_ms (2 s)."""
    with pytest.raises(zenoh.ZError) as refused:
        zenoh.open(config).close()
    return str(refused.value)


def test_a_client_with_the_recorder_credentials_connects(bus):
    with bus.session("recorder") as session:
        assert session.info.routers_zid()


def test_a_client_without_credentials_is_refused(bus):
    # zenoh 1.10.2: the router answers the client's InitSyn with a Close message (so says the client's
    # zenoh log, when enabled); open() only says that it could not connect, after connect/timeout_ms.
    config = zenoh_config(bus.options("recorder"))
    config.insert_json5("transport/auth/usrpwd", '{"user": null, "password": null}')
    assert "Unable to connect" in _open_fails(config)


def test_a_client_with_a_wrong_password_is_refused(bus):
    # The router answers the OpenSyn, which carries the password proof, with a Close (reason GENERIC).
    config = zenoh_config(bus.options("recorder"))
    config.insert_json5("transport/auth/usrpwd/password", '"not-the-password"')
    assert "Unable to connect" in _open_fails(config)


def test_a_client_that_trusts_another_ca_is_refused(bus):
    # rustls rejects the router's certificate: "invalid peer certificate: UnknownIssuer".
    foreign_ca = bus.secrets_dir / "foreign-ca.pem"
    write_ca(foreign_ca, "someone else's CA")
    config = zenoh_config(bus.options("recorder"))
    config.insert_json5("transport/link/tls/root_ca_certificate", f'"{foreign_ca}"')
    assert "Unable to connect" in _open_fails(config)


def test_a_plain_tcp_client_cannot_connect_to_the_tls_endpoint(bus):
    # Valid credentials, but no TLS: the router's TLS acceptor closes the link ("early eof").
    tcp_endpoint = bus.endpoint.replace("tls/", "tcp/")
    config = zenoh_config(BusOptions(config_file=bus.config_file("recorder"), connect=(tcp_endpoint,)))
    config.insert_json5("transport/link/protocols", '["tcp"]')
    assert "Unable to connect" in _open_fails(config)


# -- what each user may do -------------------------------------------------------------------------
REPEATS = 20  # not 1: a publisher that never learns of the subscriber still gets its first message through


@pytest.fixture(scope="module")
def delivered(bus) -> Counter[tuple[str, str, str]]:
    """How many messages per (pattern, user, key) the subscribers of a recorder-user session received when every
    user published REPEATS times on every topic of switch sw1, on every announcement key of every service, and on
    every key the announcements once lived under (railswitch/service/<topic>: the switch `service` now). One
    subscriber per switch pattern, and one on railswitch/@service/**. Forbidden keys go first, so that by the time a
    user's allowed messages have arrived its forbidden ones would have too."""
    received: Counter[tuple[str, str, str]] = Counter()
    lock = threading.Lock()

    def on_sample(pattern: str, sample: zenoh.Sample) -> None:
        with lock:
            received[(pattern, sample.payload.to_bytes().decode(), str(sample.key_expr))] += 1

    keys = {user: [f"railswitch/{switch}/{topic}" for switch in ("sw1", "service") for topic in SWITCH_TOPICS]
            + [f"railswitch/@service/{service}/test-1/status" for service in SERVICES] for user in USERS}
    allowed = {(user, key) for user, user_keys in keys.items() for key in user_keys if _may_put(user, key)}

    def complete() -> bool:
        with lock:
            arrived = {(user, key) for _, user, key in received}
            return allowed <= arrived and all(n >= REPEATS for n in received.values())

    with bus.session("recorder") as reader:
        for pattern in SWITCH_PATTERNS + ("railswitch/@service/**",):
            reader.declare_subscriber(pattern, lambda sample, pattern=pattern: on_sample(pattern, sample))
        sessions = {user: bus.session(user) for user in USERS}
        try:
            for user, session in sessions.items():
                publishers = Publishers(session)
                for key in sorted(keys[user], key=lambda k: _may_put(user, k)):
                    for _ in range(REPEATS):
                        publishers.put(key, user.encode())
            wait_for(complete, 15, f"{REPEATS} of each allowed publication")
            time.sleep(0.5)
        finally:
            for session in sessions.values():
                session.close()
    with lock:
        return Counter(received)


def _may_put(user: str, key: str) -> bool:
    chunks = key.split("/")
    if chunks[1] == "@service":
        return chunks[2] in MAY_ANNOUNCE[user]
    return chunks[2] in MAY_PUBLISH[user]


def _publishers_of(delivered: Counter[tuple[str, str, str]], topic: str) -> set[str]:
    return {user for _, user, key in delivered if key == f"railswitch/sw1/{topic}"}


@pytest.mark.parametrize("topic", SWITCH_TOPICS)
def test_only_the_users_allowed_a_topic_get_it_through(delivered, topic):
    assert _publishers_of(delivered, topic) == {user for user, topics in MAY_PUBLISH.items() if topic in topics}


def test_a_switch_named_service_is_a_switch_like_any_other(delivered):
    """railswitch/service/<topic> once held service announcements, which every user could put: now it is switch
    `service`, which only the users allowed a topic may publish."""
    got = {(user, key.split("/")[2]) for _, user, key in delivered if key.split("/")[1] == "service"}
    assert got == {(user, topic) for user, topics in MAY_PUBLISH.items() for topic in topics}


def test_each_user_announces_only_its_own_services(delivered):
    got = {(user, key.split("/")[2]) for _, user, key in delivered if key.split("/")[1] == "@service"}
    assert got == {(user, service) for user, services in MAY_ANNOUNCE.items() for service in services}


@pytest.mark.parametrize("pattern", SWITCH_PATTERNS)
def test_no_announcement_reaches_a_switch_subscriber(delivered, pattern):
    """Whatever any user puts under railswitch/@service/ (allowed or not), a subscriber of switch data never sees
    it; and on each pattern, only what the publishing user may put arrives."""
    got = [(user, key) for p, user, key in delivered if p == pattern]
    assert got and not [key for _, key in got if key.split("/")[1] == "@service"]
    assert all(_may_put(user, key) for user, key in got)


def test_every_allowed_message_arrives_not_only_the_first(delivered):
    assert set(delivered.values()) == {REPEATS}


def test_each_user_declares_liveliness_tokens_only_for_its_own_services(bus):
    sessions = {user: bus.session(user) for user in USERS}
    try:
        tokens = [s.liveliness().declare_token(f"railswitch/@service/{service}/test-2-{user}")
                  for user, s in sessions.items() for service in SERVICES]
        tokens += [s.liveliness().declare_token(f"railswitch/{switch}/test-2-{user}")
                   for user, s in sessions.items() for switch in ("sw1", "service")]
        expected = {(service, f"test-2-{user}") for user, services in MAY_ANNOUNCE.items() for service in services}
        with bus.session("recorder") as reader:
            def alive(pattern: str) -> set[tuple[str, str]]:
                replies = reader.liveliness().get(pattern)
                return {tuple(str(r.ok.key_expr).split("/")[-2:]) for r in replies if r.ok is not None}
            wait_for(lambda: alive("railswitch/@service/*/*") == expected, 10, "each user's own liveliness tokens")
            time.sleep(0.5)
            assert alive("railswitch/@service/*/*") == expected
            assert alive("railswitch/**") == set()  # no token outside the announcements, and none of them
        for token in tokens:
            token.undeclare()
    finally:
        for session in sessions.values():
            session.close()


def test_only_the_recorder_answers_for_a_stream_s_recent_throws(bus):
    """Whoever answers railswitch/*/recent hands a restarted diagnoser throws to diagnose: only the recorder user may
    (readers have a user of their own for that reason)."""
    sessions = {user: bus.session(user) for user in USERS}
    try:
        queryables = [session.declare_queryable(  # noqa: F841 - kept declared while asked
            "railswitch/sw1/recent", lambda query, user=user: query.reply("railswitch/sw1/recent", user.encode()))
            for user, session in sessions.items()]
        with bus.session("diagnoser") as asker:
            def answered() -> set[str]:
                return {reply.ok.payload.to_bytes().decode() for reply in asker.get("railswitch/*/recent", timeout=2.0)
                        if reply.ok is not None}
            wait_for(lambda: "recorder" in answered(), 10, "the recorder's answer")
            time.sleep(0.5)
            assert answered() == {"recorder"}
    finally:
        for session in sessions.values():
            session.close()


# -- the services themselves -----------------------------------------------------------------------
def test_simulator_diagnoser_and_historian_processes_work_through_the_secured_router(bus, tmp_path):
    """Each service as its own user: the diagnosis reaches a reader, and the historian answers a reader's history
    query (`railswitch history` as the reader user)."""
    with ServiceProcesses(tmp_path) as services, bus.session("reader") as reader:
        collector = DiagnosisCollector(reader)
        services.start("diagnoser", "--zenoh-config", bus.config_file("diagnoser"), "--connect", bus.endpoint)
        services.start("historian", "--zenoh-config", bus.config_file("historian"), "--connect", bus.endpoint,
                       "--db", str(tmp_path / "history.sqlite"))
        wait_ready(reader, services, timeout_s=60, diagnoser=1, historian=1)  # up to ~15 s compiling on a cold cache
        simulator = services.start("simulator", "--zenoh-config", bus.config_file("simulator"), "--connect",
                                   bus.endpoint, "--switch-id", "sw2", "--throws", "1", "--speed", "20")
        assert simulator.wait(60) == 0, services.log(simulator)
        wait_for(lambda: collector.received, 30, "a diagnosis of sw2")

        def history() -> list[dict]:
            answer = subprocess.run([sys.executable, "-m", "railswitch", "history", "sw2", "--kind", "diagnosis",
                                     "--json", "--zenoh-config", bus.config_file("reader"), "--connect",
                                     bus.endpoint, "--timeout", "5"], capture_output=True, text=True, timeout=60)
            assert answer.returncode == 0, answer.stderr
            return [json.loads(line) for line in answer.stdout.splitlines()]
        stored: list[dict] = []
        wait_for(lambda: stored.extend(history()) or stored, 30, "the historian's answer")
    assert [(d.switch_id, d.throw_index, d.decision) for d in collector.received] == [("sw2", 0, "nominal")]
    assert [(d["switch_id"], d["throw_index"], d["decision"]) for d in stored] == [("sw2", 0, "nominal")]


def test_a_diagnoser_started_late_catches_up_from_the_simulators_cache_through_the_secured_router(bus, tmp_path):
    """The advanced publishers' caches live under <key>/@adv/, which the policy must let the simulator keep and
    the diagnoser ask: the records published before any diagnoser ran are diagnosed once one starts. The simulator
    throws for 100 s, so that it outlives a diagnoser that starts cold (compiling its model first)."""
    with ServiceProcesses(tmp_path) as services, bus.session("recorder") as reader:
        collector = DiagnosisCollector(reader)
        simulator = services.start("simulator", "--zenoh-config", bus.config_file("simulator"), "--connect",
                                   bus.endpoint, "--switch-id", "sw3", "--throws", "200", "--interval", "10",
                                   "--speed", "20", "--as-records")
        early = threading.Event()
        reader.declare_subscriber("railswitch/sw3/record", lambda sample: early.set())
        wait_for(early.is_set, 60, "the first record")
        services.start("diagnoser", "--zenoh-config", bus.config_file("diagnoser"), "--connect", bus.endpoint)
        wait_for(lambda: ("sw3", 0) in collector.decisions(), 90, "throw 0, published before the diagnoser ran")
        assert simulator.poll() is None, "the simulator (and its cache) must outlive the diagnoser's start"
    assert ("sw3", 0) in collector.decisions()


def test_a_diagnoser_started_late_gets_a_sample_stream_s_throws_from_the_recorder_through_the_secured_router(
        bus, tmp_path):
    """A stream's throws that ended before any diagnoser ran come from the recorder's answer on railswitch/*/recent,
    which the policy lets the recorder give and the diagnoser ask for."""
    with ServiceProcesses(tmp_path) as services, bus.session("reader") as reader:
        collector = DiagnosisCollector(reader)
        services.start("recorder", "--zenoh-config", bus.config_file("recorder"), "--connect", bus.endpoint,
                       "--out", str(tmp_path / "secure.mcap"))
        wait_ready(reader, services, timeout_s=60, recorder=1)
        simulator = services.start("simulator", "--zenoh-config", bus.config_file("simulator"), "--connect",
                                   bus.endpoint, "--switch-id", "sw4", "--throws", "200", "--interval", "10",
                                   "--speed", "20")
        ended = threading.Event()
        reader.declare_subscriber("railswitch/sw4/throw",
                                  lambda sample: json.loads(sample.payload.to_bytes())["phase"] == "end" and ended.set())
        wait_for(ended.is_set, 60, "the first throw's end")
        services.start("diagnoser", "--zenoh-config", bus.config_file("diagnoser"), "--connect", bus.endpoint)
        wait_for(lambda: ("sw4", 0) in collector.decisions(), 90, "throw 0, streamed before the diagnoser ran")
        assert simulator.poll() is None, "the diagnoser must have started while the stream went on"
    assert ("sw4", 0) in collector.decisions()
