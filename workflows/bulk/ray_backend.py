"""Connecting a bulk run to Ray: fail fast on a wrong address, join a running cluster, check paths.

- ``--address host:port`` (a cluster's GCS) or ``ray://host:port`` (Ray Client, from the ``ray``
  extra): the address is first probed with a plain TCP connection (``PROBE_TIMEOUT_S``), so that a
  wrong host or port fails in seconds with a clear error instead of Ray's minutes of retries;
  connection errors from Ray itself become lanecast errors too.
- no address: ``RAY_ADDRESS``, else the cluster ``ray start`` last started on this machine (its
  address file), is joined when it answers; otherwise a private local Ray is started with as many
  CPUs as ``--workers``.
- Before any work, one task on the cluster checks that the workers see the inputs and OUT_DIR (by
  the same absolute paths): a path the workers cannot reach is refused, naming it.

Ray is imported here only, inside the functions: it is optional (the ``ray`` extra).
"""

from __future__ import annotations

import os
import shlex
import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from lanecast.io_adapters.errors import InputError, UsageError

PROBE_TIMEOUT_S = 5.0
CONNECT_RETRIES = 10  # Ray's attempts (about 1 s each) to reach a GCS that passed the probe
PATH_CHECK_TIMEOUT_S = 120.0
ADDRESS_HELP = "host:port of the cluster's head (`ray start --head` prints it) or ray://host:10001"
RAY_REQUIREMENT = "ray[client]>=2.30"  # pyproject.toml's `ray` extra (a test checks they agree)


def install_ray() -> str:
    """The command that installs Ray into the environment running lanecast, from any directory (not
    ``pip install 'lanecast[ray]'``, which would fetch another lanecast than a clone's)."""
    return f"{shlex.quote(sys.executable)} -m pip install '{RAY_REQUIREMENT}'"


def ray_module() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise UsageError("--engine ray", "Ray is not installed", expected=install_ray()) from exc
    return ray


def host_port(address: str) -> tuple[str, int]:
    """(host, port) of ``host:port`` or ``ray://host:port``; a clear error for anything else."""
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("ray", "tcp") or not parts.hostname or port is None:
        raise UsageError(f"--address {address}", "not a Ray address", expected=ADDRESS_HELP)
    return parts.hostname, port


def probe(address: str, timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Raise a clear ``UsageError`` unless a gRPC server (a Ray head or Ray Client server) answers at
    ``address`` within ``timeout_s``: first a TCP connection, then gRPC's HTTP/2 handshake (when grpc
    is installed and the cluster does not use TLS), which a port that is not Ray's never completes."""
    host, port = host_port(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise UsageError(
            f"--address {address}",
            f"cannot reach a Ray cluster there: {reason} (after at most {timeout_s:g} s)",
            expected=ADDRESS_HELP,
        ) from exc
    try:
        import grpc
    except ImportError:
        return
    if os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true"):
        return
    channel = grpc.insecure_channel(f"{host}:{port}")
    try:
        grpc.channel_ready_future(channel).result(timeout=timeout_s)
    except grpc.FutureTimeoutError as exc:
        raise UsageError(
            f"--address {address}",
            f"accepts connections but does not answer as a Ray cluster (no gRPC handshake within {timeout_s:g} s)",
            expected=ADDRESS_HELP,
        ) from exc
    finally:
        channel.close()


def running_local_cluster() -> str | None:
    """The address of the cluster to join when none is given: ``RAY_ADDRESS``, else the one
    ``ray start`` recorded on this machine (None when there is none)."""
    if os.environ.get("RAY_ADDRESS"):
        return os.environ["RAY_ADDRESS"]
    try:
        from ray._private.utils import read_ray_address  # where `ray start` records its address

        found = read_ray_address()
    except Exception:  # a private helper: if Ray moved it, start a local Ray as before
        return None
    return str(found) if found else None


def connect(address: str | None, workers: int) -> bool:
    """Connect to Ray (see the module docstring); True when this call started it (shut it down after)."""
    ray = ray_module()
    if ray.is_initialized():
        return False
    if address and address.startswith("ray://"):
        try:
            import grpc  # noqa: F401
            import ray.util.client
        except ImportError as exc:
            raise UsageError(
                f"--address {address}",
                "ray:// addresses need Ray Client, which is not installed",
                expected=f"{install_ray()}, or a host:port address",
            ) from exc
    target = address or running_local_cluster()
    if target:
        try:
            probe(target)
        except UsageError:
            if address:
                raise
            target = None  # a stale record of a stopped cluster: start our own
    if target:
        # Ray retries a GCS that does not answer for about 20 s; an operator's own budget wins
        os.environ.setdefault("RAY_gcs_server_port_wait_time_s", str(int(CONNECT_RETRIES)))
    try:
        if target:
            ray.init(address=target, log_to_driver=False)
        else:
            ray.init(num_cpus=max(workers, 1), include_dashboard=False, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise UsageError(
            f"--address {target}" if target else "--engine ray",
            f"Ray could not connect: {exc}",
            expected=ADDRESS_HELP,
        ) from exc
    return True


def _missing(paths: Sequence[str]) -> tuple[str, list[str]]:
    """(host, paths that do not exist there): run on a Ray worker."""
    return os.uname().nodename, [p for p in paths if not os.path.exists(p)]


def refuse_unreachable_paths(paths: Sequence[Path]) -> None:
    """Refuse the run when a Ray worker does not see ``paths`` (inputs, OUT_DIR) by the same names."""
    ray = ray_module()
    check = ray.remote(num_cpus=0)(_missing)
    host, missing = ray.get(check.remote([str(p) for p in paths]), timeout=PATH_CHECK_TIMEOUT_S)
    if missing:
        raise InputError(
            Path(missing[0]),
            f"the Ray workers (on {host}) cannot see {len(missing)} of the run's paths",
            expected="inputs and --out on storage every node mounts at the same absolute path",
        )
