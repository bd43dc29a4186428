"""Cluster options of the commands (docs/cluster.md): ``--workers K --processes`` runs K
local worker processes (loopback only, stopped with the command, the numbers of an in-process run);
``pst`` and ``study`` reach a TLS-secured scheduler with ``--tls-ca-file/--tls-cert/--tls-key`` as
``trace`` does (a real TLS scheduler on 127.0.0.1 with certificates made by openssl here); wrong
combinations are one-line errors.

The expected numbers come from the same commands run in this process."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import psutil
import pytest

from straylight.cli.main import main
from straylight.execution import Execution
from test_cluster import GOLDEN, OPTIONS, _non_loopback, listening_addresses

SCENE = GOLDEN / "tube.toml"


def test_processes_flag_runs_worker_processes_with_identical_numbers(tmp_path):
    from straylight.cli.cluster_args import cluster_client
    from straylight.cli.main import build_parser
    from straylight.scene import load_scene
    from straylight.trace import trace

    rs = load_scene(SCENE)
    reference = trace(rs.scene, rs.sources, 20_000, 5, materials=rs.materials, options=OPTIONS).to_json_dict()
    args = build_parser().parse_args(["trace", str(SCENE), "--rays", "20000", "--workers", "2", "--processes",
                                      "--json", str(tmp_path / "out.json")])
    me = psutil.Process()
    with cluster_client(args) as client:
        pids = client.run(os.getpid)
        assert len(pids) == 2 and os.getpid() not in pids.values()  # two processes, not this one
        assert all(w["nthreads"] == 1 for w in client.scheduler_info()["workers"].values())
        assert not _non_loopback(listening_addresses())
        res = trace(rs.scene, rs.sources, 20_000, 5, materials=rs.materials, options=OPTIONS, execution=Execution(client=client))
    assert res.to_json_dict() == reference
    alive = [p for p in pids.values() if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"worker processes left running after the command: {alive}"
    assert me.is_running()


@pytest.mark.parametrize("argv, message", [
    (["--processes"], "--processes needs --workers K"),
    (["--tls-cert", "x.pem", "--tls-ca-file", "y.pem", "--workers", "2"], "--tls-ca-file y.pem: no such file"),
])
@pytest.mark.parametrize("command", ["trace", "pst", "study"])
def test_cluster_flag_errors_are_one_line(tmp_path, capsys, command, argv, message):
    head = {"trace": ["trace", str(SCENE), "--rays", "100", "--json", str(tmp_path / "o.json")],
            "pst": ["pst", str(SCENE), "--rays", "100", "--angles-deg", "0", "--out", str(tmp_path / "o")],
            "study": ["study", str(SCENE), "--rays", "100", "--no-sweep", "--out", str(tmp_path / "o")]}[command]
    assert main(head + argv) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("straylight: error")]
    assert len(errors) == 1 and message in errors[0], errors


def test_tls_files_apply_to_a_scheduler_only(tmp_path, capsys):
    for name in ("ca.pem", "c.pem"):
        (tmp_path / name).write_text("-")
    argv = ["pst", str(SCENE), "--rays", "100", "--angles-deg", "0", "--out", str(tmp_path / "o"), "--workers", "2",
            "--tls-ca-file", str(tmp_path / "ca.pem"), "--tls-cert", str(tmp_path / "c.pem")]
    assert main(argv) == 2
    assert "apply to --scheduler only" in capsys.readouterr().err


def _openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture(scope="module")
def tls_scheduler(tmp_path_factory):
    """An in-process dask cluster (scheduler + one worker) speaking TLS only on 127.0.0.1, with a CA
    and one certificate made by openssl; yields (address, ca, cert, key)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make test certificates")
    from dask.distributed import LocalCluster, Security

    d = tmp_path_factory.mktemp("tls")
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=test-ca",
             "-keyout", "ca.key", "-out", "ca.pem", cwd=d)
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=straylight", "-keyout", "node.key",
             "-out", "node.csr", cwd=d)
    _openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-days", "2",
             "-out", "node.pem", cwd=d)
    ca, cert, key = (str(d / n) for n in ("ca.pem", "node.pem", "node.key"))
    sec = Security(tls_ca_file=ca, tls_scheduler_cert=cert, tls_scheduler_key=key, tls_worker_cert=cert,
                   tls_worker_key=key, tls_client_cert=cert, tls_client_key=key, require_encryption=True)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tls://", host="127.0.0.1",
                      security=sec, dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tls://127.0.0.1:")
        yield cluster.scheduler_address, ca, cert, key


def _tls_args(tls):
    address, ca, cert, key = tls
    return ["--scheduler", address, "--tls-ca-file", ca, "--tls-cert", cert, "--tls-key", key]


def _without_seconds(doc):
    return {**doc, "points": [{k: v for k, v in p.items() if k != "seconds"} for p in doc["points"]]}


def test_pst_on_a_tls_scheduler_gives_the_in_process_numbers(tls_scheduler, tmp_path):
    argv = ["pst", str(SCENE), "--rays", "3000", "--seed", "4", "--angles-deg", "0", "15"]
    assert main(argv + ["--out", str(tmp_path / "here")]) == 0
    assert main(argv + ["--out", str(tmp_path / "tls")] + _tls_args(tls_scheduler)) == 0
    here, tls = (json.loads((tmp_path / d / "pst.json").read_text()) for d in ("here", "tls"))
    assert _without_seconds(tls) == _without_seconds(here)


def test_study_on_a_tls_scheduler_gives_the_in_process_numbers(tls_scheduler, tmp_path):
    argv = ["study", str(SCENE), "--rays", "1000", "--seed", "4", "--angles-deg", "0", "15", "--path-angle-deg", "15"]
    assert main(argv + ["--out", str(tmp_path / "here")]) == 0
    assert main(argv + ["--out", str(tmp_path / "tls")] + _tls_args(tls_scheduler)) == 0
    here, tls = (json.loads((tmp_path / d / "results.json").read_text().replace(str(tmp_path / d), "OUT"))
                 for d in ("here", "tls"))
    assert tls["execution"]["scheduler"] == tls_scheduler[0]
    for doc in (here, tls):
        doc.pop("timings_s"), doc.pop("config"), doc.pop("execution")
        doc["pst"] = _without_seconds(doc["pst"])
    assert tls == here
    assert Path(tmp_path / "tls" / "index.html").is_file()
