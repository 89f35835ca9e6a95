"""``shoha serve``: the HTTP + WebSocket service the simulator calls after each block (docs/serve.md)."""

from __future__ import annotations

import json
import math
import threading

import click

from geometry.errors import InputError

from .common import json_option

#: The one host that needs no --token (docs/contract.md, "shoha serve").
LOCAL_HOST = "127.0.0.1"


@click.command("serve")
@click.argument("scene_files", metavar="[SCENE_FILE ...]", nargs=-1)
@click.option("--reference", "references", multiple=True, metavar="LAYOUT",
              help="A reference layout; it serves the scene it names. Repeatable.")
@click.option("--host", default=LOCAL_HOST, show_default=True,
              help="Address to listen on; any but 127.0.0.1 needs --token.")
@click.option("--port", type=click.IntRange(1, 65535), default=8750, show_default=True)
@click.option("--token", default=None, metavar="T",
              help="Require 'Authorization: Bearer T' of every request; pages and sockets may use ?token=T.")
@click.option("--cors", "cors", multiple=True, metavar="ORIGIN",
              help="Let pages from ORIGIN (the simulator's WebGL build) call the service. Repeatable.")
@click.option("--reference-time-limit", type=float, default=None, metavar="S",
              help="Seconds of the background optimize of a scene with no --reference "
                   "(default: optimize's own); 0 computes none.")
@click.option("--replan-time-limit", type=float, default=None, metavar="S",
              help="Seconds of a re-plan around a trainee's blocks, for a hint where no reference "
                   "block fits (default: a minute).")
@click.option("--max-sessions", type=click.IntRange(1, 10_000), default=64, show_default=True,
              help="Sessions kept at once.")
@click.option("--idle-timeout", type=float, default=3600.0, show_default=True, metavar="S",
              help="Seconds after which an unused session is forgotten.")
@click.option("--open", "open_view", is_flag=True,
              help="Open the live view (/view: the session started last) in the default browser.")
@json_option
def serve_cmd(scene_files: tuple[str, ...], references: tuple[str, ...], host: str, port: int,
              token: str | None, cors: tuple[str, ...], reference_time_limit: float | None,
              replan_time_limit: float | None, max_sessions: int,
              idle_timeout: float, open_view: bool, as_json: bool) -> None:
    """Serve live checks of a trainee's blocks over HTTP and WebSocket.

    Serves the built-in scenes and every SCENE_FILE. A scene's reference is
    the --reference layout that names it; without one it is optimized in the
    background (seed 0) and cached, and the answers say "reference": null
    until it is ready. Open http://HOST:PORT/sessions/ID/view to watch a session.

    Once it listens it says where, on stderr; with --json also as one JSON
    object on stdout (url, host, port, view, scenes, token_required), which a
    launcher can wait for. It then serves until stopped.
    """
    if host != LOCAL_HOST and not token:
        raise InputError(f"--host {host}: any host but {LOCAL_HOST} needs --token, "
                         "so that no one else on the network can drive the service")
    if token is not None and (len(token) < 8 or not token.isprintable() or " " in token):
        raise InputError("--token: use at least 8 printable characters without spaces")
    if reference_time_limit is not None and (not math.isfinite(reference_time_limit)
                                             or reference_time_limit < 0):
        raise InputError(f"--reference-time-limit {reference_time_limit}: must be 0 or more seconds")
    if replan_time_limit is not None and (not math.isfinite(replan_time_limit) or replan_time_limit <= 0):
        raise InputError(f"--replan-time-limit {replan_time_limit}: must be more than 0 seconds")
    if not math.isfinite(idle_timeout) or idle_timeout <= 0:
        raise InputError(f"--idle-timeout {idle_timeout}: must be more than 0 seconds")
    for origin in cors:
        if not origin.startswith(("http://", "https://")) or origin.endswith("/"):
            raise InputError(f"--cors {origin!r}: give an origin such as http://localhost:8000")

    _check_listen(host, port)
    import logging

    from geometry.scene import builtin_scenes, load_scene
    from optimizer.serve.app import run
    from optimizer.serve.service import Service

    scenes = [load_scene(name) for name in builtin_scenes()] + [load_scene(path) for path in scene_files]
    service = Service(scenes, list(references), reference_seconds=reference_time_limit,
                      replan_seconds=replan_time_limit, max_sessions=max_sessions, idle_s=idle_timeout)
    logging.basicConfig(level=logging.WARNING, format="shoha serve: %(message)s")

    def listening(bound: int) -> None:
        # An IPv6 literal goes in brackets; an empty host listens on every interface, of which
        # this machine's own is the one to name.
        shown = f"[{host}]" if ":" in host else host or "127.0.0.1"
        url = f"http://{shown}:{bound}"
        click.echo(f"shoha serve: {len(service.scenes)} scenes on {url}; the live view is {url}/view",
                   err=True)
        if as_json:
            click.echo(json.dumps({"url": url, "host": host, "port": bound, "view": f"{url}/view",
                                   "scenes": sorted(service.scenes), "token_required": token is not None}))
        if open_view:
            threading.Thread(target=_open_when_up, args=(host, bound, token), daemon=True).start()

    run(service, host, port, token, cors, listening=listening)


def _check_listen(host: str, port: int) -> None:
    """Refuse a host that does not resolve, or a port taken, before anything is loaded or said
    (the server found it only after saying it was serving, and exited with status 3).

    Each address is tried as asyncio's ``create_server`` binds it, which the server uses:
    every passive address of the host (an empty host is every interface), IPv6 ones alone.
    """
    import socket

    try:
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as exc:
        raise InputError(f"--host {host}: the name does not resolve ({exc})") from None
    for family, kind, proto, _, address in dict.fromkeys(infos):
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                probe.bind(address)
            except OSError as exc:
                why = exc.strerror or exc
                raise InputError(f"--port {port}: cannot listen on {host}:{port} ({why})") from None


def _open_when_up(host: str, port: int, token: str | None) -> None:
    """Open ``/view`` in the default browser once the service answers (best effort, for 60 s)."""
    import http.client
    import time
    import webbrowser
    from urllib.parse import quote

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    for _ in range(600):
        try:
            conn = http.client.HTTPConnection(host, port, timeout=1.0)
            conn.request("GET", "/healthz", headers=headers)
            if conn.getresponse().status == 200:
                query = f"?token={quote(token, safe='')}" if token else ""
                webbrowser.open(f"http://{host}:{port}/view{query}")
                return
        except OSError:
            pass
        time.sleep(0.1)
