"""Checks that a test's processes keep their traffic on the machine (issue 31).

``off_machine_sockets(pids)``: the internet sockets of those processes that could reach the
network: bound to an address other than loopback (0.0.0.0 included: such a socket sends where
the routing table says and receives from every interface) or connected to a non-loopback peer.
A socket bound to 127.0.0.0/8 or ::1 can only talk to this machine. Group memberships are not
visible per socket; :func:`in_loopback_namespace` tells a test that it runs in a network
namespace whose only interface is ``lo`` (``unshare -n``), where every join is on ``lo``.

``run_in_loopback_namespace(argv)`` runs a command in such a namespace (root and ``unshare``
needed; None when this machine cannot make one).
"""

from __future__ import annotations

import ipaddress
import os
import shlex
import shutil
import socket
import subprocess
from collections.abc import Iterable, Sequence

import psutil

NETNS_ENV = "SAFER_TEST_NETNS"


def _loopback(ip: str) -> bool:
    return ipaddress.ip_address(ip.split("%")[0]).is_loopback


def off_machine_sockets(pids: Iterable[int]) -> list[str]:
    """One line per socket of ``pids`` that is not confined to loopback (empty: all are)."""
    bad = []
    for pid in pids:
        try:
            conns = psutil.Process(pid).net_connections(kind="inet")
        except psutil.NoSuchProcess:
            continue
        for c in conns:
            unbound = not c.laddr or (c.laddr.port == 0 and not c.raddr)
            if not unbound and not _loopback(c.laddr.ip):
                bad.append(f"pid {pid} fd {c.fd}: bound to {c.laddr.ip}:{c.laddr.port}")
            if c.raddr and not _loopback(c.raddr.ip):
                bad.append(f"pid {pid} fd {c.fd}: peer {c.raddr.ip}:{c.raddr.port}")
    return bad


def family(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    try:
        p = psutil.Process(pid)
        return [pid] + [c.pid for c in p.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def in_loopback_namespace() -> bool:
    """This process sees no network interface but ``lo``."""
    return [name for _, name in socket.if_nameindex()] == ["lo"]


def can_make_namespace() -> bool:
    if os.geteuid() != 0 or shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    probe = subprocess.run(["unshare", "-n", "ip", "link", "set", "lo", "up"], capture_output=True, check=False)
    return probe.returncode == 0


def run_in_loopback_namespace(argv: Sequence[str], timeout_s: float, cwd: str | None = None
                              ) -> subprocess.CompletedProcess[str] | None:
    """``argv`` in a fresh network namespace with only ``lo`` (up); None if none can be made."""
    if not can_make_namespace():
        return None
    script = "ip link set lo up && exec " + shlex.join(argv)
    return subprocess.run(["unshare", "-n", "sh", "-c", script], capture_output=True, text=True, timeout=timeout_s,
                          cwd=cwd, env={**os.environ, NETNS_ENV: "1"}, check=False)
