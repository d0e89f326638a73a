"""The network blocked for a command a test runs: with this folder first on ``PYTHONPATH`` every Python process of
the command (and of the commands it starts) refuses each name lookup of, and each connection to, a host other than
this machine, and appends a line naming it to the file ``AGRINERF_NETWORK_LOG`` names. Connections on this machine
(the viewer's server, worker pipes) pass. Then it runs the ``sitecustomize`` it shadows, if there is one."""

import importlib.util
import os
import socket
import sys

LOCAL = {None, "", "localhost", "127.0.0.1", "::1"}


def _refuse(attempt: str) -> None:
    with open(os.environ["AGRINERF_NETWORK_LOG"], "a") as log:
        log.write(f"{os.getpid()} {sys.argv[:1]} {attempt}\n")
    raise OSError(f"network blocked (test): {attempt}")


_getaddrinfo = socket.getaddrinfo
_connect = socket.socket.connect
_connect_ex = socket.socket.connect_ex


def _lookup(host, *args, **kwargs):
    if host not in LOCAL:
        _refuse(f"getaddrinfo {host!r}")
    return _getaddrinfo(host, *args, **kwargs)


def _remote(sock: socket.socket, address) -> bool:
    return sock.family in (socket.AF_INET, socket.AF_INET6) and address[0] not in LOCAL


def _connect_checked(self, address):
    if _remote(self, address):
        _refuse(f"connect {address!r}")
    return _connect(self, address)


def _connect_ex_checked(self, address):
    if _remote(self, address):
        _refuse(f"connect_ex {address!r}")
    return _connect_ex(self, address)


if os.environ.get("AGRINERF_NETWORK_LOG"):
    socket.getaddrinfo = _lookup
    socket.socket.connect = _connect_checked
    socket.socket.connect_ex = _connect_ex_checked

_here = os.path.dirname(os.path.abspath(__file__))
for _entry in sys.path:
    _shadowed = os.path.join(os.path.abspath(_entry or "."), "sitecustomize.py")
    if os.path.dirname(_shadowed) != _here and os.path.isfile(_shadowed):
        _spec = importlib.util.spec_from_file_location("_shadowed_sitecustomize", _shadowed)
        if _spec is not None and _spec.loader is not None:
            _spec.loader.exec_module(importlib.util.module_from_spec(_spec))
        break
