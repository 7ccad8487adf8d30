"""
Run a fleet study on Dask, resumably, into Parquet.

Each batch of units is one Dask task
(:func:`~qfa_ros.fleet.self_calibration_unit.simulate_batch`). The client writes every
finished batch to ``OUT.parts/batch-START-STOP.parquet`` at once (temporary file, then
rename), so an interrupted run keeps what it finished and a restart computes only the
missing batches. When all are there the parts are joined,
sorted by unit and calibration, into ``OUT`` (again written aside, then renamed). Unit
results depend only on the study and the unit's seed, so the table is identical
whatever the number of workers.
"""

from contextlib import contextmanager
import hashlib
import json
import logging
import os
from pathlib import Path
import signal
import threading
import time

import pyarrow as pa
import pyarrow.parquet as pq

from qfa_ros.fleet.self_calibration_unit import simulate_batch
from qfa_ros.fleet.study import StudyError
from qfa_ros.model.safe_files import write_atomically

STUDY_FILE = 'study.json'
SIMULATING_PACKAGES = ('model', 'calibration', 'fleet')
"""The subpackages whose code decides a unit's rows (their sources make the code digest)."""


def code_digest():
    """
    Return a digest of the sources that compute a unit's rows.

    A resumed study must not join rows of two versions of the model: the parts directory
    records this digest beside the study's, and a run with other code refuses to resume.
    """
    package = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for name in SIMULATING_PACKAGES:
        for source in sorted((package / name).glob('*.py')):
            digest.update(f'{name}/{source.name}'.encode())
            digest.update(source.read_bytes())
    return digest.hexdigest()[:16]


def parts_directory(out_path):
    """Return where the finished batches of ``out_path`` are kept."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.name + '.parts')


def _part_path(parts, start, stop):
    return parts / f'batch-{start:07d}-{stop:07d}.parquet'


def _write_table(table, path):
    write_atomically(path, lambda stream: pq.write_table(table, stream))


def _prepare(study, parts, code):
    """Create or check the parts directory; return the batches still to compute."""
    identity = {'digest': study.digest(), 'code': code, 'study': study.to_dict()}
    marker = parts / STUDY_FILE
    if marker.exists():
        try:
            recorded = json.loads(marker.read_text())
        except (OSError, ValueError):
            recorded = {}
        if recorded.get('digest') != identity['digest']:
            raise StudyError(f'{parts} holds results of another study (digest '
                             f'{recorded.get("digest")}, this one {identity["digest"]}): '
                             'remove it or choose --out')
        if recorded.get('code') != identity['code']:
            raise StudyError(f'{parts} was computed by other model code (code digest '
                             f'{recorded.get("code")}, this one {identity["code"]}): its rows '
                             'would not match new ones; remove it or choose --out')
    else:
        parts.mkdir(parents=True, exist_ok=True)
        marker.write_text(json.dumps(identity, indent=1, default=str))
    return [(start, stop) for start, stop in study.batches
            if not _part_path(parts, start, stop).exists()]


@contextmanager
def workers_shielded_from_sigint():
    """
    Start worker processes that ignore SIGINT; a Ctrl-C meanwhile is raised afterwards.

    Ctrl-C reaches the terminal's whole process group: the workers would each print a
    traceback, while the client, which gets it too, stops the cluster itself. An ignored
    signal stays ignored in a child, so the workers started here never see it. Here
    SIGINT is blocked as well: Linux queues a blocked signal even while it is ignored,
    so a Ctrl-C during the start stays pending and is raised as
    :class:`KeyboardInterrupt` once the handler is back and the signal unblocked. That
    holds if no other thread takes the signal meanwhile (and drops it, ignored): start
    them with SIGINT blocked, as ``qfa-fleet`` does before its imports.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    if signal.SIGINT in signal.sigpending():
        # Ignoring it would discard a Ctrl-C that came while it was blocked (POSIX).
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        raise KeyboardInterrupt
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def batch_table(study, start, stop):
    """Simulate units ``start`` to ``stop - 1`` and return them as an Arrow table."""
    return pa.Table.from_pylist(simulate_batch(study, start, stop))


def run_study(study, out_path, *, workers=None, scheduler=None, client=None, progress=True,
              log=print):
    """
    Run ``study`` (resuming a previous run of it) and write the joined table to ``out_path``.

    Parameters
    ----------
    study : qfa_ros.fleet.study.Study
        The validated study.
    out_path : str or os.PathLike
        The Parquet file to write; finished batches are kept beside it in ``OUT.parts``.
    workers : int, optional
        Worker processes of the local cluster (default: every core).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://HOST:PORT``) instead.
    client : dask.distributed.Client, optional
        A client to use (and leave open), e.g. one cluster for several studies.
    progress : bool
        Show a progress bar (tqdm) on the terminal.
    log : callable
        Where one-line status messages go.

    Returns
    -------
    pyarrow.Table
        The whole study, one row per unit and calibration.
    """
    from distributed.comm import get_address_host_port

    out_path = Path(out_path)
    if scheduler:
        try:
            get_address_host_port(scheduler)  # refused before a parts directory is made
        except ValueError as error:
            raise StudyError(f'--scheduler: {error}') from None
    parts = parts_directory(out_path)
    code = code_digest()
    pending = _prepare(study, parts, code)
    done = len(study.batches) - len(pending)
    if done:
        log(f'{done} of {len(study.batches)} batches already done in {parts}; '
            f'computing {len(pending)}')
    started = time.perf_counter()
    if pending:
        _compute(study, parts, pending, workers, scheduler, client, progress)
    table = pa.concat_tables(pq.read_table(_part_path(parts, start, stop))
                             for start, stop in study.batches)
    table = table.sort_by([('unit', 'ascending'), ('calibration', 'ascending')])
    table = table.replace_schema_metadata({
        'qfa_ros.study': json.dumps(study.to_dict(), default=str),
        'qfa_ros.code_digest': code})
    _write_table(table, out_path)
    log(f'{study.units} units x {study.calibrations} calibrations -> {out_path} '
        f'({time.perf_counter() - started:.1f} s for {len(pending)} batches)')
    return table


def _compute(study, parts, pending, workers, scheduler, client, progress):
    """
    Compute the ``pending`` batches on Dask, writing each to ``parts`` as it finishes.

    Parameters
    ----------
    study, workers, scheduler, client, progress
        As :func:`run_study`'s.
    parts : pathlib.Path
        The parts directory.
    pending : list of tuple
        The ``(start, stop)`` units of the batches to compute.
    """
    from dask.distributed import as_completed, Client, LocalCluster
    from tqdm import tqdm

    own_client = client is None
    cluster = None
    try:
        if scheduler and own_client:
            client = Client(scheduler)
        elif own_client:
            # One single-threaded process per core: the model holds the GIL per task.
            # Port 0: a second study beside a running one must not fight over the port.
            # CRITICAL: a study's failures reach this process through its futures;
            # what the cluster logs as ERROR is its own chatter, e.g. a worker's
            # heartbeat racing the scheduler's close at a Ctrl-C (a traceback).
            with workers_shielded_from_sigint():
                cluster = LocalCluster(n_workers=workers or os.cpu_count(),
                                       threads_per_worker=1, processes=True,
                                       dashboard_address=':0',
                                       silence_logs=logging.CRITICAL)
            client = Client(cluster)
        futures = [client.submit(batch_table, study, start, stop, pure=False,
                                 key=f'qfa-fleet-{study.digest()}-{start}-{stop}')
                   for start, stop in pending]
        bounds = {future.key: (start, stop) for future, (start, stop)
                  in zip(futures, pending)}
        bar = tqdm(total=sum(stop - start for start, stop in pending), unit='unit',
                   desc=study.name, disable=not progress)
        with bar:
            for future in as_completed(futures):
                start, stop = bounds[future.key]
                _write_table(future.result(), _part_path(parts, start, stop))
                bar.update(stop - start)
                future.release()
    except KeyboardInterrupt:
        # Stopped mid-start, the cluster may log broken connections: asked for, not news.
        logging.getLogger('distributed').setLevel(logging.CRITICAL)
        raise
    finally:
        if own_client and client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
