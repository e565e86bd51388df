"""Fleet-size replays: recordings on object storage, jobs on a Dask cluster (desktop only).

A fleet records more bags than one machine replays in good time. ``soc_replay`` then runs its
jobs on `Dask distributed <https://distributed.dask.org>`_, an existing engine (no scheduler of
ours): ``--scheduler tcp://HOST:8786`` sends them to a running cluster, ``--scheduler local``
starts a local cluster of ``--jobs`` single-threaded worker processes; without ``--scheduler``
the process pool runs them as before. Why Dask rather than Ray: pure-Python wheels that pip
installs in a few seconds beside numpy, a local cluster in one line for tests and laptops,
and fsspec (which Dask is built on) for the inputs; Ray's wheels, object store and raylet are
more than a job of independent replays needs.

Inputs may be URLs that `fsspec <https://filesystem-spec.readthedocs.io>`_ opens
(``s3://bucket/bags/run_1``, ``gcs://...``, ``file:///...``, ``memory://...``; a remote
protocol needs its fsspec package, ``s3fs`` for S3): each job copies its recording to a
temporary directory where it runs (a worker of the cluster, or this process) and reads it
from there, so a cluster's workers fetch their own bags. A URL of a directory holding bags
expands to them, as a local directory does.

Nothing here runs onboard: the node never imports it, and ``dask``/``fsspec`` are imported
only when a URL or ``--scheduler`` is given (``setup.py`` extra ``fleet``).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

from .run import ReplayError, ReplayJob

T = TypeVar("T")
J = TypeVar("J")

#: ``--scheduler`` value that starts a local cluster.
LOCAL = "local"
#: Seconds to wait for a cluster's scheduler before giving up with one line.
CONNECT_TIMEOUT_S = 10.0


def is_url(text: str) -> bool:
    """True for ``protocol://...`` (a local path has no ``://``)."""
    return "://" in text


def _fs(url: str) -> tuple[Any, str]:
    try:
        import fsspec  # noqa: PLC0415 (desktop extra, imported when a URL is given)

        return fsspec.core.url_to_fs(url)
    except ImportError as exc:
        raise ReplayError(
            f"{url}: opening it needs fsspec and its protocol's package ({exc})"
        ) from exc
    except ValueError as exc:  # an unknown protocol
        raise ReplayError(f"{url}: {exc}") from exc


def expand_url(url: str) -> list[str]:
    """A URL of a bag, a CSV or a directory of bags (sub-directories with metadata.yaml)."""
    fs, root = _fs(url)
    try:
        if not fs.exists(root):
            raise ReplayError(f"{url}: no such file or directory")
        if not fs.isdir(root) or fs.exists(f"{root.rstrip('/')}/metadata.yaml"):
            return [url]
        children = sorted(fs.ls(root, detail=False))
    except OSError as exc:
        raise ReplayError(f"{url}: {exc}") from exc
    bags = [c for c in children if fs.exists(f"{c.rstrip('/')}/metadata.yaml")]
    if not bags:
        raise ReplayError(f"{url}: neither a bag nor a directory of bags")
    protocol = url.split("://", 1)[0]
    return [f"{protocol}://{b.split('://', 1)[-1]}" for b in bags]


def fetch(url: str, into: Path) -> Path:
    """Copy the recording at ``url`` (a file or a bag directory) into ``into``; its path."""
    fs, root = _fs(url)
    target = into / Path(root.rstrip("/")).name
    try:
        if fs.isdir(root):
            target.mkdir(parents=True, exist_ok=True)
            for entry in fs.ls(root, detail=False):
                fs.get(entry, str(target / Path(entry.rstrip("/")).name))
        else:
            fs.get(root, str(target))
    except OSError as exc:
        raise ReplayError(f"{url}: cannot fetch it: {exc}") from exc
    return target


@contextmanager
def local_copy(job: ReplayJob) -> Iterator[ReplayJob]:
    """``job`` reading a local copy of its URL (``job.url``), removed afterwards; a job
    without a URL as it is."""
    if not job.url:
        yield job
        return
    tmp = Path(tempfile.mkdtemp(prefix="soc_replay_"))
    try:
        yield replace(job, path=fetch(job.url, tmp))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run_on_dask(fn: Callable[[J], T], jobs: Sequence[J], scheduler: str, workers: int) -> list[T]:
    """``fn`` over ``jobs`` on a Dask cluster, results in the jobs' order: the cluster at
    ``scheduler`` (an address), or a local one of ``workers`` processes (``local``)."""
    try:
        from dask.distributed import Client, LocalCluster  # noqa: PLC0415 (desktop extra)
    except ImportError as exc:
        raise ReplayError(f"--scheduler needs dask[distributed] ({exc})") from exc
    cluster = None
    try:
        if scheduler == LOCAL:
            cluster = LocalCluster(
                n_workers=max(1, workers),
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",  # a free port: tests and users may run several
            )
            client = Client(cluster)
        else:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise ReplayError(f"--scheduler {scheduler}: cannot connect: {exc}") from exc
    try:
        futures = client.map(fn, list(jobs), pure=False)
        return list(client.gather(futures))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
