"""Probe: clients that cost a running server without a good key.

``bodies``: large bodies with a bogus (or wrong-scope) key, sent whole, in parallel: how
fast each is answered and how much of it was sent before the server stopped reading.
``slow``: connections that send their headers, or their bodies, a byte at a time: how long
the server holds each. Both report what ``/healthz`` sees meanwhile and the server's
memory (the resident sizes of the processes given by --pid).

Usage: python bench/hostile_clients.py bodies --url http://127.0.0.1:8392 --pid 123 \
           [--parallel 4] [--mb 30] [--bearer x] [--path /v1/floors/<id>/plan]
       python bench/hostile_clients.py slow --url ... --pid 123 --bearer <device key> \
           [--parallel 200]
"""

from __future__ import annotations

import argparse
import http.client
import json
import socket
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit


def rss_mb(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1])
    return total / 1024


def healthz_ms(host: str, port: int) -> float:
    start = time.perf_counter()
    conn = http.client.HTTPConnection(host, port, timeout=30)
    conn.request("GET", "/healthz")
    conn.getresponse().read()
    conn.close()
    return 1000 * (time.perf_counter() - start)


def send_body(host: str, port: int, path: str, bearer: str, size: int, out: list[Any]) -> None:
    """PUT ``size`` bytes of JSON-looking body, all of it unless the server closes first;
    the answer's status and when it came."""
    head = (
        f"PUT {path} HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {bearer}\r\n"
        f"Content-Type: application/json\r\nContent-Length: {size}\r\n\r\n"
    ).encode()
    chunk = b" " * 65536
    sock = socket.create_connection((host, port), timeout=60)
    start = time.perf_counter()
    answer: dict[str, Any] = {}

    def read() -> None:
        try:
            data = sock.recv(65536)
        except OSError:
            data = b""
        answer["ms"] = 1000 * (time.perf_counter() - start)
        answer["status"] = int(data.split(b" ", 2)[1]) if data else None

    reader = threading.Thread(target=read)
    sock.sendall(head)
    reader.start()
    sent = 0
    try:
        while sent < size and reader.is_alive():
            sock.sendall(chunk[: size - sent])
            sent += min(len(chunk), size - sent)
    except OSError:
        pass  # the server closed the connection: it stopped reading
    reader.join()
    sock.close()
    out.append({**answer, "sent_mb": round(sent / 2**20, 1)})


def dribble(host: str, port: int, bearer: str, body: bool, out: list[tuple[str, float]]) -> None:
    """Send a request's headers (or, with ``body``, its body, with a good key so that it is
    read) a byte every 0.5 s until the server closes the connection or 120 s pass; how
    long the server held it."""
    head = b"POST /v1/sessions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
    if body:
        head += f"Authorization: Bearer {bearer}\r\nContent-Length: 100000\r\n\r\n".encode()
    sock = socket.create_connection((host, port), timeout=130)
    start = time.perf_counter()
    try:
        if body:
            sock.sendall(head)
            head = b" " * 100000
        sock.setblocking(False)
        for byte in head:
            if time.perf_counter() - start > 120:
                break
            try:
                if sock.recv(65536) == b"":
                    break  # closed
                break  # answered (a 408): the server is done with it
            except BlockingIOError:
                pass
            sock.send(bytes([byte]))
            time.sleep(0.5)
    except OSError:
        pass  # reset by the server
    out.append(("bodies" if body else "headers", time.perf_counter() - start))
    sock.close()


def held(answers: list[tuple[str, float]]) -> dict[str, dict[str, float]]:
    """Seconds each kind of slow connection was held: median and longest."""
    out = {}
    for kind in ("headers", "bodies"):
        times = [t for k, t in answers if k == kind]
        out[kind] = {"p50_s": round(statistics.median(times), 2), "max_s": round(max(times), 2)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=["bodies", "slow"])
    parser.add_argument("--url", required=True)
    parser.add_argument("--pid", type=int, action="append", default=[])
    parser.add_argument("--parallel", type=int, default=4)
    parser.add_argument("--mb", type=float, default=30)
    parser.add_argument("--bearer", default="x")
    parser.add_argument("--path", default="/v1/floors/" + "0" * 32 + "/plan")
    args = parser.parse_args()
    where = urlsplit(args.url)
    host, port = where.hostname or "127.0.0.1", where.port or 80
    quiet = [healthz_ms(host, port) for _ in range(20)]
    before = rss_mb(args.pid) if args.pid else None
    answers: list[Any] = []
    work: list[tuple[Callable[..., None], tuple[Any, ...]]]
    if args.mode == "bodies":
        size = int(args.mb * 2**20)
        work = [(send_body, (host, port, args.path, args.bearer, size, answers))] * args.parallel
    else:
        work = [
            (dribble, (host, port, args.bearer, i % 2 == 1, answers)) for i in range(args.parallel)
        ]
    senders = [threading.Thread(target=f, args=a) for f, a in work]
    for s in senders:
        s.start()
    during, peak = [], before
    while any(s.is_alive() for s in senders):
        during.append(healthz_ms(host, port))
        if args.pid:
            peak = max(peak or 0.0, rss_mb(args.pid))
        time.sleep(0.05)
    print(  # noqa: T201 - the probe's report
        json.dumps(
            {
                "answers": answers if args.mode == "bodies" else held(answers),
                "healthz_ms_quiet_p50": round(statistics.median(quiet), 2),
                "healthz_ms_during_max": round(max(during), 2) if during else None,
                "rss_mb_before": before and round(before, 1),
                "rss_mb_peak": peak and round(peak, 1),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
