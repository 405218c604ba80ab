"""The secured bus of deploy/secure on loopback: TLS links, user names and passwords, and the
router's access-control policy. Certificates and passwords are made here, in a temporary directory,
and the configs are the committed templates with only their secret paths and passwords filled in."""
from __future__ import annotations

import datetime
import ipaddress
import secrets
import socket
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
SWITCH_TOPICS = ("motor", "throw", "truth", "diagnosis", "inject")
MAY_PUBLISH = {  # issue 6, item 4: the policy the router must enforce
    "simulator": {"motor", "throw", "truth", "inject"},
    "diagnoser": {"diagnosis"},
    "recorder": set(),
    "operator": {"inject"},
}


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
def delivered(bus) -> Counter[tuple[str, str]]:
    """How many messages per (user, topic) a recorder-user subscriber received when every user published
    REPEATS times on every topic of switch sw1 and on its status key. Forbidden topics go first, so that
    by the time a user's allowed messages have arrived its forbidden ones would have too."""
    received: Counter[tuple[str, str]] = Counter()
    lock = threading.Lock()

    def on_sample(sample: zenoh.Sample) -> None:
        with lock:
            received[tuple(sample.payload.to_bytes().decode().split(" "))] += 1

    def complete() -> bool:
        with lock:
            return all(received[(user, topic)] >= REPEATS for user, topic in allowed)

    allowed = {(user, topic) for user, topics in MAY_PUBLISH.items() for topic in topics}
    allowed |= {(user, "status") for user in USERS}
    with bus.session("recorder") as reader:
        reader.declare_subscriber("railswitch/**", on_sample)
        sessions = {user: bus.session(user) for user in USERS}
        try:
            for user, session in sessions.items():
                publishers = Publishers(session)
                for topic in sorted(SWITCH_TOPICS, key=lambda t: t in MAY_PUBLISH[user]):
                    for _ in range(REPEATS):
                        publishers.put(f"railswitch/sw1/{topic}", f"{user} {topic}".encode())
                for _ in range(REPEATS):
                    publishers.put(f"railswitch/service/{user}/test-1/status", f"{user} status".encode())
            wait_for(complete, 10, f"{REPEATS} of each allowed publication")
            time.sleep(0.5)
        finally:
            for session in sessions.values():
                session.close()
    with lock:
        return Counter(received)


def _publishers_of(delivered: Counter[tuple[str, str]], topic: str) -> set[str]:
    return {user for user, t in delivered if t == topic}


def test_only_the_diagnoser_user_gets_a_diagnosis_through(delivered):
    assert _publishers_of(delivered, "diagnosis") == {"diagnoser"}


@pytest.mark.parametrize("topic", ["motor", "throw", "truth"])
def test_only_the_simulator_user_gets_plant_messages_through(delivered, topic):
    assert _publishers_of(delivered, topic) == {"simulator"}


def test_only_the_operator_and_simulator_users_inject_faults(delivered):
    assert _publishers_of(delivered, "inject") == {"operator", "simulator"}


def test_every_user_publishes_its_status(delivered):
    assert _publishers_of(delivered, "status") == set(USERS)


def test_every_allowed_message_arrives_not_only_the_first(delivered):
    assert set(delivered.values()) == {REPEATS}


def test_every_user_declares_a_liveliness_token_that_a_reader_sees(bus):
    sessions = {user: bus.session(user) for user in USERS}
    try:
        tokens = [s.liveliness().declare_token(f"railswitch/service/{u}/test-2") for u, s in sessions.items()]
        with bus.session("recorder") as reader:
            def alive() -> set[str]:
                replies = reader.liveliness().get("railswitch/service/*/test-2")
                return {str(r.ok.key_expr).split("/")[2] for r in replies if r.ok is not None}
            wait_for(lambda: alive() == set(USERS), 10, "every user's liveliness token")
        for token in tokens:
            token.undeclare()
    finally:
        for session in sessions.values():
            session.close()


# -- the services themselves -----------------------------------------------------------------------
def test_simulator_and_diagnoser_processes_deliver_a_diagnosis_through_the_secured_router(bus, tmp_path):
    with ServiceProcesses(tmp_path) as services, bus.session("recorder") as reader:
        collector = DiagnosisCollector(reader)
        services.start("diagnoser", "--zenoh-config", bus.config_file("diagnoser"), "--connect", bus.endpoint)
        wait_ready(reader, services, timeout_s=60, diagnoser=1)  # up to ~15 s of compiling on a cold cache
        simulator = services.start("simulator", "--zenoh-config", bus.config_file("simulator"), "--connect",
                                   bus.endpoint, "--switch-id", "sw2", "--throws", "1", "--speed", "20")
        assert simulator.wait(60) == 0, services.log(simulator)
        wait_for(lambda: collector.received, 30, "a diagnosis of sw2")
    assert [(d.switch_id, d.throw_index, d.decision) for d in collector.received] == [("sw2", 0, "nominal")]
