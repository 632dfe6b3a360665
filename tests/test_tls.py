"""A TLS-only dask cluster on loopback: certificates made here, plaintext refused."""

import datetime
import ipaddress
import os
import sys
from pathlib import Path

import pytest
from conftest import ROOT, TINY_SCENE, assert_same_samples, dask_processes, run_cli

from service.run import execute
from service.store.location import Store
from service.sweep import parse_sweep

x509 = pytest.importorskip("cryptography.x509")
from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import NameOID  # noqa: E402

BIN = Path(sys.executable).parent

SWEEP = TINY_SCENE.format(name="tls", seed=4, realisations=2, output="tls.zarr")


def certificates(folder: Path):
    """A CA, and one certificate it signs for 127.0.0.1 (scheduler, workers, client)."""
    now = datetime.datetime.now(datetime.UTC)

    def name(common):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common)])

    def write(path, key, cert):
        (folder / f"{path}.key").write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM,
                serialization.PrivateFormat.PKCS8,
                serialization.NoEncryption(),
            )
        )
        (folder / f"{path}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("oceanlidar test CA"))
        .issuer_name(name("oceanlidar test CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    write("ca", ca_key, ca)
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (
        x509.CertificateBuilder()
        .subject_name(name("127.0.0.1"))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(
            x509.SubjectAlternativeName(
                [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
            ),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )
    write("node", key, cert)
    return folder / "ca.pem", folder / "node.pem", folder / "node.key"


@pytest.fixture(scope="module")
def tls_cluster(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tls")
    ca, cert, key = certificates(folder)
    files = ["--tls-ca-file", str(ca), "--tls-cert", str(cert), "--tls-key", str(key)]
    env = {"PYTHONPATH": str(ROOT), "DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION": "True"}
    with dask_processes(folder, protocol="tls", options=files, env=env) as address:
        yield address, int(address.rsplit(":", 1)[1]), [str(ca), str(cert), str(key)]


def test_a_sweep_over_tls_writes_the_embedded_bytes(tls_cluster, tmp_path, cli, shared_cluster):
    address, _, (ca, cert, key) = tls_cluster
    sweep = tmp_path / "s.yaml"
    sweep.write_text(SWEEP)
    tls = ["--tls-ca-file", ca, "--tls-cert", cert, "--tls-key", key]
    output = tmp_path / "tls.zarr"
    result = cli("run", sweep, "--scheduler", address, *tls, "--output", output, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    local = str(tmp_path / "local.zarr")
    execute(parse_sweep(SWEEP), Store.at(local), workers=1, progress_stream=open(os.devnull, "w"))
    assert_same_samples(output, local)


def test_a_plaintext_client_is_refused_and_nothing_is_written(tls_cluster, tmp_path):
    _, port, _ = tls_cluster
    sweep = tmp_path / "s.yaml"
    sweep.write_text(SWEEP)
    result = run_cli(
        "run",
        sweep,
        "--scheduler",
        f"tcp://127.0.0.1:{port}",
        "--output",
        tmp_path / "plain.zarr",
        cwd=tmp_path,
        env={"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "5s"},
    )
    assert result.returncode == 1
    assert "cannot connect to the scheduler" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "plain.zarr").exists()


def test_the_service_runs_its_jobs_on_a_tls_cluster(tls_cluster, tmp_path, shared_cluster):
    from test_server import Server, finished

    address, _, (ca, cert, key) = tls_cluster
    tls = ["--tls-ca-file", ca, "--tls-cert", cert, "--tls-key", key]
    server = Server(tmp_path, "--scheduler", address, *tls)
    try:
        server.start()
        status, job = server.submit(SWEEP)
        assert status == 201, job
        job = server.wait(job["id"], finished)
        assert job["state"] == "succeeded", job
    finally:
        server.stop()
    local = str(tmp_path / "local.zarr")
    execute(parse_sweep(SWEEP), Store.at(local), workers=1, progress_stream=open(os.devnull, "w"))
    assert_same_samples(job["url"], local)
