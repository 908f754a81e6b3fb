"""Sweeps on dask.distributed: byte-identical output, resuming, a killed worker, the command line."""

import os
import signal

import pytest

distributed = pytest.importorskip("distributed")

import lenssim_studies.cluster  # noqa: E402
from lenssim_studies.cluster import ClusterError, _chunk_task, compute_chunks, dask_client  # noqa: E402
from lenssim.model.camera import Camera  # noqa: E402
from lenssim.model.numerics import FAST_NUMERICS  # noqa: E402
from lenssim_studies.sweep import SweepConfig, _checksum, _compute_chunk, run_sweep  # noqa: E402
from lenssim.torch_utils import select_device  # noqa: E402
import dataclasses
from lenssim_studies.paper import PAPER_LENS, PAPER_SENSOR, PAPER_SPECTRUM

CFG = SweepConfig(camera=Camera(dataclasses.replace(PAPER_LENS, field_angles_deg=(0.0, 5.0, 10.0, 14.0)), PAPER_SENSOR, PAPER_SPECTRUM),
                  grid={"s": (-1.5, 0.0, 0.25), "Q_back": (-6.0, 0.0, 2.0)}, numerics=FAST_NUMERICS)


@pytest.fixture(scope="module")
def serial_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "serial.nc"
    run_sweep(CFG, out, device="cpu", show_progress=False)
    return out


def test_two_local_workers_write_the_single_process_file_byte_for_byte(serial_file, tmp_path):
    out = tmp_path / "cluster.nc"
    # interrupted after 3 chunks (the finished ones stay), then resumed on the cluster
    assert run_sweep(CFG, out, device="cpu", show_progress=False, workers=2, max_chunks=3) is None
    assert len(list((tmp_path / "cluster.nc.partial").glob("chunk_*.npz"))) == 3
    ds = run_sweep(CFG, out, device="cpu", show_progress=False, workers=2)
    assert ds is not None and out.read_bytes() == serial_file.read_bytes()


def test_a_worker_killed_mid_task_is_survived():
    indices = list(range(len(CFG.values("s"))))
    expected = {i: _checksum(_compute_chunk(CFG, i, select_device("cpu"), None)) for i in indices}
    got, killed = {}, []
    with dask_client(workers=2) as client:
        pids = client.run(os.getpid)
        for i, chunk in compute_chunks(client, CFG, indices, device="cpu"):
            got[i] = _checksum(chunk)
            if not killed:  # kill a worker that is computing a chunk right now
                busy = [w for w, keys in client.processing().items() if keys]
                assert busy, "no worker was busy after the first chunk"
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
    assert killed and got == expected


def _omp_threads():
    return os.environ.get("OMP_NUM_THREADS")


def test_a_local_cluster_leaves_the_caller_s_environment_as_it_was():
    """dask's nanny writes its workers' variables (OMP_NUM_THREADS=1, MKL_NUM_THREADS=1, PYTHONHASHSEED, ...) into the
    spawning process's os.environ and leaves them: every later subprocess of the caller ran on one thread. The workers
    keep dask's settings; the caller's environment is its own again, while the cluster runs and after it."""
    before = dict(os.environ)
    with dask_client(workers=1) as client:
        assert dict(os.environ) == before
        assert set(client.run(_omp_threads).values()) == {"1"}
    assert dict(os.environ) == before


def test_a_scheduler_address_is_used_and_an_absent_one_is_a_clear_error(serial_file, tmp_path, monkeypatch):
    from distributed import LocalCluster

    from lenssim_studies.cluster import _environment_kept

    with _environment_kept(), LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                           dashboard_address=None) as cluster:
        out = tmp_path / "remote.nc"
        run_sweep(CFG, out, device="cpu", show_progress=False, scheduler=cluster.scheduler_address)
    assert out.read_bytes() == serial_file.read_bytes()

    monkeypatch.setattr(lenssim_studies.cluster, "CONNECT_TIMEOUT_S", 2)
    with pytest.raises(ConnectionError, match="no dask scheduler answers at 'tcp://127.0.0.1:9'"):
        run_sweep(CFG, tmp_path / "none.nc", device="cpu", show_progress=False, scheduler="tcp://127.0.0.1:9")


def test_command_line_checks_the_worker_count_before_any_work(tmp_path, capsys):
    from lenssim_cli.main import main

    out = tmp_path / "x.nc"
    assert main(["sweep", "small_grid", "--out", str(out), "--workers", "0", "--quiet"]) == 2
    assert "--workers 0 is not allowed" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "x.nc.partial").exists()
    with pytest.raises(SystemExit):
        main(["sweep", "small_grid", "--out", str(out), "--workers", "2", "--scheduler", "tcp://h:1"])


def test_a_worker_that_reads_the_config_differently_refuses():
    """A worker whose lenssim computes another digest for the config would write another sweep: it refuses."""
    with pytest.raises(ClusterError, match="install the client's lenssim version on every worker"):
        _chunk_task(CFG.to_dict(), "0" * 16, 0, "cpu", 1)
