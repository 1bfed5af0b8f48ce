"""Hosts on one machine for multi-host tests: Linux network namespaces joined by a bridge.

``Lan(prefix)`` makes a "switch" namespace holding a bridge and, per :meth:`Lan.host`, a namespace
with a veth pair: one end (``eth0``, address ``10.<net>.0.<n>/24``) in the host, the other on the
bridge. Commands run inside a host with :meth:`Lan.cmd` (``ip netns exec``). :meth:`cut` and
:meth:`restore` take a host's link down and up (the switch side, as a pulled cable). Everything,
addresses included, exists only inside the namespaces, and :meth:`close` deletes them all.

:func:`unavailable` says why namespaces cannot be made here (not root, no ``ip``), for a skip.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid

__all__ = ["Lan", "unavailable"]


def _ip(*args: str, ns: str | None = None) -> None:
    cmd = ["ip", *(["netns", "exec", ns, "ip"] if ns else []), *args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=20)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {r.stderr.strip()}")


def unavailable() -> str | None:
    """Why network namespaces cannot be created here, or None when they can."""
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    name = f"rsalprobe{uuid.uuid4().hex[:6]}"
    try:
        _ip("netns", "add", name)
    except (RuntimeError, subprocess.TimeoutExpired) as e:
        return f"cannot create a network namespace: {e}"
    subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=20)
    return None


class Lan:
    def __init__(self, net: int = 77):
        self.tag = uuid.uuid4().hex[:5]
        self.net = net
        self.switch = f"rsw{self.tag}"
        self.hosts: dict[str, tuple[str, str, str]] = {}  # name -> (namespace, address, switch-side veth)
        _ip("netns", "add", self.switch)
        _ip("link", "set", "lo", "up", ns=self.switch)
        _ip("link", "add", "br0", "type", "bridge", ns=self.switch)
        _ip("link", "set", "br0", "up", ns=self.switch)

    def host(self, name: str) -> str:
        """Add a host; returns its address."""
        n = len(self.hosts) + 1
        ns = f"r{self.tag}{name}"[:15]
        addr = f"10.{self.net}.0.{n}"
        outer = f"v{self.tag}{n}"
        _ip("netns", "add", ns)
        _ip("link", "set", "lo", "up", ns=ns)
        _ip("link", "add", "eth0", "type", "veth", "peer", "name", outer, ns=ns)
        _ip("link", "set", outer, "netns", self.switch, ns=ns)
        _ip("addr", "add", f"{addr}/24", "dev", "eth0", ns=ns)
        _ip("link", "set", "eth0", "up", ns=ns)
        _ip("link", "set", outer, "master", "br0", ns=self.switch)
        _ip("link", "set", outer, "up", ns=self.switch)
        self.hosts[name] = (ns, addr, outer)
        return addr

    def addr(self, name: str) -> str:
        return self.hosts[name][1]

    def cmd(self, name: str, argv: list[str]) -> list[str]:
        """``argv`` run inside host ``name``."""
        return ["ip", "netns", "exec", self.hosts[name][0], *argv]

    def cut(self, name: str) -> None:
        """Pull host ``name``'s cable: its port on the switch goes down."""
        _ip("link", "set", self.hosts[name][2], "down", ns=self.switch)

    def restore(self, name: str) -> None:
        _ip("link", "set", self.hosts[name][2], "up", ns=self.switch)

    def close(self) -> None:
        for ns, _, _ in self.hosts.values():
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=20)
        subprocess.run(["ip", "netns", "del", self.switch], capture_output=True, timeout=20)
        self.hosts.clear()
